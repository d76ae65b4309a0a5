"""Oblique cameras: a camera attitude per frame (gimbal angles, KLV sensor angles) places the frames
through the ground plane, whatever the configured mount, on a simulated oblique flight with truth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from srmosaic_ros.config import PipelineConfig
from srmosaic_ros.core.georef import Georeferencer
from srmosaic_ros.core.georef.frames import (
    R_enu_from_cam_aviation,
    R_enu_from_cam_platform_sensor,
    matrix_from_rotvec,
)
from srmosaic_ros.core.types import CameraAttitude, GeoFix
from srmosaic_ros.io.metadata import merge_by_time
from srmosaic_ros.app.process import write_outputs
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, simulate

EAST, NORTH, UP = np.eye(3)


def test_gimbal_angles_give_the_optical_axes():
    R = R_enu_from_cam_aviation(0.0, -90.0, 0.0)  # nadir, yaw north: image top north, image right east
    assert np.allclose(R[:, 0], EAST) and np.allclose(R[:, 1], -NORTH) and np.allclose(R[:, 2], -UP)
    R = R_enu_from_cam_aviation(90.0, -30.0, 0.0)  # looking east, 30 deg below the horizon
    assert np.allclose(R[:, 2], [math.cos(math.radians(30)), 0.0, -0.5])
    assert np.allclose(R[:, 0], -NORTH)  # image right is south when looking east
    R = R_enu_from_cam_aviation(0.0, -90.0, 10.0)  # roll about the optical axis keeps it nadir
    assert np.allclose(R[:, 2], -UP)


def test_turret_angles_compose_platform_and_sensor():
    # a platform heading 80 deg with the sensor 10 deg right of the nose is a camera heading 90 deg
    assert np.allclose(R_enu_from_cam_platform_sensor(80.0, 0.0, 0.0, 10.0, -30.0),
                       R_enu_from_cam_aviation(90.0, -30.0, 0.0))
    # platform pitched 5 deg nose up, sensor 35 deg down relative to it: 30 deg down
    R = R_enu_from_cam_platform_sensor(0.0, 5.0, 0.0, 0.0, -35.0)
    assert math.degrees(math.asin(-R[2, 2])) == pytest.approx(30.0)
    # a platform rolled right wing down 20 deg, sensor looking right 90 deg, level: looks 20 deg down
    R = R_enu_from_cam_platform_sensor(0.0, 0.0, 20.0, 90.0, 0.0)
    assert math.degrees(math.asin(-R[2, 2])) == pytest.approx(20.0)


@pytest.mark.parametrize('mount_elevation_deg', [-90.0, -60.0])
def test_camera_attitude_is_the_filters_camera(mount_elevation_deg):
    """Whatever the mount, the pose's camera is the measured one (to the filter's noise)."""
    import dataclasses

    cfg = dataclasses.replace(PipelineConfig().georef, gimbal_elevation_deg=mount_elevation_deg,
                              gimbal_azimuth_deg=30.0)
    g = Georeferencer(cfg)
    R = R_enu_from_cam_aviation(120.0, -40.0, 3.0)
    g.feed_fix(GeoFix(0, 30.0, -98.0, 300.0))
    g.feed_camera_attitude(CameraAttitude(0, R, math.radians(0.1)))
    pose = g.feed_frame(1)
    assert pose.valid
    angle = np.linalg.norm(np.degrees(np.arccos(np.clip((np.trace(pose.camera.R_enu_from_cam.T @ R) - 1) / 2, -1, 1))))
    assert angle < 0.05


def test_camera_attitude_looking_at_the_horizon_is_skipped():
    g = Georeferencer()
    g.feed_camera_attitude(CameraAttitude(0, R_enu_from_cam_aviation(0.0, -2.0, 0.0)))
    assert g.skipped['camera_attitude_horizon'] == 1


def test_oblique_flight_is_ortho_rectified_within_one_percent_of_the_slant_range(tmp_path):
    """A camera 40 deg below the horizon, 200 m up, looking left of a line flight: with the camera
    attitude per frame (0.2 deg noise) and the default (nadir) mount, every frame corner lands on
    the map within 1 % of its slant range of where the true camera sees it."""
    from srmosaic_ros.app.evaluate import evaluate_dir
    from srmosaic_ros.sim import save_truth

    elevation, altitude = -40.0, 200.0
    flight = simulate(SimConfig(trajectory='line', frames=16, rate_hz=2.0, altitude_m=altitude, hfov_deg=20.0,
                                width=320, height=240, gimbal_elevation_deg=elevation, gimbal_azimuth_deg=90.0,
                                world='data/worlds/caliterra_IMG_9360.jpg', heading_deg=0.0,
                                start_east_m=-40.0, start_north_m=-240.0, gps_sigma_h_m=1.0, gps_sigma_v_m=2.0,
                                seed=3))
    rng = np.random.default_rng(0)
    attitudes = [CameraAttitude(f.stamp_ns, matrix_from_rotvec(rng.normal(0.0, math.radians(0.2), 3)) @ f.R_enu_from_cam,
                                math.radians(0.2)) for f in flight.truth.frames]
    config = PipelineConfig()
    assert config.georef.gimbal_elevation_deg == -90.0  # the mount says nadir: only the attitudes say oblique
    pipeline = Pipeline(config)
    for item in merge_by_time(flight.frames, sorted(flight.fixes + attitudes, key=lambda x: x.stamp_ns)):
        pipeline.feed(item)
    result = pipeline.finish()
    write_outputs(result, tmp_path, config, {})
    save_truth(flight.truth, tmp_path / 'truth.json')
    figures = evaluate_dir(tmp_path, tmp_path / 'truth.json')
    assert figures['frames_registered'] == 16
    # slant range of the nearest corner: the tightest bound
    cam = flight.camera
    corners = np.array([[0, 0], [cam.width - 1, 0], [cam.width - 1, cam.height - 1], [0, cam.height - 1]], float)
    nearest = min(np.linalg.norm(_ground_points(f, cam, corners) - f.camera_enu_m, axis=1).min()
                  for f in flight.truth.frames)
    assert nearest > 200.0
    print(figures["georef_error_max_m"], figures["georef_error_rms_m"], nearest)
    assert figures["georef_error_max_m"] < 0.01 * nearest, figures


def _ground_points(frame, cam, px):
    rays = (frame.R_enu_from_cam @ np.linalg.inv(cam.K) @ np.c_[px, np.ones(len(px))].T).T
    t = -frame.camera_enu_m[2] / rays[:, 2]
    return frame.camera_enu_m + t[:, None] * rays
