"""MISB KLV metadata in MPEG-TS video: the ST0601 UAS Datalink Local Set and the legacy EG0104 set.

Demultiplexing (PyAV): the KLV data stream is the first data stream FFmpeg labels ``klv`` (its PMT
entry carries the ``KLVA`` registration descriptor), else the first data stream whose first
packet starts with the SMPTE ST 336 key prefix ``06 0E 2B 34``. A stream is called synchronous
when its PES packets carry a PTS, asynchronous otherwise (ST1402); asynchronous KLV has no
container time, so its records have ``pts_ns=None`` and are timed by ``precision_time_us`` alone.
One PES packet may hold several concatenated KLV items (16-byte universal key + BER length, short
or long form); an item cut across two PES packets of a stream is joined again.

Time: ``KlvRecord.pts_ns`` is the data packet's PTS on the container clock minus the PTS of the
first decoded video frame, in ns, with the same rounding as ``VideoReader`` stamps, so a record and
the frame it was muxed with have equal stamps. It is negative for metadata sent before frame 0.

Field names and units (``KlvRecord.fields``; floats in degrees and metres, NaN where the standard's
reserved "error"/"out of range"/"off-earth" value was sent, absent when the item was not sent):
``precision_time_us`` (int, UNIX epoch microseconds, UTC without leap seconds),
``mission_id``, ``platform_designation``, ``image_source_sensor`` (str), ``ls_version`` (int, ST0601
tag 65), ``platform_heading_deg`` (clockwise from true north, [0, 360)), ``platform_pitch_deg`` (nose
up positive), ``platform_roll_deg`` (right wing down positive), ``sensor_latitude_deg``,
``sensor_longitude_deg`` (WGS84), ``sensor_altitude_m`` (true altitude, above mean sea level),
``sensor_hfov_deg``, ``sensor_vfov_deg``, ``slant_range_m``, ``target_width_m``,
``frame_center_latitude_deg``, ``frame_center_longitude_deg``, ``frame_center_elevation_m`` (MSL),
``corner_latitude_deg`` and ``corner_longitude_deg`` (tuples of 4: upper left, upper right, lower
right, lower left of the image), and the sensor pointing angles below. Items this module does not
decode are kept raw in ``fields['raw']`` (ST0601: int tag -> bytes; EG0104: hex key -> bytes) and
counted in ``KlvTrack.unknown_keys``.

Angle conventions, per standard:

- ST0601 (UAS Datalink LS) carries the platform attitude (tag 5 heading clockwise from true north,
  tag 6/90 pitch positive nose up, tag 7/91 roll positive right wing down) and the sensor angles
  RELATIVE to the platform: tag 18 ``sensor_rel_azimuth_deg`` clockwise from the platform's nose
  seen from above, [0, 360); tag 19 ``sensor_rel_elevation_deg`` from the platform's
  longitudinal-transverse plane, negative down; tag 20 ``sensor_rel_roll_deg`` about the line of
  sight, clockwise seen from behind the camera, [0, 360). The sensor pointing is the platform
  attitude (Z-Y-X: heading, pitch, roll) followed by azimuth, elevation, roll. Pitch and roll come
  from the full-range tags 90/91 when sent, else from the short-range tags 6/7. The corners come
  from the full corner tags 82-89 when all eight were sent, else from the offset tags 26-33 added
  to the frame centre.
- EG0104 (Predator UAV Basic Universal Metadata Set) carries the platform attitude as IEEE floats
  in the same sense (heading wrapped here into [0, 360)) and the sensor pointing as ABSOLUTE,
  earth-referenced angles: "Angle to North" -> ``sensor_azimuth_deg`` (clockwise from true north,
  [0, 360)), "Obliquity Angle" -> ``sensor_elevation_deg`` (from the local horizontal, negative
  below it, as the real files carry it: aphill_short.ts sends -37.55 where its slant range and
  positions give a 37.57 degree depression), "Sensor Roll Angle" -> ``sensor_roll_deg``. When the
  attitude and both pointing angles are present, ``sensor_rel_azimuth_deg`` and
  ``sensor_rel_elevation_deg`` are DERIVED from them in the ST0601 sense (the line of sight rotated
  into the platform frame), and ``fields['derived']`` names them; no relative roll is derived.

The checksum (ST0601 tag 1, the last item) is the 16-bit running sum of the whole packet, key and
length included, up to and including the checksum's own tag and length bytes, each even-offset
byte weighted 256. Packets failing it are counted in ``KlvTrack.bad_checksum`` and left out of
``records``. EG0104 has no checksum (``checksum_ok=None``).

Written by hand from the public definitions (ST0601 tags and their integer mappings, checked in
the tests against kwiver's decoded values; EG0104.5 keys as listed in Kitware kwiver
arrows/klv/klv_0104.cxx and in OSSIM's ossimPredatorKlvTable.cxx); the
``klvdata`` package (0.0.3) is not used because it cannot decode these files (its tag-73 parser
raises on every kwiver ST0601 packet, it reads only one-byte tags, does not verify the checksum,
raises on the reserved error values and has no EG0104).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

from ..errors import MetadataError

__all__ = [
    'EG0104_KEY',
    'ST0601_KEY',
    'KlvRecord',
    'KlvTrack',
    'decode_eg0104',
    'decode_st0601',
    'read_klv',
    'split_klv',
]

ST0601_KEY = bytes.fromhex('060e2b34020b01010e01030101000000')  # UAS Datalink Local Set
EG0104_KEY = bytes.fromhex('060e2b34020101010e01010201010000')  # Predator UAV Basic Universal Set
_UL_PREFIX = b'\x06\x0e\x2b\x34'  # every SMPTE universal label starts so (ST 336)
_SNIFF_PACKETS = 200  # data packets inspected to find KLV in a stream FFmpeg did not label


@dataclass(frozen=True)
class KlvRecord:
    """One decoded KLV set (a ST0601 local set, or an EG0104 universal set).

    pts_ns: presentation time of its data packet in ns from the first video frame (None for an
    asynchronous stream); standard: 'ST0601' or 'EG0104'; fields: see the module docstring;
    checksum_ok: True for a verified ST0601 checksum, None when the standard has none.
    """

    pts_ns: int | None
    standard: str
    fields: dict[str, object]
    checksum_ok: bool | None


@dataclass
class KlvTrack:
    """All KLV of a file: good records in pts order (demux order when asynchronous) and counts.

    packets: top-level KLV items seen; bad_checksum: ST0601 packets that failed their checksum
    (not in records); unknown_keys: hex key (or 'ST0601 tag N') -> count of items not decoded;
    standards: 'ST0601'/'EG0104' -> sets seen, bad checksums included; stream: which stream
    was read, '' when the file has none; malformed: items cut short or bytes that are not KLV;
    error: why demultiplexing stopped early ('' when it read to the end).
    """

    records: list[KlvRecord]
    packets: int
    bad_checksum: int
    unknown_keys: dict[str, int]
    standards: dict[str, int]
    stream: str
    malformed: int = 0
    error: str = ''


# ---------------------------------------------------------------------------------------------
# KLV framing (SMPTE ST 336)


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


# ---------------------------------------------------------------------------------------------
# MISB ST0601 UAS Datalink Local Set


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


def _text(raw: bytes) -> str:
    # ST0601 strings are ISO 646 (a subset of UTF-8); some producers pad with NULs
    return raw.decode('utf-8', errors='replace').rstrip('\x00').strip()


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


# ---------------------------------------------------------------------------------------------
# MISB EG0104 Predator UAV Basic Universal Metadata Set


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


# ---------------------------------------------------------------------------------------------
# Demultiplexing


def _find_klv_stream(container):
    """The KLV data stream and whether FFmpeg labelled it, or (None, False)."""
    data_streams = list(container.streams.data)
    for stream in data_streams:
        if getattr(stream, 'name', None) == 'klv':
            return stream, True
    if not data_streams:
        return None, False
    # some muxers omit the KLVA descriptor: look for universal keys in the first packets
    seen = 0
    for packet in container.demux(*data_streams):
        payload = bytes(packet)
        if payload:
            if payload.startswith(_UL_PREFIX):
                return packet.stream, False
            seen += 1
            if seen >= _SNIFF_PACKETS:
                break
    return None, False


def _first_frame_seconds(path: Path) -> Fraction | None:
    """PTS of the first decoded video frame in seconds (the VideoReader origin), None without video."""
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                return None
            stream = container.streams.video[0]
            time_base = stream.time_base or Fraction(1, 90000)
            try:
                for frame in container.decode(stream):
                    if frame.pts is not None:
                        return frame.pts * time_base
                    break
            except av.error.FFmpegError:  # undecodable video: fall back to the declared start
                pass
            if stream.start_time is not None:
                return stream.start_time * time_base
    except (av.error.FFmpegError, OSError):  # opened once already; timing then counts from the KLV
        return None
    return None


class _Joiner:
    """Splits successive PES payloads into KLV items, joining an item cut across two of them.

    A payload that does not start with a key prefix continues the previous payload's unfinished
    item; one that does means that item was lost (counted in ``malformed`` with non-KLV runs).
    """

    def __init__(self) -> None:
        self.carry = b''
        self.malformed = 0

    def feed(self, payload: bytes) -> list[tuple[bytes, bytes, bytes]]:
        if self.carry and not payload.startswith(_UL_PREFIX):
            payload = self.carry + payload
        elif self.carry:
            self.malformed += 1
        items, junk, self.carry = _split_items(payload)
        self.malformed += junk
        return items


class _TrackBuilder:
    """Accumulates decoded items of one stream into a KlvTrack."""

    def __init__(self) -> None:
        self.track = KlvTrack([], 0, 0, {}, {}, '')

    def _unknown(self, key: str) -> None:
        self.track.unknown_keys[key] = self.track.unknown_keys.get(key, 0) + 1

    def _standard(self, name: str) -> None:
        self.track.standards[name] = self.track.standards.get(name, 0) + 1

    def add_packet(self, items: list[tuple[bytes, bytes, bytes]], pts_ns: int | None) -> None:
        loose: list[tuple[bytes, bytes]] = []  # EG0104 elements sent without their set
        for key, value, whole in items:
            self.track.packets += 1
            if _same_ul(key, ST0601_KEY):
                self._standard('ST0601')
                fields, ok = decode_st0601(value, packet=whole)
                for tag in fields.get('raw', {}):
                    self._unknown(f'ST0601 tag {tag}')
                if ok:
                    self.track.records.append(KlvRecord(pts_ns, 'ST0601', fields, True))
                else:
                    self.track.bad_checksum += 1
            elif _same_ul(key, EG0104_KEY):
                self._standard('EG0104')
                self._add_eg0104(split_klv(value), pts_ns)
            elif _eg0104_item(key) is not None:
                loose.append((key, value))
            else:
                self._unknown(key.hex())
        if loose:
            self._standard('EG0104')
            self._add_eg0104(loose, pts_ns)

    def _add_eg0104(self, items: list[tuple[bytes, bytes]], pts_ns: int | None) -> None:
        fields = _eg0104_fields(items)
        for key in fields.get('raw', {}):
            self._unknown(key)
        self.track.records.append(KlvRecord(pts_ns, 'EG0104', fields, None))


def _open(path: Path):
    import av

    try:
        return av.open(str(path))
    except (av.error.FFmpegError, OSError) as exc:  # not a media file, a damaged header, no access
        msg = (f'KLV: {str(path)!r} cannot be opened as a video container ({exc}); MISB KLV is read '
               'from MPEG transport streams (.ts): check that this is one and that the copy is complete.')
        raise MetadataError(msg) from None


def _read_stream(path: Path, container, stream, builder: _TrackBuilder) -> int:
    """Demultiplex the KLV stream into the builder; returns how many packets carried a PTS."""
    import av

    track = builder.track
    time_base: Fraction = stream.time_base or Fraction(1, 90000)
    origin: Fraction | None = None
    joiner = _Joiner()
    with_pts = 0
    try:
        for packet in container.demux(stream):
            payload = bytes(packet)
            if not payload:
                continue  # the demuxer's flush packet
            pts = packet.pts if packet.pts is not None else packet.dts
            pts_ns = None
            if pts is not None:
                with_pts += 1
                if origin is None:
                    origin = _first_frame_seconds(path)
                    if origin is None:  # no video: count from the first KLV packet instead
                        origin = pts * time_base
                pts_ns = round(float(pts * time_base - origin) * 1e9)
            builder.add_packet(joiner.feed(payload), pts_ns)
    except av.error.FFmpegError as exc:  # damage mid-file: keep what was read
        track.error = f'demultiplexing stopped after {track.packets} KLV items: {exc}'
    track.malformed += joiner.malformed + bool(joiner.carry)
    return with_pts


def read_klv(path: str | Path) -> KlvTrack:
    """Every KLV set of a video file (MPEG-TS), decoded; an empty track when it carries none.

    Raises MetadataError when the file is missing or cannot be opened as a media container.
    A packet failing its checksum or cut short is counted and skipped, never raised.
    """
    path = Path(path)
    if not path.is_file():
        msg = f'KLV: {str(path)!r} does not exist; check the path.'
        raise MetadataError(msg)
    builder = _TrackBuilder()
    track = builder.track
    with _open(path) as container:
        stream, labelled = _find_klv_stream(container)
        if stream is None:
            return track
        index = stream.index
        if labelled:
            with_pts = _read_stream(path, container, stream, builder)
    if not labelled:  # sniffing consumed packets: demultiplex again from the start
        with _open(path) as container:
            with_pts = _read_stream(path, container, container.streams[index], builder)
    timing = 'synchronous' if with_pts else 'asynchronous'
    kind = 'KLVA' if labelled else 'data, KLV keys found'
    track.stream = f'stream #{index} ({kind}, {timing})'
    if track.records and all(r.pts_ns is not None for r in track.records):
        track.records.sort(key=lambda r: r.pts_ns)  # type: ignore[arg-type, return-value]
    return track
