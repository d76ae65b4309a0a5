"""GPS and intrinsics but no measured attitude (no Imu orientation, gimbal or KLV angles): the
filter's camera is only the assumed mount, nadir by default (issue 17, found on a GoPro Karma
clip). An oblique camera must not be pulled onto that assumption: the mosaic is chained, and not
georeferenced by its geotags either (its frame centres do not follow them), the report saying why. A nadir camera is still placed by
its poses from the first frame, its figures unchanged."""
from __future__ import annotations

import dataclasses
import logging
import math

import pytest

from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.app.process import not_georeferenced_reason, write_outputs
from srmosaic_ros.config import PipelineConfig
from srmosaic_ros.core.georef.frames import R_enu_from_cam_aviation
from srmosaic_ros.core.types import CameraAttitude
from srmosaic_ros.core.georef.pose_check import MIN_INNOVATIONS, check_pose_placement, mount_axis_angle_deg
from srmosaic_ros.io.metadata import merge_by_time
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, save_truth
from flights import simulated

# test_sim_orbit.py's orbit: 52 frames of 160 x 120 circling at 80 m, 58 deg below the horizon
ORBIT = {'trajectory': 'orbit', 'orbit_radius_m': 50.0, 'laps': 1.1, 'altitude_m': 80.0, 'hfov_deg': 40.0,
         'width': 160, 'height': 120, 'speed_m_s': 10.0, 'rate_hz': 1.5, 'seed': 4}
NADIR = {'trajectory': 'line', 'frames': 20, 'rate_hz': 4.0, 'altitude_m': 80.0, 'width': 160, 'height': 120,
         'world': 'data/worlds/caliterra_IMG_9360.jpg', 'seed': 5}


def _run(cfg: SimConfig, tmp_path, factory, *, imu: bool = False, horizon_attitudes: bool = False):
    """(PipelineResult, report, truth figures) of a simulated flight fed with its fixes (and its Imu
    samples when ``imu``; a camera attitude 1 deg below the horizon at every fix when
    ``horizon_attitudes``), the frames carrying their intrinsics; default configuration (nadir mount).
    The flight is simulated once for the session (test/flights.py): three tests here and
    test_sim_orbit.py take the orbit."""
    flight = simulated(factory, cfg)
    telemetry = flight.fixes + (flight.imus if imu else [])
    if horizon_attitudes:  # what karma.mp4's Karma gimbal records: measured, but no ground in view
        telemetry += [CameraAttitude(f.stamp_ns, R_enu_from_cam_aviation(0.0, -1.0, 0.0), math.radians(1.0))
                      for f in flight.fixes]
    config = PipelineConfig()
    pipeline = Pipeline(config)
    for item in merge_by_time(flight.frames, sorted(telemetry, key=lambda x: x.stamp_ns)):
        pipeline.feed(item)
    result = pipeline.finish()
    report = write_outputs(result, tmp_path, config, {})
    save_truth(flight.truth, tmp_path / 'truth.json')
    return result, report, evaluate_dir(tmp_path, tmp_path / 'truth.json')


def test_oblique_orbit_without_attitude_is_chained_not_forced_to_nadir(tmp_path, tmp_path_factory, caplog) -> None:
    """Before the check, drift control pulled every frame toward a nadir footprint: corner error
    4.78 px mean (14.0 max) against the truth; chained, 0.083 px (0.19 max), as without intrinsics."""
    with caplog.at_level(logging.WARNING, logger='srmosaic_ros.pipeline'):
        result, report, fig = _run(SimConfig(**ORBIT), tmp_path, tmp_path_factory)
    assert fig['frames_registered'] == fig['frames_in'] == 52
    assert fig['corner_error_mean_px'] < 0.3, fig  # measured 0.083 px (4.78 px when forced to nadir)
    assert [seg.georeferenced for seg in result.segments] == [False]
    placement = report['pose_placement']
    assert placement['used'] is False and placement['attitude'] == 'not measured'
    assert placement['median_nis'] > placement['gate_nis'] and placement['innovations'] >= MIN_INNOVATIONS
    assert 'mount' in placement['reason'] and 'nadir' in placement['reason']
    # Nor by its geotags (placed by them, it was 178 m RMS off on the map): its frames see the first
    # one's plane obliquely (median depth ratio 2.1), and their centres stay near the orbit's centre
    # while the geotags go round (fit residual 47.9 m RMS over a 49.5 m track).
    assert report['georeferenced'] is None
    reason = not_georeferenced_reason(result, PipelineConfig())  # report.json's, as `process` writes it
    assert 'do not look straight down' in reason and 'georef.gimbal_elevation_deg' in reason
    said = ' '.join(r.getMessage() for r in caplog.records)
    assert 'not placed by the filter' in said and 'georef.gimbal_elevation_deg' in said


def test_oblique_orbit_with_its_imu_is_not_checked(tmp_path, tmp_path_factory) -> None:
    """A measured attitude: the filter's camera is not an assumption, and nothing is decided."""
    cfg = SimConfig(**{**ORBIT, 'laps': 0.3})
    result, report, _ = _run(cfg, tmp_path, tmp_path_factory, imu=True)
    assert result.pose_check is None and 'pose_placement' not in report


def test_nadir_flight_without_attitude_is_placed_by_its_poses_from_the_start(tmp_path, tmp_path_factory) -> None:
    """GPS only over a nadir camera: the check passes (median NIS 1.8 against the gate 37.3) and the
    frames are on the map from the first one, as before it existed (0.048 px, 0.97 m; with
    consecutive frames tracked photometrically, registration.track_frames, 0.044 px, 1.03 m)."""
    result, report, fig = _run(SimConfig(**NADIR), tmp_path, tmp_path_factory)
    assert result.pose_check is not None and result.pose_check.used
    assert result.pose_check.median_nis < 5.0
    shown = result.pose_check.frames_mount  # the chain agrees: measured 1.9 deg off nadir (gusts of 2 deg)
    assert shown is not None and mount_axis_angle_deg((0.0, -90.0), (shown.azimuth_deg, shown.elevation_deg)) < 4.0
    assert [seg.georeferenced for seg in result.segments] == [True]
    assert report['georeferenced']['method'] == 'filter' and report['pose_placement']['used'] is True
    assert fig['frames_registered'] == 20
    assert fig['corner_error_mean_px'] == pytest.approx(0.0437, abs=0.005), fig
    assert fig['georef_error_rms_m'] == pytest.approx(1.031, abs=0.01), fig


def test_the_rule_is_the_median_innovation_against_the_filters_gate() -> None:
    mount = (0.0, -90.0)
    assert check_pose_placement([500.0] * (MIN_INNOVATIONS - 1) + [math.nan], 0.99999, mount) is None  # too few
    used = check_pose_placement([2.0, 3.0, 1.0, 900.0, 2.5], 0.99999, mount)  # one bad registration does not decide
    assert used is not None and used.used and used.reason == ''
    assert used.gate_nis == pytest.approx(37.33, abs=0.01)  # chi-square, 8 dof, at georef.gate_probability
    refused = check_pose_placement([300.0, 20.0, 400.0, 250.0, 1.0], 0.99999, (90.0, -30.0))
    assert refused is not None and not refused.used
    assert refused.median_nis == 250.0 and 'elevation -30 deg: oblique' in refused.reason


def test_attitudes_at_the_horizon_do_not_count_as_measured(tmp_path, tmp_path_factory) -> None:
    """Camera attitudes the filter cannot use (less than 5 deg below the horizon: a Karma gimbal
    levelled at the horizon) leave the orbit as unmeasured: chained, not forced to nadir, and the
    reason says first that they were left out. Counted as measured, the frames were placed on the
    nadir assumption (karma.mp4 with --hfov 110: 3 segments, consistency 0.566 instead of 0.826)."""
    result, report, fig = _run(SimConfig(**ORBIT), tmp_path, tmp_path_factory, horizon_attitudes=True)
    assert result.georef.skipped['camera_attitude_horizon'] == len(result.attitudes) > 0
    assert report['pose_placement']['used'] is False
    assert report['pose_placement']['reason'].startswith(
        'no camera attitude the filter can use was measured (only attitudes at the horizon)')
    assert [seg.georeferenced for seg in result.segments] == [False]
    assert fig['corner_error_mean_px'] < 0.3, fig
    reason = not_georeferenced_reason(result, PipelineConfig())
    assert reason.startswith(f'{len(result.attitudes)} measured camera attitude(s) look less than 5 deg below the '
                             'horizon'), reason
    assert 'do not look straight down' in reason


def test_an_orbit_starts_at_its_course_when_fixes_precede_its_frames(tmp_path_factory) -> None:
    """GPS only, the fixes 5.3 s ahead of the frames (the first 8 frames dropped), the orbit's own
    mount set: the filter's first heading comes from the fixes before the first frame. A chord
    through them lagged the turn by 36 deg (half of 5 s at 11.5 deg/s; settling NIS 28.3 against
    the gate 37.3); the track's quadratic reads it at the frame: 1.2 deg, NIS 10.1."""
    flight = simulated(tmp_path_factory, SimConfig(**ORBIT))
    config = PipelineConfig()
    config = dataclasses.replace(config, georef=dataclasses.replace(config.georef, gimbal_azimuth_deg=90.0,
                                                                    gimbal_elevation_deg=-58.0))
    pipeline = Pipeline(config)
    for item in merge_by_time(flight.frames[8:], sorted(flight.fixes, key=lambda x: x.stamp_ns)):
        pipeline.feed(item)
    result = pipeline.finish()
    first = next(p for p in pipeline.georef.poses if p.valid)
    truth = next(t for t in flight.truth.frames if t.stamp_ns == first.stamp_ns)
    assert abs((math.degrees(first.rpy_rad[2]) - truth.yaw_deg + 180.0) % 360.0 - 180.0) < 10.0
    assert result.pose_check is not None and result.pose_check.used and result.pose_check.median_nis < 20.0
