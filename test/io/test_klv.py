"""MISB KLV reading: framing, ST0601 and EG0104 decoding, checksums and timing on real files.

References: the MISB example packet below; kwiver's own test expectations for the same bytes
(Kitware/kwiver arrows/klv/tests/test_klv_0601.cxx and arrows/ffmpeg/tests/test_video_input_ffmpeg.cxx);
and, for the real EG0104 video, geometry cross-checks between independently sent items.
"""
from __future__ import annotations

import math
import shutil
from datetime import datetime, timezone
from fractions import Fraction

import av
import numpy as np
import pytest

from srmosaic_ros.errors import MetadataError
from srmosaic_ros.io.klv import (
    EG0104_KEY,
    ST0601_KEY,
    _Joiner,
    _split_items,
    _TrackBuilder,
    decode_eg0104,
    decode_st0601,
    read_klv,
    split_klv,
)
from repo_paths import TEST_DATA

DATA = TEST_DATA / 'real' / 'klv'
ST0601_FILES = ['h264_klv.ts', 'h265_klv.ts', 'mpeg2_klv.ts']

# MISB ST 0902 Annex C "Dynamic Only" example: a ST0601 packet with the ST0601 example values
# (tags 2, 5-7, 13-25, 65 and the checksum 0x5C2B), short-form length 0x61.
MISB_EXAMPLE = bytes.fromhex(
    '060e2b34020b01010e0103010100000061'
    '020800046050584e0180050271c20602fd3d070208b8'
    '0d045595b66d0e045b5360c40f02c2211002cd9c1102d917'
    '1204724a0a20130487f84b8614047dc55ece150403830926'
    '160212811704f101a229180414bc082b190234f3410106'
    '01025c2b'
)

# kwiver's decoded values for these exact raw bytes (test_klv_0601.cxx expected_result)
KWIVER_0601 = {
    'platform_heading_deg': 159.97436484321355,
    'platform_pitch_deg': -0.4315317239906003,  # tag 6 (short range)
    'platform_roll_deg': 3.4058656575212867,  # tag 7
    'sensor_latitude_deg': 60.176822966978335,
    'sensor_longitude_deg': 128.42675904204452,
    'sensor_altitude_m': 14190.719462882427,
    'sensor_hfov_deg': 144.57129777981231,
    'sensor_vfov_deg': 152.64362554360267,
    'sensor_rel_azimuth_deg': 160.71921143697557,
    'sensor_rel_elevation_deg': -168.79232483394085,
    'sensor_rel_roll_deg': 176.86543764939194,
    'slant_range_m': 68590.983298744770,
    'target_width_m': 722.81986724650960,
    'frame_center_latitude_deg': -10.542388633146132,
    'frame_center_longitude_deg': 29.157890122923018,
    'frame_center_elevation_m': 3216.0372320134275,
}

# the example values the standard lists (ST0601 section 8), with half the item's resolution as tolerance
STANDARD_0601 = {
    'platform_heading_deg': (159.9744, 360 / 65535 / 2),
    'platform_pitch_deg': (-0.4315251, 40 / 65534 / 2),
    'platform_roll_deg': (3.405814, 100 / 65534 / 2),
    'sensor_latitude_deg': (60.1768229669783, 180 / (2**32 - 2) / 2),
    'sensor_longitude_deg': (128.426759042045, 360 / (2**32 - 2) / 2),
    'sensor_altitude_m': (14190.72, 19900 / 65535 / 2),
    'sensor_hfov_deg': (144.5713, 180 / 65535 / 2),
    'sensor_vfov_deg': (152.6436, 180 / 65535 / 2),
    'sensor_rel_azimuth_deg': (160.719211474396, 360 / (2**32 - 1) / 2),
    'sensor_rel_elevation_deg': (-168.792324833941, 360 / (2**32 - 2) / 2),
    'sensor_rel_roll_deg': (176.865437690572, 360 / (2**32 - 1) / 2),
    'slant_range_m': (68590.98, 0.005),  # listed to the centimetre, coarser than the item
    'target_width_m': (722.8199, 10000 / 65535 / 2),
    'frame_center_latitude_deg': (-10.5423886331461, 180 / (2**32 - 2) / 2),
    'frame_center_longitude_deg': (29.157890122923, 360 / (2**32 - 2) / 2),
    'frame_center_elevation_m': (3216.037, 19900 / 65535 / 2),
}


def bcc16(data: bytes) -> int:
    """The standard's own checksum loop: bcc += buf[i] << (8 * ((i + 1) % 2))."""
    bcc = 0
    for i, b in enumerate(data):
        bcc += b << (8 * ((i + 1) % 2))
    return bcc & 0xFFFF


def first_data_packet(name: str) -> bytes:
    with av.open(str(DATA / name)) as container:
        for packet in container.demux(container.streams.data[0]):
            if packet.size:
                return bytes(packet)
    raise AssertionError(name)


def value_of(item: bytes) -> bytes:
    """The value of the first KLV item in item."""
    return split_klv(item)[0][1]


def frame_stamps_ns(name: str) -> list[int]:
    """Frame stamps as VideoReader makes them: pts minus the first decoded frame's pts."""
    with av.open(str(DATA / name)) as container:
        stream = container.streams.video[0]
        pts = [f.pts for f in container.decode(stream)]
        tb = stream.time_base
    return [round(float((p - pts[0]) * tb) * 1e9) for p in pts]


# --- framing ----------------------------------------------------------------------------------

def test_split_short_and_long_form_and_concatenated_items():
    aphill = first_data_packet('aphill_short.ts')
    assert aphill[16:19] == b'\x82\x02\x17'  # long form, 2 length bytes
    (key, value), = split_klv(aphill)
    assert key == EG0104_KEY and len(value) == 0x217
    (key, value), = split_klv(MISB_EXAMPLE)  # short form
    assert key == ST0601_KEY and len(value) == 0x61

    items = split_klv(b'\x00\xff\x47' + MISB_EXAMPLE + aphill + MISB_EXAMPLE[:40])
    assert [k for k, _ in items] == [ST0601_KEY, EG0104_KEY]  # leading junk skipped, cut tail dropped
    assert items[1][1] == value_of(aphill)
    parsed, junk, tail = _split_items(b'\x00\xff' + MISB_EXAMPLE + MISB_EXAMPLE[:40])
    assert (len(parsed), junk, tail) == (1, 1, MISB_EXAMPLE[:40])


def test_checksum_covers_key_and_length_bytes():
    value = value_of(MISB_EXAMPLE)
    long_form = MISB_EXAMPLE[:16] + b'\x81\x61' + value  # same value, length in long form
    assert split_klv(long_form) == [(ST0601_KEY, value)]
    assert decode_st0601(value, packet=long_form)[1] is False  # the sum now includes 0x81
    fixed = long_form[:-2] + bcc16(long_form[:-2]).to_bytes(2, 'big')
    assert decode_st0601(value_of(fixed), packet=fixed)[1] is True


def test_item_cut_across_pes_packets_is_joined():
    aphill = first_data_packet('aphill_short.ts')
    joiner = _Joiner()
    assert joiner.feed(MISB_EXAMPLE + aphill[:300]) == [(ST0601_KEY, value_of(MISB_EXAMPLE), MISB_EXAMPLE)]
    assert joiner.feed(aphill[300:]) == [(EG0104_KEY, value_of(aphill), aphill)]
    assert (joiner.carry, joiner.malformed) == (b'', 0)
    joiner.feed(aphill[:300])
    assert joiner.feed(MISB_EXAMPLE) == [(ST0601_KEY, value_of(MISB_EXAMPLE), MISB_EXAMPLE)]
    assert joiner.malformed == 1  # the cut item's rest never came


# --- ST0601 -----------------------------------------------------------------------------------

def test_st0601_misb_example_field_by_field():
    assert bcc16(MISB_EXAMPLE[:-2]) == 0x5C2B
    fields, ok = decode_st0601(value_of(MISB_EXAMPLE), packet=MISB_EXAMPLE)
    assert ok is True
    assert fields['precision_time_us'] == 1231798102000000
    assert datetime.fromtimestamp(fields['precision_time_us'] / 1e6, timezone.utc) == datetime(
        2009, 1, 12, 22, 8, 22, tzinfo=timezone.utc)
    assert fields['ls_version'] == 6
    for name, expected in KWIVER_0601.items():
        assert fields[name] == pytest.approx(expected, rel=1e-12, abs=1e-12), name
    for name, (nominal, half_lsb) in STANDARD_0601.items():
        assert abs(fields[name] - nominal) <= half_lsb, name
    assert 'raw' not in fields and 'corner_latitude_deg' not in fields  # every item decoded; no corners sent
    assert set(fields) == set(KWIVER_0601) | {'precision_time_us', 'ls_version'}


def test_st0601_corrupted_copies_fail_checksum():
    value = value_of(MISB_EXAMPLE)
    flipped = bytearray(MISB_EXAMPLE)
    flipped[20] ^= 0x01  # a bit of the time stamp (tag 2 value at bytes 19-26)
    fields, ok = decode_st0601(value_of(bytes(flipped)), packet=bytes(flipped))
    assert ok is False and fields['precision_time_us'] != 1231798102000000
    wrong_sum = MISB_EXAMPLE[:-1] + b'\x2a'
    assert decode_st0601(value_of(wrong_sum), packet=wrong_sum)[1] is False
    assert decode_st0601(value, packet=wrong_sum)[1] is False  # value and packet disagree
    no_sum = value[:-4]  # checksum item removed (a producer that omits it)
    assert decode_st0601(no_sum, packet=MISB_EXAMPLE[:16] + bytes([len(no_sum)]) + no_sum)[1] is False
    assert decode_st0601(value)[1] is None  # nothing to verify against


def test_st0601_reserved_values_are_nan_and_unknown_tags_raw():
    value = bytes.fromhex(
        '0d0480000000'  # sensor latitude: 0x80000000 = N/A (off-earth)
        '06028000'  # pitch: 0x8000 = out of range ...
        '5a0480000000'  # ... and so is the full-range pitch
        '07020000'  # roll 0 (short range) ...
        '5b04c0000001'  # ... the full-range roll wins: -45 degrees
        '814803010203'  # tag 200 (two-byte BER-OID 81 48), unknown
        '1403ffffff'  # relative roll sent with a length the standard does not allow
    )
    fields, ok = decode_st0601(value)
    assert ok is None
    assert math.isnan(fields['sensor_latitude_deg'])
    assert math.isnan(fields['platform_pitch_deg'])
    assert fields['platform_roll_deg'] == pytest.approx(-45.0, abs=1e-7)
    assert fields['raw'] == {200: b'\x01\x02\x03', 20: b'\xff\xff\xff'}
    assert 'sensor_rel_roll_deg' not in fields


@pytest.mark.parametrize('name', ST0601_FILES)
def test_st0601_fixture_first_packet_matches_kwiver(name):
    track = read_klv(DATA / name)
    assert (len(track.records), track.packets, track.bad_checksum) == (30, 30, 0)
    assert track.standards == {'ST0601': 30}
    assert (track.malformed, track.error) == (0, '')
    assert track.stream == 'stream #1 (KLVA, asynchronous)'
    assert all(r.pts_ns is None and r.checksum_ok is True for r in track.records)
    f = track.records[0].fields
    assert f['precision_time_us'] == 0x000459F4A6AA4AA8  # 2008-10-24 00:13:29.913 UTC
    assert (f['mission_id'], f['platform_designation'], f['image_source_sensor']) == ('MISSION01', 'MQ1-B', 'EO')
    assert f['ls_version'] == 17
    for key in KWIVER_0601.keys() - {'platform_pitch_deg', 'platform_roll_deg'}:
        assert f[key] == pytest.approx(KWIVER_0601[key], rel=1e-12), key
    # full-range pitch and roll (tags 90/91) take precedence over tags 6/7
    assert f['platform_pitch_deg'] == pytest.approx(-0.43152510208614409, rel=1e-12)
    assert f['platform_roll_deg'] == pytest.approx(3.4058139815022304, rel=1e-12)
    # full corners (tags 82-89), kwiver's values; they agree with frame centre + offsets 26-33
    full_lat = (-10.528728394084018, -10.546048884534299, -10.553450817499986, -10.541326436466223)
    full_lon = (29.161550416220702, 29.171550361985130, 29.152729888052090, 29.145729909253181)
    assert f['corner_latitude_deg'] == pytest.approx(full_lat, rel=1e-12)
    assert f['corner_longitude_deg'] == pytest.approx(full_lon, rel=1e-12)
    offsets_lat = (0.013660084841456343, -0.0036599322489089632, -0.011062196722312082, 0.0010620441297647023)
    offsets_lon = (0.0036599322489089632, 0.013660084841456343, -0.005159154026917325, -0.01216086306344798)
    assert np.allclose(np.array(full_lat) - f['frame_center_latitude_deg'], offsets_lat, atol=3e-6)
    assert np.allclose(np.array(full_lon) - f['frame_center_longitude_deg'], offsets_lon, atol=3e-6)
    # tags 4, 8, 9, 12, 34-64, ... up to 142 (a two-byte BER-OID) are kept raw and counted
    assert track.unknown_keys['ST0601 tag 142'] == 30
    assert f['raw'][59] == b'TOP GUN'
    steps = np.diff([r.fields['precision_time_us'] for r in track.records])
    assert set(steps.tolist()) == {33333, 33334}  # 30 Hz, in demux order


def local_set_items(value: bytes) -> list[tuple[int, bytes]]:
    """(tag, whole item bytes) of a ST0601 value: BER-OID tag, BER length, value."""
    out, pos = [], 0
    while pos < len(value):
        start, tag = pos, 0
        while True:
            tag = (tag << 7) | (value[pos] & 0x7F)
            pos += 1
            if not value[pos - 1] & 0x80:
                break
        n = value[pos]
        length, pos = (n, pos + 1) if n < 0x80 else (
            int.from_bytes(value[pos + 1:pos + 1 + (n & 0x7F)], 'big'), pos + 1 + (n & 0x7F))
        pos += length
        out.append((tag, value[start:pos]))
    return out


def test_st0601_offsets_used_when_full_corners_absent():
    value = value_of(first_data_packet('h264_klv.ts'))
    fields, _ = decode_st0601(value)
    without_full = b''.join(item for tag, item in local_set_items(value) if not 82 <= tag <= 89)
    offset_fields, _ = decode_st0601(without_full)
    lat0 = fields['frame_center_latitude_deg']
    assert offset_fields['corner_latitude_deg'] == pytest.approx(
        tuple(lat0 + d for d in (0.013660084841456343, -0.0036599322489089632,
                                 -0.011062196722312082, 0.0010620441297647023)), abs=1e-12)
    assert np.allclose(offset_fields['corner_longitude_deg'], fields['corner_longitude_deg'], atol=3e-6)


def test_corrupted_file_counts_bad_checksum(tmp_path):
    data = bytearray((DATA / 'h264_klv.ts').read_bytes())
    at = data.find(b'MISSION01')
    assert at > 0
    data[at + 8] = ord('X')  # one payload byte of the first ST0601 packet
    copy = tmp_path / 'h264_klv_damaged.ts'
    copy.write_bytes(bytes(data))
    track = read_klv(copy)
    assert (track.bad_checksum, len(track.records), track.standards) == (1, 29, {'ST0601': 30})
    assert track.records[0].fields['mission_id'] == 'MISSION01'  # the second packet, intact


# --- EG0104 -----------------------------------------------------------------------------------

def enu_m(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    """Local east/north metres on the WGS84 ellipsoid (adequate over a few km)."""
    a, e2 = 6378137.0, 0.00669437999014
    phi = math.radians(lat0)
    n = a / math.sqrt(1 - e2 * math.sin(phi) ** 2)
    m = a * (1 - e2) / (1 - e2 * math.sin(phi) ** 2) ** 1.5
    return math.radians(lon - lon0) * n * math.cos(phi), math.radians(lat - lat0) * m


def test_aphill_eg0104_track_and_first_packet():
    packet = first_data_packet('aphill_short.ts')
    assert split_klv(packet)[0][0] == bytes.fromhex('060e2b34020101010e01010201010000')  # as the README says
    track = read_klv(DATA / 'aphill_short.ts')
    assert (len(track.records), track.packets, track.bad_checksum) == (48, 48, 0)
    assert track.standards == {'EG0104': 48} and track.unknown_keys == {}
    assert track.stream == 'stream #1 (KLVA, synchronous)'
    assert all(r.standard == 'EG0104' and r.checksum_ok is None for r in track.records)
    # kwiver's sync_metadata test: UNIX time stamps of the packets of the first five frames
    assert [r.fields['precision_time_us'] for r in track.records[:6]] == [
        1221515219356000, 1221515219396000, 1221515219426000, 1221515219456000,
        1221515219486000, 1221515219516000]

    f = track.records[0].fields
    assert f['platform_designation'] == 'ABCD'
    assert f['sensor_latitude_deg'] == 38.252336 and f['sensor_longitude_deg'] == -77.366859  # float64
    assert f['sensor_altitude_m'] == pytest.approx(1054.4, abs=1e-4)  # float32 on the wire
    assert (f['sensor_hfov_deg'], f['sensor_vfov_deg']) == pytest.approx((0.8, 0.6), abs=1e-6)
    assert f['slant_range_m'] == pytest.approx(1729.92, abs=0.01)
    assert f['platform_heading_deg'] == pytest.approx(360 - 102.7880859375, abs=1e-9)  # sent as -102.79
    assert f['sensor_elevation_deg'] == pytest.approx(-37.5539, abs=1e-4)

    # cross-checks between independently sent items
    lat0, lon0 = f['frame_center_latitude_deg'], f['frame_center_longitude_deg']
    east, north = enu_m(f['sensor_latitude_deg'], f['sensor_longitude_deg'], lat0, lon0)
    ground = math.hypot(east, north)
    depression = math.degrees(math.acos(ground / f['slant_range_m']))
    assert depression == pytest.approx(-f['sensor_elevation_deg'], abs=0.1)  # 37.57 vs 37.55
    bearing = math.degrees(math.atan2(-east, -north)) % 360  # sensor -> frame centre
    assert bearing == pytest.approx(f['sensor_azimuth_deg'], abs=2.0)  # absolute, not from the nose
    corners = [enu_m(la, lo, lat0, lon0) for la, lo in zip(f['corner_latitude_deg'], f['corner_longitude_deg'])]
    sides = [math.dist(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    across = 2 * f['slant_range_m'] * math.tan(math.radians(f['sensor_hfov_deg'] / 2))
    along = 2 * f['slant_range_m'] * math.tan(math.radians(f['sensor_vfov_deg'] / 2)) / math.sin(
        math.radians(depression))
    assert (across, along) == pytest.approx((24.2, 29.7), abs=0.1)
    assert sides == pytest.approx([across, along, across, along], abs=0.4)  # about 24 m x 30 m
    crossings = [(bx - ax) * (0 - ay) - (by - ay) * (0 - ax)  # edge x (centre - corner), z component
                 for (ax, ay), (bx, by) in zip(corners, corners[1:] + corners[:1])]
    assert all(c < 0 for c in crossings) or all(c > 0 for c in crossings)  # centre inside the quad


def test_aphill_derived_relative_angles_round_trip():
    f = read_klv(DATA / 'aphill_short.ts').records[0].fields
    assert f['derived'] == ('sensor_rel_azimuth_deg', 'sensor_rel_elevation_deg')
    h, p, r = np.radians([f['platform_heading_deg'], f['platform_pitch_deg'], f['platform_roll_deg']])
    az, el = np.radians([f['sensor_rel_azimuth_deg'], f['sensor_rel_elevation_deg']])
    rz = np.array([[np.cos(h), -np.sin(h), 0], [np.sin(h), np.cos(h), 0], [0, 0, 1]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ned = rz @ ry @ rx @ np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)])
    assert math.degrees(math.atan2(ned[1], ned[0])) % 360 == pytest.approx(f['sensor_azimuth_deg'], abs=1e-9)
    assert math.degrees(math.atan2(-ned[2], math.hypot(ned[0], ned[1]))) == pytest.approx(
        f['sensor_elevation_deg'], abs=1e-9)
    # the attitude is nearly level, so the relative azimuth is close to the plain difference
    assert f['sensor_rel_azimuth_deg'] == pytest.approx(
        (f['sensor_azimuth_deg'] - f['platform_heading_deg']) % 360, abs=2.0)


def test_aphill_one_packet_per_frame_on_the_video_clock():
    track = read_klv(DATA / 'aphill_short.ts')
    stamps = frame_stamps_ns('aphill_short.ts')
    pts = [r.pts_ns for r in track.records]
    assert len(pts) == len(stamps) == 48
    assert all(b > a for a, b in zip(pts, pts[1:]))
    # each packet is muxed with the PTS of the frame before it: one frame period of lead
    assert pts[1:] == stamps[:-1]
    assert pts[0] == round(float(Fraction(-3003, 90000)) * 1e9) == -33366667


def test_eg0104_elements_without_their_set_make_one_record():
    value = value_of(first_data_packet('aphill_short.ts'))
    wrapped = decode_eg0104(value)
    items, junk, tail = _split_items(value)  # the set's elements, as older streams send them
    assert (len(items), junk, tail) == (23, 0, b'')
    builder = _TrackBuilder()
    builder.add_packet(items, 0)
    track = builder.track
    assert (track.packets, track.standards, len(track.records)) == (23, {'EG0104': 1}, 1)
    assert track.records[0].fields == wrapped


def crc32_mpeg2(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for b in data:
        crc ^= b << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7) & 0xFFFFFFFF if crc & 0x80000000 else (crc << 1) & 0xFFFFFFFF
    return crc


def test_klv_found_by_key_when_the_pmt_lacks_the_klva_descriptor(tmp_path):
    data = bytearray((DATA / 'aphill_short.ts').read_bytes())
    patched = 0
    for at in range(0, len(data), 188):  # rename the registration descriptor in every PMT copy
        ts = data[at:at + 188]
        j = ts.find(b'\x05\x04KLVA')
        if j < 0:
            continue
        start = 4 + (1 + ts[4] if ts[3] & 0x20 else 0)  # skip an adaptation field
        start += 1 + ts[start]  # pointer field
        end = start + 3 + (((ts[start + 1] & 0x0F) << 8) | ts[start + 2])  # section end, CRC included
        assert crc32_mpeg2(bytes(ts[start:end - 4])) == int.from_bytes(ts[end - 4:end], 'big')
        ts[j + 2:j + 6] = b'XXXX'
        ts[end - 4:end] = crc32_mpeg2(bytes(ts[start:end - 4])).to_bytes(4, 'big')
        data[at:at + 188] = ts
        patched += 1
    assert patched > 0
    copy = tmp_path / 'aphill_no_klva.ts'
    copy.write_bytes(bytes(data))
    with av.open(str(copy)) as container:
        assert container.streams.data[0].name != 'klv'  # FFmpeg no longer labels it
    track = read_klv(copy)
    assert track.stream == 'stream #1 (data, KLV keys found, synchronous)'
    assert (len(track.records), track.records[1].pts_ns) == (48, 0)


# --- files without KLV, and files that are not video ---------------------------------------------

def test_video_without_klv_gives_empty_track():
    track = read_klv(DATA / 'h264_no_klv.ts')
    assert (track.records, track.packets, track.stream, track.standards) == ([], 0, '', {})


def test_not_a_video_raises_metadata_error(tmp_path):
    with pytest.raises(MetadataError, match='LICENSE.*cannot be opened'):
        read_klv(DATA / 'LICENSE')
    with pytest.raises(MetadataError, match='does not exist'):
        read_klv(tmp_path / 'missing.ts')
    shutil.copy(DATA / 'LICENSE', tmp_path / 'notes.ts')
    with pytest.raises(MetadataError, match='notes.ts'):
        read_klv(tmp_path / 'notes.ts')
