"""MISB EG0104 Predator UAV Basic Universal Metadata Set: its keys, values and derived pointing.

Field names, units and angle conventions: klv.py's module docstring.
"""
from __future__ import annotations

import math
import struct

from .klv_framing import _text, split_klv

__all__ = ['EG0104_KEY', 'decode_eg0104']

EG0104_KEY = bytes.fromhex('060e2b34020101010e01010201010000')  # Predator UAV Basic Universal Set


def _float(raw: bytes) -> float | None:
    if len(raw) == 4:
        return float(struct.unpack('>f', raw)[0])
    if len(raw) == 8:
        return float(struct.unpack('>d', raw)[0])
    return None


def _uint64(raw: bytes) -> int | None:
    return int.from_bytes(raw, 'big') if len(raw) == 8 else None


def _wrapped(raw: bytes) -> float | None:
    v = _float(raw)
    return None if v is None else v % 360.0


# Keys 06 0E 2B 34 01 01 01 vv + these 8 bytes (vv, the registry version, is ignored). Taken from
# Kitware kwiver arrows/klv/klv_0104.cxx (BSD-3-Clause, itself from EG0104.5 and the EG0104
# mapping in ST0601.12), with two variants seen in OSSIM ossimPredator/ossimPredatorKlvTable.cxx
# (frame centre elevation 07 01 02 03 10, platform designation 01 01 21 01).
_EG0104_ITEMS: dict[bytes, tuple[str, object]] = {bytes.fromhex(k): v for k, v in {
    '0702010101050000': ('precision_time_us', _uint64),  # User Defined Time Stamp / UNIX Timestamp
    '0105050000000000': ('mission_id', _text),  # Episode Number
    '0101200100000000': ('platform_designation', _text),  # Device Designation
    '0101210100000000': ('platform_designation', _text),
    '0420010201010000': ('image_source_sensor', _text),  # Image Source Device
    '0701100106000000': ('platform_heading_deg', _wrapped),
    '0701100105000000': ('platform_pitch_deg', _float),
    '0701100104000000': ('platform_roll_deg', _float),
    '0701020102040200': ('sensor_latitude_deg', _float),  # Device Latitude
    '0701020102060200': ('sensor_longitude_deg', _float),
    '0701020102020000': ('sensor_altitude_m', _float),  # Device Altitude, MSL
    '0420020101080000': ('sensor_hfov_deg', _float),
    '04200201010a0100': ('sensor_vfov_deg', _float),
    '0701080101000000': ('slant_range_m', _float),
    '0701090201000000': ('target_width_m', _float),
    '0701020103020000': ('frame_center_latitude_deg', _float),
    '0701020103040000': ('frame_center_longitude_deg', _float),
    '0701020103160000': ('frame_center_elevation_m', _float),
    '0701020310000000': ('frame_center_elevation_m', _float),
    '0701020103070100': ('_corner_lat0', _float),
    '0701020103080100': ('_corner_lat1', _float),
    '0701020103090100': ('_corner_lat2', _float),
    '07010201030a0100': ('_corner_lat3', _float),
    '07010201030b0100': ('_corner_lon0', _float),
    '07010201030c0100': ('_corner_lon1', _float),
    '07010201030d0100': ('_corner_lon2', _float),
    '07010201030e0100': ('_corner_lon3', _float),
    '0701100102000000': ('sensor_azimuth_deg', _wrapped),  # Angle to North
    '0701100103000000': ('sensor_elevation_deg', _float),  # Obliquity Angle
    '0701100101000000': ('sensor_roll_deg', _float),  # Sensor Roll Angle
}.items()}
_EG0104_ITEM_PREFIX = bytes.fromhex('060e2b34010101')


def _eg0104_item(key: bytes) -> tuple[str, object] | None:
    if len(key) != 16 or key[:7] != _EG0104_ITEM_PREFIX:
        return None
    return _EG0104_ITEMS.get(key[8:])


def _relative_pointing(fields: dict[str, object]) -> tuple[float, float] | None:
    """ST0601-style (relative azimuth, relative elevation) of an absolute line of sight, degrees."""
    names = ('platform_heading_deg', 'platform_pitch_deg', 'platform_roll_deg',
             'sensor_azimuth_deg', 'sensor_elevation_deg')
    vals = [fields.get(n) for n in names]
    if not all(isinstance(v, float) and math.isfinite(v) for v in vals):
        return None
    h, p, r, az, el = (math.radians(float(v)) for v in vals)  # type: ignore[arg-type]
    # line of sight in north-east-down, then into the body frame: d_b = Rx(r)^T Ry(p)^T Rz(h)^T d_n
    n, e, d = math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)
    n, e = math.cos(h) * n + math.sin(h) * e, -math.sin(h) * n + math.cos(h) * e
    n, d = math.cos(p) * n - math.sin(p) * d, math.sin(p) * n + math.cos(p) * d
    e, d = math.cos(r) * e + math.sin(r) * d, -math.sin(r) * e + math.cos(r) * d
    rel_az = math.degrees(math.atan2(e, n)) % 360.0
    rel_el = math.degrees(math.atan2(-d, math.hypot(n, e)))
    return rel_az, rel_el


def _eg0104_fields(items: list[tuple[bytes, bytes]]) -> dict:
    tmp: dict[str, object] = {}
    raw: dict[str, bytes] = {}
    for key, value in items:
        spec = _eg0104_item(key)
        decoded = spec[1](value) if spec is not None else None  # type: ignore[operator]
        if decoded is None:
            raw[key.hex()] = value
            continue
        tmp[spec[0]] = decoded  # type: ignore[index]
    fields: dict[str, object] = {k: v for k, v in tmp.items() if not k.startswith('_')}
    lats = [tmp.get(f'_corner_lat{i}') for i in range(4)]
    lons = [tmp.get(f'_corner_lon{i}') for i in range(4)]
    if all(v is not None for v in lats + lons):
        fields['corner_latitude_deg'] = tuple(lats)
        fields['corner_longitude_deg'] = tuple(lons)
    rel = _relative_pointing(fields)
    if rel is not None:
        fields['sensor_rel_azimuth_deg'], fields['sensor_rel_elevation_deg'] = rel
        fields['derived'] = ('sensor_rel_azimuth_deg', 'sensor_rel_elevation_deg')
    if raw:
        fields['raw'] = raw
    return fields


def decode_eg0104(value: bytes) -> dict:
    """Fields of one EG0104 universal set value (the bytes after its key and length).

    Each element is a 16-byte universal key + BER length + big-endian value: IEEE float32 or
    float64 (by length) for angles, positions and distances, uint64 microseconds for the time
    stamp, text for names. Unknown or oddly sized elements go raw into ``fields['raw']``.
    """
    return _eg0104_fields(split_klv(value))
