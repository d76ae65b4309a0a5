"""MISB ST0601 UAS Datalink Local Set: the tag table, the integer mappings and the checksum.

Field names, units and angle conventions: klv.py's module docstring.
"""
from __future__ import annotations

import math

from .klv_framing import _ber_length, _text

__all__ = ['ST0601_KEY', 'decode_st0601']

ST0601_KEY = bytes.fromhex('060e2b34020b01010e01030101000000')  # UAS Datalink Local Set


def _map_unsigned(lo: float, hi: float):
    """ST0601 fixed mapping of an unsigned integer onto [lo, hi]: lo + v * (hi - lo) / (2^n - 1)."""
    def convert(raw: bytes) -> float:
        return lo + int.from_bytes(raw, 'big') * (hi - lo) / float((1 << (8 * len(raw))) - 1)
    return convert


def _map_signed(half: float):
    """ST0601 fixed mapping of a signed integer onto [-half, half]: v * 2 half / (2^n - 2).

    The most negative value (0x80.., "out of range", "error" or "N/A off-earth") becomes NaN.
    """
    def convert(raw: bytes) -> float:
        v = int.from_bytes(raw, 'big', signed=True)
        if v == -(1 << (8 * len(raw) - 1)):
            return math.nan
        return v * (2.0 * half) / float((1 << (8 * len(raw))) - 2)
    return convert


def _uint(raw: bytes) -> int:
    return int.from_bytes(raw, 'big')



# tag -> (field name, value length in bytes or None for any, converter); names starting with '_'
# are intermediate values combined below (pitch/roll sources, corner offsets and full corners)
_ST0601_TAGS = {
    2: ('precision_time_us', 8, _uint),
    3: ('mission_id', None, _text),
    5: ('platform_heading_deg', 2, _map_unsigned(0.0, 360.0)),
    6: ('_pitch_short', 2, _map_signed(20.0)),
    7: ('_roll_short', 2, _map_signed(50.0)),
    10: ('platform_designation', None, _text),
    11: ('image_source_sensor', None, _text),
    13: ('sensor_latitude_deg', 4, _map_signed(90.0)),
    14: ('sensor_longitude_deg', 4, _map_signed(180.0)),
    15: ('sensor_altitude_m', 2, _map_unsigned(-900.0, 19000.0)),
    16: ('sensor_hfov_deg', 2, _map_unsigned(0.0, 180.0)),
    17: ('sensor_vfov_deg', 2, _map_unsigned(0.0, 180.0)),
    18: ('sensor_rel_azimuth_deg', 4, _map_unsigned(0.0, 360.0)),
    19: ('sensor_rel_elevation_deg', 4, _map_signed(180.0)),
    20: ('sensor_rel_roll_deg', 4, _map_unsigned(0.0, 360.0)),
    21: ('slant_range_m', 4, _map_unsigned(0.0, 5.0e6)),
    22: ('target_width_m', 2, _map_unsigned(0.0, 10000.0)),
    23: ('frame_center_latitude_deg', 4, _map_signed(90.0)),
    24: ('frame_center_longitude_deg', 4, _map_signed(180.0)),
    25: ('frame_center_elevation_m', 2, _map_unsigned(-900.0, 19000.0)),
    **{26 + 2 * i: (f'_offset_lat{i}', 2, _map_signed(0.075)) for i in range(4)},
    **{27 + 2 * i: (f'_offset_lon{i}', 2, _map_signed(0.075)) for i in range(4)},
    65: ('ls_version', 1, _uint),
    **{82 + 2 * i: (f'_full_lat{i}', 4, _map_signed(90.0)) for i in range(4)},
    **{83 + 2 * i: (f'_full_lon{i}', 4, _map_signed(180.0)) for i in range(4)},
    90: ('_pitch_full', 4, _map_signed(90.0)),
    91: ('_roll_full', 4, _map_signed(90.0)),
}


def _ber_oid(data: bytes, pos: int) -> tuple[int, int] | None:
    """(tag, position after it) of a BER-OID tag (7 bits a byte, high bit = more follow)."""
    tag = 0
    while pos < len(data):
        byte = data[pos]
        pos += 1
        tag = (tag << 7) | (byte & 0x7F)
        if not byte & 0x80:
            return tag, pos
    return None


def _st0601_checksum(packet: bytes) -> int:
    """Running 16-bit sum over packet[:-2] with even offsets as high bytes (ST0601 section 6)."""
    body = packet[:-2]
    total = sum(body[0::2]) * 256 + sum(body[1::2])
    return total & 0xFFFF


def _first_finite(*values: object) -> float | None:
    present = [v for v in values if isinstance(v, float)]
    for v in present:
        if not math.isnan(v):
            return v
    return present[0] if present else None


def decode_st0601(value: bytes, *, packet: bytes | None = None) -> tuple[dict, bool | None]:
    """Fields of one ST0601 local set value (the bytes after key and length), and its checksum state.

    packet: the whole item (key + length + value) as it was received, needed to verify the checksum;
    without it the second result is None. With it: True when tag 1 is the last item and matches,
    False otherwise (missing, misplaced or wrong, or a packet that does not end with value).
    Unknown tags, and known tags sent with a length the standard does not allow, go raw into
    ``fields['raw']``; a value cut short ends the decoding.
    """
    value = bytes(value)
    raw: dict[int, bytes] = {}
    tmp: dict[str, object] = {}
    checksum_at: tuple[int, bytes] | None = None  # (offset after it in value, its bytes)
    pos = 0
    while pos < len(value):
        tag_pos = _ber_oid(value, pos)
        if tag_pos is None:
            break
        tag, pos = tag_pos
        length_pos = _ber_length(value, pos)
        if length_pos is None or length_pos[1] + length_pos[0] > len(value):
            break
        length, pos = length_pos
        item = value[pos:pos + length]
        pos += length
        if tag == 1:
            checksum_at = (pos, item)
            continue
        spec = _ST0601_TAGS.get(tag)
        if spec is None or (spec[1] is not None and spec[1] != length):
            raw[tag] = item
            continue
        tmp[spec[0]] = spec[2](item)

    fields: dict[str, object] = {k: v for k, v in tmp.items() if not k.startswith('_')}
    pitch = _first_finite(tmp.get('_pitch_full'), tmp.get('_pitch_short'))
    roll = _first_finite(tmp.get('_roll_full'), tmp.get('_roll_short'))
    if pitch is not None:
        fields['platform_pitch_deg'] = pitch
    if roll is not None:
        fields['platform_roll_deg'] = roll
    full = [tmp.get(f'_full_{axis}{i}') for axis in ('lat', 'lon') for i in range(4)]
    offsets = [tmp.get(f'_offset_{axis}{i}') for axis in ('lat', 'lon') for i in range(4)]
    if all(v is not None for v in full):
        fields['corner_latitude_deg'] = tuple(full[:4])
        fields['corner_longitude_deg'] = tuple(full[4:])
    elif (all(v is not None for v in offsets) and 'frame_center_latitude_deg' in fields
          and 'frame_center_longitude_deg' in fields):
        lat0 = float(fields['frame_center_latitude_deg'])  # type: ignore[arg-type]
        lon0 = float(fields['frame_center_longitude_deg'])  # type: ignore[arg-type]
        fields['corner_latitude_deg'] = tuple(lat0 + float(v) for v in offsets[:4])  # type: ignore[arg-type]
        fields['corner_longitude_deg'] = tuple(lon0 + float(v) for v in offsets[4:])  # type: ignore[arg-type]
    if raw:
        fields['raw'] = raw

    if packet is None:
        return fields, None
    packet = bytes(packet)
    if (checksum_at is None or checksum_at[0] != len(value) or len(checksum_at[1]) != 2
            or not packet.endswith(value)):
        return fields, False
    return fields, _st0601_checksum(packet) == int.from_bytes(checksum_at[1], 'big')
