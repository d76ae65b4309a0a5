"""GoPro GPMF telemetry on the real karma.mp4 (HERO5 Black on a Karma drone), its GPMF track kept
byte for byte in test/data/real/gopro/karma_telemetry.mp4 (see the folder's README.md).

Reference values were decoded independently by GoPro's own gpmf-parser C library (through the
py-gpmf-parser 0.1.1 bindings, GPMF_ScaledData): they are not produced by the code under test.
"""
from __future__ import annotations

import dataclasses
import math
from datetime import datetime, timezone

import av
import numpy as np
import pytest

from srmosaic_ros.errors import InputError, MetadataError
from srmosaic_ros.core.georef.georeferencer import Georeferencer
from srmosaic_ros.core.georef.georef_config import GeorefConfig
from srmosaic_ros.core.types import CameraAttitude, GeoFix
from srmosaic_ros.io.gpmf import GpsSample, read_gpmf
from srmosaic_ros.io.metadata import MetadataSummary, gpmf_items
from repo_paths import TEST_DATA

KARMA = TEST_DATA / 'real' / 'gopro' / 'karma_telemetry.mp4'
VIDEO_END_NS = 12_078_733_333  # 1087086 / 90000 s: the original video track's duration (362 frames)


@pytest.fixture(scope='module')
def karma():
    return read_gpmf(KARMA)


def test_payloads_devices_and_counts(karma):
    assert karma.payloads == 13
    assert karma.device == 'Camera, GoPro Karma v1.0'
    assert karma.skipped == {}
    # sample totals equal the streams' own TSMP counters in the last payload
    assert (len(karma.accel), len(karma.gyro), len(karma.gps)) == (2397, 4795, 47)
    assert karma.orientation == []  # CORI starts with HERO8


def test_gps_comes_from_the_karma_receiver(karma):
    # The HERO5 wrote no GPS5 (its GPS was off): the fixes are the drone's "GPS RAW" (GPRI).
    assert karma.gps_source == 'GPRI'
    first, last = karma.gps[0], karma.gps[-1]
    # gpmf-parser: GPRI first [145.911705, 33.125368, -117.3310641, 15.445, 0.25, 0.42, 0.59, 334.35, 3, 20]
    assert first == GpsSample(stamp_ns=0, latitude_deg=33.125368, longitude_deg=-117.3310641, altitude_m=15.445,
                              speed_2d_m_s=0.59, fix=3, dop=0.25, utc_ns=first.utc_ns)
    # gpmf-parser: GPRI last [157.615923, 33.126003, -117.3314762, 16.167, 0.27, 0.41, 8.09, 331.15, 3, 20]
    assert (last.latitude_deg, last.longitude_deg, last.altitude_m, last.speed_2d_m_s, last.fix, last.dop) == (
        33.126003, -117.3314762, 16.167, 8.09, 3, 0.27)
    assert {g.fix for g in karma.gps} == {3}
    assert all(15.3 < g.altitude_m < 16.7 for g in karma.gps)


def test_gps_utc_from_the_drone_clock(karma):
    # SYST (boot 146.544283 s = UNIX 1492457278.0 s) maps GPRI's boot time 145.911705 s to UTC.
    assert karma.gps[0].utc_ns == 1_492_457_277_367_422_000
    assert karma.gps[-1].utc_ns == 1_492_457_289_072_353_000
    # independent check: the MP4's creation_time is 2017-04-17T19:27:57Z
    created = datetime(2017, 4, 17, 19, 27, 57, tzinfo=timezone.utc).timestamp()
    assert abs(karma.gps[0].utc_ns / 1e9 - created) < 1.0


def test_gps_stamps_spread_over_each_payload(karma):
    stamps = [g.stamp_ns for g in karma.gps]
    assert stamps[:5] == [0, 250_250_000, 500_500_000, 750_750_000, 1_001_000_000]
    assert stamps == sorted(stamps)
    rate_hz = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9)
    assert 3.5 < rate_hz < 4.5  # the Karma logs GPS at about 4 Hz, not the HERO5's 18 Hz


def test_imu_values_match_gpmf_parser(karma):
    assert karma.accel[0] == (0, (10.157894736842104, -0.8516746411483254, -3.700956937799043))
    assert karma.accel[-1][1] == (9.961722488038278, -4.117224880382775, 2.8014354066985647)
    assert karma.gyro[0] == (0, (0.04580559254327563, 0.018641810918774968, 0.033288948069241014))
    assert karma.gyro[-1][1] == (-0.7944074567243675, -0.009587217043941412, 0.005858854860186418)
    magnitude = np.linalg.norm(np.array([a for _, a in karma.accel]), axis=1)
    assert 9.7 < float(magnitude.mean()) < 9.9  # gravity: the drone cruises without accelerating much


def test_last_payload_keeps_the_stream_rate(karma):
    # The closing payload (12.012 s) holds 14 ACCL and 28 GYRO samples but the MP4 gives it 1.001 s:
    # spread at the streams' own rates they end with the video (within a few ms) instead of 0.9 s after.
    last_payload = [s for s, _ in karma.accel if s >= 12_012_000_000]
    assert len(last_payload) == 14
    step = np.diff(last_payload)
    assert np.all((step > 4_900_000) & (step < 5_200_000))  # about 200 Hz
    assert abs(karma.accel[-1][0] - VIDEO_END_NS) < 5_000_000
    assert abs(karma.gyro[-1][0] - VIDEO_END_NS) < 5_000_000


def test_the_karma_drone_attitude_and_gimbal_angles(karma):
    """ATTD (MAVLink ATTITUDE) and CYTS (the gimbal, "Coyote Status"), both TYPE structs; reference
    values unpacked with struct from the KLV bytes ('>Lffffffb', '>LLLLLfffBB')."""
    assert (len(karma.platform_attitude), len(karma.gimbal_angles)) == (47, 48)
    assert karma.platform_attitude[0] == (0, (-0.07731033116579056, -0.1803593933582306, -0.4963531494140625))
    assert karma.platform_attitude[-1] == (11_761_750_000, (-0.028938211500644684, -0.10744842886924744,
                                                            -0.5208327770233154))
    assert karma.gimbal_angles[0] == (0, (-0.00022660930699203163, 0.00017213367391377687, -0.04088740050792694))
    assert karma.gimbal_angles[-1][1] == (0.0001054052117979154, 6.725257844664156e-05, -0.010097235441207886)
    # the drone's yaw follows its course over ground (about 330 deg: north-north-west along the coast)
    first, last = karma.gps[0], karma.gps[-1]
    north = (last.latitude_deg - first.latitude_deg) * 111_320.0
    east = (last.longitude_deg - first.longitude_deg) * 111_320.0 * math.cos(math.radians(first.latitude_deg))
    course = math.degrees(math.atan2(east, north))
    yaws = [math.degrees(a[2]) for _, a in karma.platform_attitude[8:]]  # past the start's acceleration
    assert all(abs(y - course) < 6.0 for y in yaws), (course, yaws)
    # the gimbal levels the camera (2.3 deg below to 0.1 deg above the horizon) while the drone pitches 5-22 deg nose down
    assert all(abs(g[0]) < 0.01 and abs(g[1]) < 0.01 and -0.05 < g[2] < 0.01 for _, g in karma.gimbal_angles)
    assert all(-0.4 < a[1] < -0.09 for _, a in karma.platform_attitude)


def test_mp4_without_gpmf_gives_an_empty_track(tmp_path):
    path = tmp_path / 'plain.mp4'
    with av.open(str(path), 'w') as out:
        stream = out.add_stream('mpeg4', rate=25)
        stream.width, stream.height, stream.pix_fmt = 64, 48, 'yuv420p'
        for i in range(3):
            frame = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 40 * i, np.uint8), format='rgb24')
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    track = read_gpmf(path)
    assert (track.payloads, track.gps, track.accel, track.device, track.gps_source) == (0, [], [], '', '')


def test_cut_file_is_a_metadata_error(tmp_path):
    path = tmp_path / 'cut.mp4'
    path.write_bytes(KARMA.read_bytes()[:4096])  # the moov index is at the end: gone
    with pytest.raises(MetadataError, match='cut.mp4'):
        read_gpmf(path)


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match='does not exist'):
        read_gpmf(tmp_path / 'GOPR0001.MP4')


def test_stamps_are_finite_integers(karma):
    for seq in (karma.accel, karma.gyro):
        assert all(isinstance(s, int) for s, _ in seq)
        assert all(math.isfinite(v) for _, values in seq for v in values)


def test_karma_camera_attitudes_for_the_filter(karma):
    """metadata.gpmf_items: at each gimbal sample the camera's line of sight has the drone's yaw
    (clockwise from north) and the gimbal's tilt below the horizon; the fixes are as before."""
    summary = MetadataSummary()
    items = gpmf_items(karma, summary)
    fixes = [i for i in items if isinstance(i, GeoFix)]
    attitudes = [i for i in items if isinstance(i, CameraAttitude)]
    assert (len(fixes), len(attitudes)) == (47, 48)
    assert [i.stamp_ns for i in items] == sorted(i.stamp_ns for i in items)
    assert (summary.frames_with_position, summary.frames_with_attitude) == (47, 48)
    assert "Karma drone attitude and gimbal tilt" in summary.fields
    yaw_t = np.array([s for s, _ in karma.platform_attitude], dtype=float)
    yaw = np.unwrap([a[2] for _, a in karma.platform_attitude])
    for att, (stamp, (_, _, tilt)) in zip(attitudes, karma.gimbal_angles):
        axis = att.R_enu_from_cam[:, 2]  # the optical axis in ENU
        assert att.stamp_ns == stamp
        assert math.degrees(math.asin(axis[2])) == pytest.approx(math.degrees(tilt), abs=1e-6)
        heading = math.degrees(math.atan2(axis[0], axis[1]))
        assert (heading - math.degrees(np.interp(stamp, yaw_t, yaw)) + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)
        down = att.R_enu_from_cam[:, 1]  # image down: level (no roll), below the horizon
        assert abs(float(np.dot(att.R_enu_from_cam[:, 0], (0.0, 0.0, 1.0)))) < 1e-9 and down[2] < 0.0
    assert any('2.3 deg below the horizon to 0.1 deg above the horizon (at the horizon' in n for n in summary.notes)


def test_karma_take_off_altitude_is_the_ground_prior(karma):
    """GLPI (MAVLink GLOBAL_POSITION_INT: altitude above mean sea level and height above the take-off
    point, mm; raw first sample 15711, 2003): their difference, constant to 1 mm over the clip, is
    the take-off point's altitude, in the fixes' datum (GPRI: mean sea level too)."""
    assert len(karma.heights) == 47
    assert karma.heights[0] == (0, (15.711, 2.003)) and karma.heights[-1][1] == (16.223, 2.515)
    summary = MetadataSummary()
    gpmf_items(karma, summary)
    assert summary.ground_altitude_m == pytest.approx(13.708, abs=1e-9)
    assert summary.ground_altitude_sigma_m == 5.0 and 'take-off' in summary.ground_altitude_source
    summary = MetadataSummary()  # fixes in another datum (a camera's GPS5: the ellipsoid): no prior from MSL heights
    gpmf_items(dataclasses.replace(karma, gps_source='GPS5'), summary)
    assert math.isnan(summary.ground_altitude_m)


def test_karma_gimbal_samples_rolled_or_panned_are_left_out(karma):
    """The CYTS angles' meaning is read off karma.mp4, where the gimbal is level and follows the
    heading; samples where it is not are not guessed at."""
    panned = [(s, (g[0], math.radians(30.0), g[2]) if k % 2 else g) for k, (s, g) in enumerate(karma.gimbal_angles)]
    summary = MetadataSummary()
    items = gpmf_items(dataclasses.replace(karma, gimbal_angles=panned), summary)
    assert sum(isinstance(i, CameraAttitude) for i in items) == 24
    assert summary.problems['gpmf_gimbal_not_level'] == 24
    summary = MetadataSummary()
    items = gpmf_items(dataclasses.replace(karma, platform_attitude=[]), summary)
    assert not any(isinstance(i, CameraAttitude) for i in items)
    assert any('only one of the drone attitude' in n for n in summary.notes)


def test_karma_attitudes_at_the_horizon_are_not_fused(karma):
    """The camera looks 0.1 above to 2.3 deg below the horizon: no ground plane in view, and the
    georeferencer leaves every one of them out (counted), as it does any camera at the horizon."""
    georef = Georeferencer(GeorefConfig())
    for att in (i for i in gpmf_items(karma, MetadataSummary()) if isinstance(i, CameraAttitude)):
        georef.feed_camera_attitude(att)
    assert georef.skipped['camera_attitude_horizon'] == 48
