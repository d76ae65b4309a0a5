"""SMPTE ST 336 KLV framing: 16-byte universal keys, BER lengths, items of concatenated KLV.

Shared by the set decoders (klv_st0601.py, klv_eg0104.py) and the stream reader (klv.py).
"""
from __future__ import annotations

__all__ = ['split_klv']

_UL_PREFIX = b'\x06\x0e\x2b\x34'  # every SMPTE universal label starts so (ST 336)


def _same_ul(key: bytes, ref: bytes) -> bool:
    """Universal labels compare equal ignoring byte 8, the registry version (ST 336)."""
    return len(key) == 16 and key[:7] == ref[:7] and key[8:] == ref[8:]


def _ber_length(data: bytes, pos: int) -> tuple[int, int] | None:
    """(length, position after it) of a BER length at pos, or None when cut short or invalid."""
    if pos >= len(data):
        return None
    first = data[pos]
    if first < 0x80:
        return first, pos + 1
    n = first & 0x7F
    if n == 0 or n > 8 or pos + 1 + n > len(data):  # 0x80 (indefinite) is not allowed in KLV
        return None
    return int.from_bytes(data[pos + 1:pos + 1 + n], 'big'), pos + 1 + n


def _split_items(data: bytes) -> tuple[list[tuple[bytes, bytes, bytes]], int, bytes]:
    """(key, value, whole item bytes) items, count of skipped non-KLV runs, and an unfinished tail.

    Bytes before a key prefix are skipped (one count per run); an item whose value runs past the
    end is returned as the tail, for the caller to join with the next packet or to count.
    """
    items: list[tuple[bytes, bytes, bytes]] = []
    junk = 0
    pos = 0
    while pos < len(data):
        if data[pos:pos + 4] != _UL_PREFIX:
            nxt = data.find(_UL_PREFIX, pos + 1)
            junk += 1
            if nxt < 0:
                return items, junk, b''
            pos = nxt
            continue
        if pos + 17 > len(data):
            return items, junk, data[pos:]
        parsed = _ber_length(data, pos + 16)
        if parsed is None:
            if pos + 17 + 8 > len(data):  # a long-form length may continue in the next packet
                return items, junk, data[pos:]
            junk += 1
            nxt = data.find(_UL_PREFIX, pos + 1)
            if nxt < 0:
                return items, junk, b''
            pos = nxt
            continue
        length, start = parsed
        end = start + length
        if end > len(data):
            return items, junk, data[pos:]
        items.append((data[pos:pos + 16], data[start:end], data[pos:end]))
        pos = end
    return items, junk, b''


def split_klv(data: bytes) -> list[tuple[bytes, bytes]]:
    """The (16-byte key, value) items of concatenated KLV; non-KLV bytes and a cut tail are dropped."""
    items, _, _ = _split_items(bytes(data))
    return [(key, value) for key, value, _ in items]


def _text(raw: bytes) -> str:
    # ST0601 strings are ISO 646 (a subset of UTF-8); some producers pad with NULs
    return raw.decode('utf-8', errors='replace').rstrip('\x00').strip()
