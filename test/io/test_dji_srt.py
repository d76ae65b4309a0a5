"""DJI .SRT telemetry on real files of every generation (test/data/real/dji_srt, see its README.md).

Expected values are copied from the files' own text: the first and last good block of each file.
"""
from __future__ import annotations

import math
from datetime import datetime, timezone

import pytest

from srmosaic_ros.errors import InputError, MetadataError
from srmosaic_ros.io.dji_srt import find_srt, read_srt
from repo_paths import TEST_DATA

DATA = TEST_DATA / 'real' / 'dji_srt'
NAN = math.nan

# file, format, blocks, samples, skipped,
#   first and last sample: (index, start_ns, end_ns, local date-time or None, lat, lon, altitude_m,
#                           relative_altitude_m, gimbal_ypr_deg, flight_ypr_deg, focal_length_mm)
PARSED = [
    ('MAVIC3_first50.srt', 'mavic3', 50, 50, {},
     (1, 0, 20_000_000, '2021-12-25T12:27:52.373000', 3.41531, -3.3744, 0.401, -2.4, None, None, 24.0),
     (50, 980_000_000, 1_000_000_000, '2021-12-25T12:27:53.350000', 3.41531, -3.3744, 0.401, -2.4, None, None, 24.0)),
    ('air2s.srt', 'air2', 17, 17, {},
     (1, 0, 33_000_000, '2022-08-07T13:40:40.774808', 41.424724, 2.234156, 117.0, NAN, None, None, 24.0),
     (17, 533_000_000, 567_000_000, '2022-08-07T13:40:41.308639', 41.42473, 2.234102, 117.1, NAN, None, None, 24.0)),
    ('broken_incomplete.SRT', 'mavic_pro_2017', 20, 19, {'no_gps': 1},
     (1, 1_000_000_000, 2_000_000_000, '2017-07-03T10:15:03.000000', -34.7383, -58.4563, NAN, 20.1, None, None, None),
     (19, 19_000_000_000, 20_000_000_000, '2017-07-03T10:15:21.000000', -34.7383, -58.4563, NAN, 7.7, None, None,
      None)),
    ('broken_incomplete2.SRT', 'mavic2', 6, 4, {'no_gps': 2},
     (1, 0, 40_000_000, '2020-08-12T08:55:21.745078', -34.86995, -57.823395, 74.725998, NAN, None, None, 28.0),
     (5, 160_000_000, 200_000_000, '2020-08-12T08:55:21.905078', -34.869945, -57.823383, 74.725998, NAN, None, None,
      28.0)),
    ('m2zoom_first50.SRT', 'mavic2', 50, 50, {},
     (1, 0, 16_000_000, '2020-04-02T15:19:58.720764', 31.452012, 74.398751, 213.983002, NAN, None, None, 24.0),
     (50, 817_000_000, 834_000_000, '2020-04-02T15:19:59.538248', 31.452012, 74.398751, 213.983994, NAN, None, None,
      24.0)),
    ('matrice_300.srt', 'm300', 381, 381, {},
     (1, 0, 1_000_000_000, '2022-06-21T16:06:17.000000', 36.6146, -6.112, NAN, 0.3, None, None, None),
     (381, 380_000_000_000, 381_000_000_000, '2022-06-21T16:12:37.000000', 36.6146, -6.112, NAN, 0.0, None, None,
      None)),
    ('mavic_2pro_new_first50.SRT', 'mavic2', 50, 50, {},
     (1, 0, 40_000_000, '2019-09-27T10:28:08.438904', -35.080155, -60.286702, NAN, NAN, None, None, 28.0),
     (50, 2_360_000_000, 2_440_000_000, '2019-09-27T10:28:10.798919', -35.080369, -60.286585, NAN, NAN, None, None,
      28.0)),
    ('mavic_air2.srt', 'air2', 25, 25, {},
     (1, 0, 16_000_000, '2022-05-01T15:01:58.531716', 41.420684, 2.162162, 27.3, NAN, None, None, 24.0),
     (25, 400_000_000, 416_000_000, '2022-05-01T15:01:58.931885', 41.420686, 2.162162, 29.2, NAN, None, None, 24.0)),
    ('mavic_mini.SRT', 'p4p_mini', 117, 117, {},
     (1, 0, 1_000_000_000, None, 48.0771, -121.7458, NAN, 200.7, None, None, None),
     (117, 116_000_000_000, 117_000_000_000, None, 48.0775, -121.7476, NAN, 200.8, None, None, None)),
    ('mavic_pro.SRT', 'mavic_pro_2017', 468, 468, {},
     (1, 1_000_000_000, 2_000_000_000, '2017-08-05T14:11:51.000000', -20.2533, 149.0251, NAN, 1.9, None, None, None),
     (468, 468_000_000_000, 469_000_000_000, '2017-08-05T14:19:39.000000', -20.2532, 149.0251, NAN, 0.0, None, None,
      None)),
    ('mavic_pro_buggy.SRT', 'mavic_pro_2017', 546, 530, {'no_gps': 16},
     (1, 1_000_000_000, 2_000_000_000, '2018-08-19T08:00:36.000000', 42.4668, -1.2218, NAN, 0.0, None, None, None),
     (546, 546_000_000_000, 547_000_000_000, '2018-08-19T08:09:42.000000', 42.4668, -1.2217, NAN, 15.8, None, None,
      None)),
    ('mix_p4rtk_mavic2pro.srt', 'p4rtk+mavic2', 12, 12, {},
     (1, 904_904_000_000, 905_905_000_000, None, -34.6502, -59.409424, NAN, 17.39, (-76.0, -27.3, 0.0),
      (-75.0, -8.9, 2.9), None),
     (12, 910_242_000_000, 910_276_000_000, '2020-10-07T12:00:10.403182', -34.65118, -59.409483, 120.140999, NAN,
      None, None, 28.0)),
    ('old_format.SRT', 'old_gps_lon_lat', 468, 468, {},
     (1, 1_000_000_000, 2_000_000_000, '2017-08-05T14:11:51.000000', -20.2533, 149.0251, NAN, 1.9, None, None, None),
     (468, 468_000_000_000, 469_000_000_000, '2017-08-05T14:19:39.000000', -20.2532, 149.0251, NAN, 0.0, None, None,
      None)),
    ('p4_rtk.SRT', 'p4rtk', 55, 55, {},
     (1, 0, 1_000_000_000, None, -34.237922, -58.851745, NAN, 85.8, (110.4, -24.4, 0.0), (110.1, 2.7, -7.0), None),
     (55, 54_000_000_000, 55_000_000_000, None, -34.232349, -58.849196, NAN, 85.8, (111.9, -24.4, 0.0),
      (109.2, 8.4, -20.1), None)),
    ('p4p_sample.SRT', 'p4p_mini', 5, 5, {},
     (1, 0, 1_000_000_000, None, 47.4692, 8.209, NAN, 45.6, None, None, None),
     (5, 4_000_000_000, 5_000_000_000, None, 47.4692, 8.209, NAN, 45.6, None, None, None)),
]

REFUSED = [
    ('broken_empty.SRT', ['is empty (0 bytes)']),
    ('broken_empty2.SRT', ['no subtitle timing lines', 'in its 2 lines']),
    ('mavic_2_style.SRT', ['no subtitle timing lines', 'in its 1872 lines', 'Use the .SRT the drone recorded']),
    ('mavic_air.SRT', ['none of its 2 subtitle blocks has a usable position', 'no_gps: 2', 'format mavic2',
                       '--telemetry']),
]


def _same(actual: float, expected: float) -> bool:
    return math.isnan(expected) and math.isnan(actual) or actual == expected


def _local(utc_ns: int | None) -> str | None:
    if utc_ns is None:
        return None
    return datetime.fromtimestamp(utc_ns / 1e9, timezone.utc).strftime('%Y-%m-%dT%H:%M:%S.%f')


def _check(sample, expected) -> None:
    index, start, end, when, lat, lon, alt, rel, gimbal, flight, focal = expected
    assert (sample.index, sample.start_ns, sample.end_ns) == (index, start, end)
    assert _local(sample.utc_ns) == when
    assert (sample.latitude_deg, sample.longitude_deg) == (lat, lon)
    assert _same(sample.altitude_m, alt), sample.altitude_m
    assert _same(sample.relative_altitude_m, rel), sample.relative_altitude_m
    assert sample.gimbal_ypr_deg == gimbal
    assert sample.flight_ypr_deg == flight
    assert sample.focal_length_mm == focal


@pytest.mark.parametrize(('name', 'fmt', 'blocks', 'count', 'skipped', 'first', 'last'), PARSED,
                         ids=[p[0] for p in PARSED])
def test_reads_every_generation(name, fmt, blocks, count, skipped, first, last):
    track = read_srt(DATA / name)
    assert track.path == DATA / name
    assert track.format == fmt
    assert track.blocks == blocks
    assert len(track.samples) == count
    assert track.skipped == skipped
    assert track.blocks == count + sum(skipped.values())
    _check(track.samples[0], first)
    _check(track.samples[-1], last)
    starts = [s.start_ns for s in track.samples]
    assert starts == sorted(set(starts))  # strictly in time order


@pytest.mark.parametrize(('name', 'fragments'), REFUSED, ids=[r[0] for r in REFUSED])
def test_refuses_files_with_nothing_usable(name, fragments):
    with pytest.raises(MetadataError) as info:
        read_srt(DATA / name)
    message = str(info.value)
    assert name in message
    for fragment in fragments:
        assert fragment in message


def test_every_fixture_is_parsed_or_refused():
    names = {p.name for p in DATA.iterdir() if p.suffix.lower() == '.srt'}
    assert names == {p[0] for p in PARSED} | {r[0] for r in REFUSED}


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match='does not exist'):
        read_srt(tmp_path / 'DJI_0001.SRT')


def test_raw_camera_settings_and_satellites_stay_in_extra():
    old = read_srt(DATA / 'old_format.SRT').samples[0].extra
    assert {k: old[k] for k in ('iso', 'shutter', 'ev', 'fnum', 'hs', 'satellites', 'home')} == {
        'iso': '100', 'shutter': '60', 'ev': '0', 'fnum': 'F2.8', 'hs': '1.9', 'satellites': '16',
        'home': '149.0251, -20.2532'}
    pro = read_srt(DATA / 'mavic_pro.SRT').samples[0].extra
    assert (pro['shutter'], pro['fnum'], pro['ev'], pro['satellites']) == ('60', '2.2', '', '16')
    rtk = read_srt(DATA / 'p4_rtk.SRT').samples[0].extra
    assert {k: rtk[k] for k in ('fnum', 'shutter', 'iso', 'ev', 'distance', 'h_speed', 'v_speed', 'home')} == {
        'fnum': '5.6', 'shutter': '400', 'iso': '100', 'ev': '0', 'distance': '698.70m', 'h_speed': '0.00m/s',
        'v_speed': '0.00m/s', 'home': '-58.847509, -34.232707, -57.98m'}
    m2 = read_srt(DATA / 'm2zoom_first50.SRT').samples[0].extra
    assert {k: m2[k] for k in ('frame_cnt', 'diff_time', 'iso', 'shutter', 'fnum', 'ct', 'color_md', 'focal_len')} == {
        'frame_cnt': '1', 'diff_time': '16ms', 'iso': '120', 'shutter': '1/2500.0', 'fnum': '280', 'ct': '5003',
        'color_md': 'default', 'focal_len': '240'}
    m3 = read_srt(DATA / 'MAVIC3_first50.srt').samples[0].extra
    assert (m3['fnum'], m3['focal_len'], m3['frame_cnt']) == ('3.2', '24.00', '1')
    assert 'latitude' not in m3 and 'abs_alt' not in m3  # typed fields are not repeated in extra


def test_m300_is_latitude_first_and_its_minute_ends_at_sixty_seconds():
    track = read_srt(DATA / 'matrice_300.srt')
    by_index = {s.index: s for s in track.samples}
    minute = by_index[60]  # "00:00:59,000 --> 00:00:60,000", GPS(36.6153,-6.1130,0.0M) BAROMETER:83.8M
    assert (minute.start_ns, minute.end_ns) == (59_000_000_000, 60_000_000_000)
    assert (minute.latitude_deg, minute.longitude_deg, minute.relative_altitude_m) == (36.6153, -6.1130, 83.8)
    assert math.isnan(minute.altitude_m) and minute.extra['gps_altitude'] == '0.0M'
    assert max(s.relative_altitude_m for s in track.samples) == 87.9


def test_blocks_without_a_position_are_counted_not_returned():
    buggy = read_srt(DATA / 'mavic_pro_buggy.SRT')  # its GPS(N/A,N/A,3) blocks while locking
    indices = {s.index for s in buggy.samples}
    assert not indices & set(range(15, 31))
    assert buggy.skipped == {'no_gps': 16}


def test_zero_positions_before_the_gps_lock_are_skipped(tmp_path):
    # Air 2 firmware writes [latitude: 0.000000] [longitude: 0.000000] until its GPS locks: the
    # first three blocks of the real air2s.srt rewritten that way.
    text = (DATA / 'air2s.srt').read_text(encoding='utf-8')
    blocks = text.split('\n\n')
    for i in range(3):
        head, _, _ = blocks[i].partition('[latitude:')
        blocks[i] = head + '[latitude: 0.000000] [longitude: 0.000000] [altitude: 0.000000] </font>'
    path = tmp_path / 'DJI_0001.SRT'
    path.write_text('\n\n'.join(blocks), encoding='utf-8')
    track = read_srt(path)
    assert track.skipped == {'zero_position': 3}
    assert [s.index for s in track.samples] == list(range(4, 18))


def test_duplicate_and_out_of_order_blocks_are_skipped(tmp_path):
    blocks = (DATA / 'p4p_sample.SRT').read_text(encoding='utf-8').strip().split('\n\n\n')
    assert len(blocks) == 5
    path = tmp_path / 'joined.SRT'
    path.write_text('\n\n'.join([blocks[0], blocks[1], blocks[1], blocks[3], blocks[2], blocks[4]]) + '\n',
                    encoding='utf-8')
    track = read_srt(path)
    assert [s.index for s in track.samples] == [1, 2, 4, 5]
    assert track.skipped == {'duplicate': 1, 'out_of_order': 1}
    assert track.blocks == 6


def test_attitude_brackets_of_later_models(tmp_path):
    # Lines as other readers document them (Mavic 3T "[gb_yaw: ..]", older "[Drone: Yaw:..]"),
    # appended to the real MAVIC3 blocks: no such file is in the fixtures.
    blocks = (DATA / 'MAVIC3_first50.srt').read_text(encoding='utf-8').strip().split('\n\n')[:2]
    blocks = [b.replace(' </font>', ' [gb_yaw: -142.5 gb_pitch: -28.7 gb_roll: 0.0] '
                        '[Drone: Yaw:147.9, Pitch:4.5, Roll:-0.1] </font>') for b in blocks]
    path = tmp_path / 'm3t.srt'
    path.write_text('\n\n'.join(blocks) + '\n', encoding='utf-8')
    sample = read_srt(path).samples[0]
    assert sample.gimbal_ypr_deg == (-142.5, -28.7, 0.0)
    assert sample.flight_ypr_deg == (147.9, 4.5, -0.1)
    assert (sample.latitude_deg, sample.altitude_m, sample.relative_altitude_m) == (3.41531, 0.401, -2.4)


def test_find_srt_beside_a_video(tmp_path):
    (tmp_path / 'DJI_0001.MP4').touch()
    (tmp_path / 'DJI_0001.SRT').touch()
    (tmp_path / 'DJI_0002.mp4').touch()
    (tmp_path / 'dji_0002.srt').touch()
    (tmp_path / 'DJI_0003.MP4').touch()
    (tmp_path / 'DJI_0003.srt').touch()
    (tmp_path / 'DJI_0003.SRT').touch()
    (tmp_path / 'DJI_0004.MP4').touch()
    (tmp_path / 'DJI_0004.txt').touch()
    assert find_srt(tmp_path / 'DJI_0001.MP4') == tmp_path / 'DJI_0001.SRT'
    assert find_srt(tmp_path / 'DJI_0002.mp4') == tmp_path / 'dji_0002.srt'
    assert find_srt(tmp_path / 'DJI_0003.MP4') == tmp_path / 'DJI_0003.SRT'
    assert find_srt(tmp_path / 'DJI_0004.MP4') is None
    assert find_srt(tmp_path / 'missing' / 'DJI_0005.MP4') is None
