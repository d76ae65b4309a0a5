"""Rewrite a GoPro MP4 without its video and audio tracks (how karma_telemetry.mp4 was made).

    python strip_av_tracks.py karma.mp4 karma_telemetry.mp4

Every atom is copied byte for byte except: the 'vide' and 'soun' traks are dropped, the kept
tracks' samples are packed into a new mdat in their original order, and their chunk offsets
(stco/co64) are rewritten to point there. The GPMF ('gpmd', "GoPro MET"), timecode ('tmcd') and
SOS ('fdsc') tracks, their sample tables, durations, handler names and the moov/udta atoms are
unchanged, so a GPMF reader sees the same payloads at the same track times.
"""
from __future__ import annotations

import struct
import sys

CONTAINERS = {b'moov', b'trak', b'mdia', b'minf', b'stbl', b'dinf', b'edts', b'udta', b'gmhd'}


def parse(buf: bytes, start: int, end: int) -> list[list]:
    atoms = []
    off = start
    while off + 8 <= end:
        size, kind = struct.unpack_from('>I4s', buf, off)
        header = 8
        if size == 1:
            size, header = struct.unpack_from('>Q', buf, off + 8)[0], 16
        elif size == 0:
            size = end - off
        body = (parse(buf, off + header, off + size) if kind in CONTAINERS and kind != b'udta'
                else buf[off + header:off + size])
        atoms.append([kind, body])
        off += size
    return atoms


def serialize(atoms: list[list]) -> bytes:
    out = bytearray()
    for kind, body in atoms:
        data = serialize(body) if isinstance(body, list) else bytes(body)
        out += struct.pack('>I4s', 8 + len(data), kind) + data
    return bytes(out)


def find(atoms: list[list], kind: bytes) -> list:
    return next(a for a in atoms if a[0] == kind)


def handler(trak: list[list]) -> bytes:
    return find(find(trak[1], b'mdia')[1], b'hdlr')[1][8:12]


def chunks(stbl: list[list]) -> tuple[list[int], list[int], bytes]:
    """(offsets, byte lengths, offset atom kind) of a track's chunks."""
    stsz = find(stbl, b'stsz')[1]
    fixed, count = struct.unpack_from('>II', stsz, 4)
    sizes = [fixed] * count if fixed else list(struct.unpack_from(f'>{count}I', stsz, 12))
    stsc = find(stbl, b'stsc')[1]
    entries = [struct.unpack_from('>III', stsc, 8 + 12 * i) for i in range(struct.unpack_from('>I', stsc, 4)[0])]
    kind = b'stco' if any(a[0] == b'stco' for a in stbl) else b'co64'
    table = find(stbl, kind)[1]
    n = struct.unpack_from('>I', table, 4)[0]
    offsets = list(struct.unpack_from(f'>{n}{"I" if kind == b"stco" else "Q"}', table, 8))
    lengths, sample = [], 0
    for c in range(1, n + 1):
        per = next(spc for first, spc, _ in reversed(entries) if first <= c)
        lengths.append(sum(sizes[sample:sample + per]))
        sample += per
    return offsets, lengths, kind


def main(src: str, dst: str) -> None:
    buf = open(src, 'rb').read()
    top = parse(buf, 0, len(buf))
    ftyp = find(top, b'ftyp')
    moov = find(top, b'moov')
    moov[1] = [a for a in moov[1] if not (a[0] == b'trak' and handler(a) in (b'vide', b'soun'))]
    pieces = []  # (original offset, length, stbl, chunk number)
    for trak in (a for a in moov[1] if a[0] == b'trak'):
        stbl = find(find(find(trak[1], b'mdia')[1], b'minf')[1], b'stbl')[1]
        offsets, lengths, _ = chunks(stbl)
        pieces += [(o, n, id(stbl), k) for k, (o, n) in enumerate(zip(offsets, lengths))]
    head = 8 + len(ftyp[1]) + 8  # ftyp atom, then the mdat header
    data = bytearray()
    new_offsets: dict[tuple[int, int], int] = {}
    for o, n, key, k in sorted(pieces):
        new_offsets[(key, k)] = head + len(data)
        data += buf[o:o + n]
    for trak in (a for a in moov[1] if a[0] == b'trak'):
        stbl = find(find(find(trak[1], b'mdia')[1], b'minf')[1], b'stbl')[1]
        offsets, _, kind = chunks(stbl)
        rewritten = [new_offsets[(id(stbl), k)] for k in range(len(offsets))]
        for atom in stbl:
            if atom[0] == kind:
                atom[0] = b'stco'
                atom[1] = atom[1][:4] + struct.pack(f'>I{len(rewritten)}I', len(rewritten), *rewritten)
    with open(dst, 'wb') as out:
        out.write(serialize([ftyp, [b'mdat', bytes(data)], moov]))


if __name__ == '__main__':
    main(sys.argv[1], sys.argv[2])
