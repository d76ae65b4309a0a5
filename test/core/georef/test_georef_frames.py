"""Frame transforms, flat-ground homographies and geodetic conversions against hand-computed cases."""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from srmosaic_ros.core.georef.frames import (
    R_BODY_FROM_CAM_NADIR,
    R_body_from_cam,
    R_enu_from_body,
    camera_pose,
    invert_T,
    make_T,
    matrix_from_quat_xyzw,
    matrix_from_rotvec,
    quat_xyzw_from_matrix,
    rotvec_from_matrix,
    rpy_from_R_enu_from_body,
)
from srmosaic_ros.core.georef.geodetic import WGS84_A_M, WGS84_F, LocalTangentPlane, ecef_from_geodetic
from srmosaic_ros.core.georef.ground_homography import (
    apply_H,
    frame2_H_frame1,
    ground_H_image,
    image_H_ground,
)

F_PX = 500.0
W, H = 640, 480
K = np.array([[F_PX, 0.0, (W - 1) / 2], [0.0, F_PX, (H - 1) / 2], [0.0, 0.0, 1.0]])
PP = np.array([(W - 1) / 2, (H - 1) / 2])
DEG = math.pi / 180.0


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return matrix_from_rotvec(rng.normal(size=3))


# --- rotations -------------------------------------------------------------------------------


def test_attitude_axes_follow_rep103() -> None:
    np.testing.assert_allclose(R_enu_from_body(0, 0, 0), np.eye(3))
    # yaw 90 deg: the nose (body x) points north
    np.testing.assert_allclose(R_enu_from_body(0, 0, 90 * DEG) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    # positive pitch: nose down
    assert (R_enu_from_body(0, 10 * DEG, 0) @ [1, 0, 0])[2] < 0
    # positive roll: right wing (body -y) down
    assert (R_enu_from_body(10 * DEG, 0, 0) @ [0, -1, 0])[2] < 0


@pytest.mark.parametrize('rpy_deg', [(0, 0, 0), (5, -3, 170), (-20, 40, -95), (179, 0, 1), (3, 89, 45)])
def test_rpy_round_trip(rpy_deg: tuple[float, float, float]) -> None:
    r, p, y = (v * DEG for v in rpy_deg)
    got = rpy_from_R_enu_from_body(R_enu_from_body(r, p, y))
    np.testing.assert_allclose(R_enu_from_body(*got), R_enu_from_body(r, p, y), atol=1e-12)
    if abs(rpy_deg[1]) < 80:
        np.testing.assert_allclose(got, (r, p, y), atol=1e-12)


def test_quaternion_and_rotvec_round_trips() -> None:
    rng = np.random.default_rng(0)
    cases = [random_rotation(rng) for _ in range(50)]
    cases += [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]), np.eye(3)]
    for R in cases:
        q = quat_xyzw_from_matrix(R)
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        np.testing.assert_allclose(matrix_from_quat_xyzw(q), R, atol=1e-12)
        np.testing.assert_allclose(matrix_from_rotvec(rotvec_from_matrix(R)), R, atol=1e-9)
    # yaw 90 deg about z: q = (0, 0, sin 45, cos 45)
    np.testing.assert_allclose(quat_xyzw_from_matrix(R_enu_from_body(0, 0, 90 * DEG)),
                               [0, 0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-15)


def test_default_mounting_is_nadir_top_to_nose_right_to_right_wing() -> None:
    R = R_BODY_FROM_CAM_NADIR
    np.testing.assert_allclose(R @ [0, 0, 1], [0, 0, -1], atol=1e-15)  # optical axis down
    np.testing.assert_allclose(R @ [0, -1, 0], [1, 0, 0], atol=1e-15)  # image up -> nose
    np.testing.assert_allclose(R @ [1, 0, 0], [0, -1, 0], atol=1e-15)  # image right -> right wing
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_gimbal_angles() -> None:
    # elevation 0: looking along the nose, image up = body up
    R = R_body_from_cam(0.0, 0.0)
    np.testing.assert_allclose(R @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(R @ [0, -1, 0], [0, 0, 1], atol=1e-15)
    # azimuth 90 deg (counter-clockwise from above): looking along the left wing
    np.testing.assert_allclose(R_body_from_cam(90 * DEG, 0.0) @ [0, 0, 1], [0, 1, 0], atol=1e-15)
    # elevation -30 deg: optical axis 30 deg below the horizon, ahead
    np.testing.assert_allclose(R_body_from_cam(0.0, -30 * DEG) @ [0, 0, 1],
                               [math.cos(30 * DEG), 0, -math.sin(30 * DEG)], atol=1e-15)


def test_camera_pose_lever_arm_rotates_with_the_body() -> None:
    pose = camera_pose(np.array([10.0, 20.0, 100.0]), 0.0, 0.0, 90 * DEG, lever_arm_body_m=(1.0, 0.0, -0.5))
    np.testing.assert_allclose(pose.center_enu_m, [10.0, 21.0, 99.5], atol=1e-12)
    R, C = pose  # unpacks like a tuple
    np.testing.assert_allclose(R @ [0, 0, 1], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(R @ [0, -1, 0], [0, 1, 0], atol=1e-15)  # image up -> nose -> north


def test_rigid_transforms() -> None:
    rng = np.random.default_rng(1)
    R, t = random_rotation(rng), rng.normal(size=3)
    a_T_b = make_T(R, t)
    np.testing.assert_allclose(invert_T(a_T_b) @ a_T_b, np.eye(4), atol=1e-12)
    p_b = np.array([1.0, 2.0, 3.0, 1.0])
    np.testing.assert_allclose((a_T_b @ p_b)[:3], R @ p_b[:3] + t)


# --- flat-ground homography ------------------------------------------------------------------


def nadir(east: float, north: float, h: float, yaw_deg: float = 0.0, roll_deg: float = 0.0,
          pitch_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    return camera_pose(np.array([east, north, h]), roll_deg * DEG, pitch_deg * DEG, yaw_deg * DEG)


def test_principal_point_maps_below_a_nadir_camera() -> None:
    R, C = nadir(12.0, -7.0, 100.0, yaw_deg=33.0)
    np.testing.assert_allclose(apply_H(ground_H_image(K, R, C), PP), [12.0, -7.0], atol=1e-9)


@pytest.mark.parametrize('yaw_deg', [0.0, 90.0, -135.0])
def test_pixel_offset_maps_to_h_offset_over_f_in_the_right_direction(yaw_deg: float) -> None:
    h, dx, dy = 80.0, 40.0, -25.0
    R, C = nadir(5.0, 6.0, h, yaw_deg=yaw_deg)
    g = apply_H(ground_H_image(K, R, C), PP + [dx, dy])
    yaw = yaw_deg * DEG
    nose = np.array([math.cos(yaw), math.sin(yaw)])
    right_wing = np.array([math.sin(yaw), -math.cos(yaw)])
    expected = np.array([5.0, 6.0]) + h / F_PX * (dx * right_wing - dy * nose)  # image up = nose
    np.testing.assert_allclose(g, expected, atol=1e-9)


def test_roll_and_pitch_signs() -> None:
    h = 100.0
    # right wing down: the belly, hence the view, turns toward the left wing (north when flying east)
    R, C = nadir(0.0, 0.0, h, yaw_deg=0.0, roll_deg=5.0)
    np.testing.assert_allclose(apply_H(ground_H_image(K, R, C), PP), [0.0, h * math.tan(5 * DEG)], atol=1e-9)
    # nose down: the belly, hence the view, tilts aft (west when flying east)
    R, C = nadir(0.0, 0.0, h, yaw_deg=0.0, pitch_deg=5.0)
    np.testing.assert_allclose(apply_H(ground_H_image(K, R, C), PP), [-h * math.tan(5 * DEG), 0.0], atol=1e-9)


def test_ground_homography_agrees_with_projection_and_inverse() -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        attitude = R_enu_from_body(*rng.normal(0, 0.1, 2), rng.uniform(-math.pi, math.pi))
        R = attitude @ R_BODY_FROM_CAM_NADIR
        C = np.array([*rng.normal(0, 50, 2), rng.uniform(30, 300)])
        z0 = rng.normal(0, 5)
        ground = np.c_[rng.normal(C[0], 20, (10, 2))[:, 0], rng.normal(C[1], 20, 10)]
        X = np.c_[ground, np.full(10, z0)]
        x = (K @ R.T @ (X - C).T).T
        pix = x[:, :2] / x[:, 2:]
        np.testing.assert_allclose(apply_H(image_H_ground(K, R, C, ground_z_m=z0), ground), pix, atol=1e-7)
        np.testing.assert_allclose(apply_H(ground_H_image(K, R, C, ground_z_m=z0), pix), ground, atol=1e-7)


def test_frame2_H_frame1_is_eq_428() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        poses = []
        for _ in range(2):
            R = R_enu_from_body(*rng.normal(0, 0.05, 2), rng.uniform(-3, 3)) @ R_BODY_FROM_CAM_NADIR
            poses.append((R, np.array([*rng.normal(0, 10, 2), rng.uniform(80, 120)])))
        composed = image_H_ground(K, *poses[1]) @ ground_H_image(K, *poses[0])
        composed /= composed[2, 2]
        np.testing.assert_allclose(frame2_H_frame1(K, *poses[0], *poses[1]), composed, atol=1e-9, rtol=1e-9)
    # identical poses: identity; a pure east translation of a north-flying nadir camera: a shift
    R, C = nadir(0.0, 0.0, 100.0, yaw_deg=90.0)
    np.testing.assert_allclose(frame2_H_frame1(K, R, C, R, C), np.eye(3), atol=1e-12)
    H = frame2_H_frame1(K, R, C, R, C + [2.0, 0.0, 0.0])
    # the camera moved 2 m toward its right: the scene moves 2 * f / h px to the left
    np.testing.assert_allclose(H, [[1, 0, -2 * F_PX / 100], [0, 1, 0], [0, 0, 1]], atol=1e-9)


# --- geodetic --------------------------------------------------------------------------------


def test_ecef_known_points() -> None:
    np.testing.assert_allclose(ecef_from_geodetic(0.0, 0.0, 0.0), [WGS84_A_M, 0, 0], atol=1e-6)
    np.testing.assert_allclose(ecef_from_geodetic(90.0, 0.0, 0.0), [0, 0, WGS84_A_M * (1 - WGS84_F)], atol=1e-6)


@pytest.mark.parametrize('lat0', [30.17115, 46.8427, -60.0])
def test_local_tangent_plane_round_trip_and_scale(lat0: float) -> None:
    ltp = LocalTangentPlane(lat0, -98.08987, 250.0)
    np.testing.assert_allclose(ltp.enu_from_geodetic(lat0, -98.08987, 250.0), [0, 0, 0], atol=1e-6)
    rng = np.random.default_rng(4)
    enu = rng.uniform(-1000, 1000, (100, 3))
    lat, lon, alt = ltp.geodetic_from_enu(enu)
    np.testing.assert_allclose(ltp.enu_from_geodetic(lat, lon, alt), enu, atol=1e-6)
    # 100 m north at height 250 m: dlat = 100 / (M + 250), M the meridional radius of curvature
    e2 = WGS84_F * (2 - WGS84_F)
    phi = math.radians(lat0)
    m = WGS84_A_M * (1 - e2) / (1 - e2 * math.sin(phi) ** 2) ** 1.5
    lat_n, lon_n, _ = ltp.geodetic_from_enu(np.array([0.0, 100.0, 0.0]))
    assert (float(lat_n) - lat0) * math.pi / 180 * (m + 250.0) == pytest.approx(100.0, abs=1e-3)
    assert float(lon_n) == pytest.approx(-98.08987, abs=1e-12)


def test_core_georef_imports_no_ros() -> None:
    code = ('import sys; import srmosaic_ros.core.georef.frames, srmosaic_ros.core.georef.ground_homography, '
            'srmosaic_ros.core.georef.geodetic; '
            'bad = [m for m in ("rclpy", "rosbags", "msg_adapters") if m in sys.modules]; '
            'sys.exit(1 if bad else 0)')
    assert subprocess.run([sys.executable, '-c', code], check=False).returncode == 0
