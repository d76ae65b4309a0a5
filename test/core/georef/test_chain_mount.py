"""The mount a chain of homographies shows (chain_mount.py), on exact geometry: cameras on a mount
flying over level ground, their frames related through the ground plane; and the pose check's
use of it (pose_check.py)."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.georef.chain_mount import mount_from_chain
from srmosaic_ros.core.georef.frames import camera_pose
from srmosaic_ros.core.georef.geotag_fit import check_mount_nadir
from srmosaic_ros.core.georef.ground_homography import image_H_ground
from srmosaic_ros.core.georef.pose_check import (MAX_SPREAD_TO_TRY_DEG, MOUNT_TOLERANCE_DEG, check_pose_placement,
                                                 mount_axis_angle_deg)

K = np.array([[220.0, 0.0, 160.0], [0.0, 220.0, 120.0], [0.0, 0.0, 1.0]])  # 320 x 240, HFOV 72 deg


def _image_H_ground(azimuth_deg: float, elevation_deg: float, position: np.ndarray, rpy_deg: np.ndarray,
                    yaw_deg: float) -> np.ndarray:
    """(3, 3) ground (east, north on z = 0, m) -> image pixels of a camera on that mount."""
    roll, pitch, yaw = np.radians(rpy_deg) + np.array([0.0, 0.0, math.radians(yaw_deg)])
    pose = camera_pose(position, roll, pitch, yaw, gimbal_azimuth_rad=math.radians(azimuth_deg),
                       gimbal_elevation_rad=math.radians(elevation_deg))
    return image_H_ground(K, pose.R_enu_from_cam, pose.center_enu_m)


def _chain(azimuth_deg: float, elevation_deg: float, *, frames: int = 12, step_m: float = 3.0,
           sway_deg: float = 0.0, yaw_deg: float = 30.0, noise_px: float = 0.0,
           seed: int = 0) -> list[np.ndarray]:
    """first_H_frames of a straight flight at 80 m along the body's nose (heading ``yaw_deg`` from
    east), the body swaying ``sway_deg`` RMS per axis, corners moved by ``noise_px`` RMS."""
    rng = np.random.default_rng(seed)
    heading = np.array([math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg)), 0.0])
    Hs = [_image_H_ground(azimuth_deg, elevation_deg, np.array([0.0, 0.0, 80.0]) + k * step_m * heading,
                          rng.normal(0.0, sway_deg, 3), yaw_deg) for k in range(frames)]
    corners = np.array([[0, 320, 320, 0], [0, 0, 240, 240]], dtype=np.float32).T
    out = []
    for H in Hs:  # frame corners moved by the noise, mapped exactly: a homography that far off
        there = cv2.perspectiveTransform(corners[None], Hs[0] @ np.linalg.inv(H))[0]
        moved = corners + rng.normal(0.0, noise_px, corners.shape).astype(np.float32)
        out.append(cv2.getPerspectiveTransform(moved, there))
    return out


@pytest.mark.parametrize(('azimuth', 'elevation'), [(0.0, -90.0), (0.0, -55.0), (90.0, -60.0), (-45.0, -40.0),
                                                    (180.0, -70.0), (0.0, -10.0), (0.0, 3.0), (30.0, 1.0)])
def test_the_chain_shows_the_mount_it_was_flown_on(azimuth: float, elevation: float) -> None:
    """Exact to 0.05 deg, also for a camera whose frame reaches past the ground's horizon (-10 deg:
    the top half of its frame is sky) and one looking above it (3 deg: ground in the lower half only;
    the optical axis's test read it as its mirror, 3 deg below and 180 deg from the travel, as on
    karma.mp4)."""
    shown = mount_from_chain(_chain(azimuth, elevation), [K] * 12)
    assert shown is not None and shown.frames >= 7  # those moved MIN_BASELINE of the distance
    assert shown.elevation_deg == pytest.approx(elevation, abs=0.05)
    if elevation > -89.0:
        assert (shown.azimuth_deg - azimuth + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=0.1)
    assert shown.spread_deg < 0.01


def test_sway_and_registration_noise_move_it_by_a_degree_or_two() -> None:
    """Gusts of 2 deg RMS per axis and corners 0.2 px RMS off: the body's sway averages out over the
    frames (each frame's own attitude is taken, not only the first's)."""
    for seed in range(4):
        shown = mount_from_chain(_chain(20.0, -55.0, sway_deg=2.0, noise_px=0.2, seed=seed), [K] * 12)
        assert shown is not None
        assert mount_axis_angle_deg((20.0, -55.0), (shown.azimuth_deg, shown.elevation_deg)) < 2.5, shown


def test_a_hover_or_a_short_chain_shows_nothing() -> None:
    """Without translation the homographies are rotations only: no plane, no mount (None)."""
    assert mount_from_chain(_chain(0.0, -60.0, step_m=0.0, sway_deg=1.0), [K] * 12) is None
    assert mount_from_chain(_chain(0.0, -60.0, frames=3), [K] * 3) is None  # 2 frames moved: fewer than 3


def test_a_zoomed_camera_shows_nothing() -> None:
    """Narrower than MIN_HFOV_DEG the frames see an affine patch: its projective terms are noise
    (KLV's aphill_short.ts at 0.8 deg "showed" 0.6 deg below the horizon, its KLV says 37)."""
    zoomed = K.copy()
    zoomed[0, 0] = zoomed[1, 1] = 160.0 / math.tan(math.radians(7.0))  # 14 deg wide (the guard alone)
    assert mount_from_chain(_chain(0.0, -60.0), [zoomed] * 12) is None


def test_a_zoom_is_read_through_each_frames_intrinsics() -> None:
    """Frame i taken with K_i (a zoom): its homography is in its own pixels."""
    Ks = [np.array([[220.0 * (1 + 0.05 * k), 0, 160.0], [0, 220.0 * (1 + 0.05 * k), 120.0], [0, 0, 1]]) for k in range(12)]
    rng = np.random.default_rng(1)
    heading = np.array([1.0, 0.0, 0.0])
    Hs = []
    for k, Kk in enumerate(Ks):
        pose = camera_pose(np.array([0.0, 0.0, 80.0]) + 3.0 * k * heading, *np.radians(rng.normal(0, 0.5, 3)),
                           gimbal_elevation_rad=math.radians(-50.0))
        Hs.append(image_H_ground(Kk, pose.R_enu_from_cam, pose.center_enu_m))
    shown = mount_from_chain([Hs[0] @ np.linalg.inv(H) for H in Hs], Ks)
    assert shown is not None and shown.elevation_deg == pytest.approx(-50.0, abs=1.0)


def test_the_pose_check_refuses_a_mount_the_frames_contradict() -> None:
    """A low NIS does not pass a chain that shows another mount (the oblique line that passed the
    NIS alone: median 36.1 under the gate 37.3, placed 15 px off); one that agrees passes."""
    oblique = mount_from_chain(_chain(0.0, -70.0), [K] * 12)
    nadir = mount_from_chain(_chain(0.0, -90.0, sway_deg=1.0), [K] * 12)
    low = [3.0, 2.0, 36.0, 4.0, 5.0]
    refused = check_pose_placement(low, 0.99999, (0.0, -90.0), oblique)
    assert refused is not None and not refused.used
    assert '70 deg below the horizon' in refused.reason and '20 deg from the mount' in refused.reason
    assert refused.as_dict()['frames_mount']['elevation_deg'] == pytest.approx(-70.0, abs=0.1)
    passed = check_pose_placement(low, 0.99999, (0.0, -90.0), nadir)
    assert passed is not None and passed.used and passed.frames_mount is nadir
    assert check_pose_placement(low, 0.99999, (0.0, -70.0), oblique).used  # the mount it was flown on
    tilted = mount_from_chain(_chain(0.0, -80.0), [K] * 12)  # 10 deg off: the nadir mount places it (1.3 px)
    assert check_pose_placement(low, 0.99999, (0.0, -90.0), tilted).used
    assert mount_axis_angle_deg((0.0, -90.0), (0.0, -90.0 + MOUNT_TOLERANCE_DEG + 0.5)) > MOUNT_TOLERANCE_DEG


def test_the_mount_to_try_is_one_the_filter_can_use() -> None:
    """The refusal offers the frames' mount, rounded, when every frame corner looks 10 deg or more
    below the horizon through it; a camera near the horizon (a GoPro's view) is offered nothing."""
    low = [3.0, 2.0, 4.0, 4.0, 5.0]
    oblique = check_pose_placement(low, 0.99999, (0.0, -90.0), mount_from_chain(_chain(30.0, -55.0), [K] * 12))
    assert oblique.with_mount_to_try(K).mount_to_try == (30.0, -55.0)
    shallow = check_pose_placement(low, 0.99999, (0.0, -90.0), mount_from_chain(_chain(0.0, -40.0, step_m=1.0), [K] * 12))
    assert not shallow.used and shallow.with_mount_to_try(K).mount_to_try is None  # its top corners: 4 deg below
    horizon = check_pose_placement(low, 0.99999, (0.0, -90.0), mount_from_chain(_chain(0.0, -5.0), [K] * 12))
    assert not horizon.used and '5 deg below the horizon' in horizon.reason  # karma.mp4: 2 deg
    assert horizon.with_mount_to_try(K).mount_to_try is None
    assert check_pose_placement(low, 0.99999, (0.0, -90.0)).with_mount_to_try(K).mount_to_try is None  # passed
    rough = mount_from_chain(_chain(30.0, -55.0, sway_deg=2.0, noise_px=0.5, seed=2), [K] * 12)
    assert MAX_SPREAD_TO_TRY_DEG < rough.spread_deg < 2.0  # refuses, but is not a mount to fly
    refused_roughly = check_pose_placement(low, 0.99999, (0.0, -90.0), rough)
    assert not refused_roughly.used and refused_roughly.with_mount_to_try(K).mount_to_try is None
    offered = oblique.with_mount_to_try(K)
    assert 'restart with georef.gimbal_elevation_deg: -55, georef.gimbal_azimuth_deg: 30' in offered.operator_note()
    assert 'give the camera attitude' in horizon.with_mount_to_try(K).operator_note()
    assert check_pose_placement(low, 0.99999, (0.0, -90.0)).operator_note() == ''  # used: nothing to say


def test_geotags_do_not_place_frames_whose_chain_shows_a_tilt() -> None:
    """A constant tilt keeps the frames parallel (check_views_nadir passes them): the chain's mount
    refuses the geotag fit, with the mount to set."""
    check_mount_nadir(None)
    check_mount_nadir(mount_from_chain(_chain(0.0, -85.0), [K] * 12))  # 5 deg off nadir: placed
    with pytest.raises(ValueError, match=r'62 deg below the horizon.*georef.gimbal_elevation_deg: -62.0'):
        check_mount_nadir(mount_from_chain(_chain(0.0, -62.0), [K] * 12))
