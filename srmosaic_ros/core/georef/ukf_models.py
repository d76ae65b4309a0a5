"""The state layout and the models of the pose UKF (ukf.py): motion, camera mount, measurements.

State (13,), float64: ``x = [y_prev, y_cur, g]`` with ``y = (east_m, north_m, up_m, roll_rad,
pitch_rad, yaw_rad)`` and g the ENU height of the ground plane (m); see ukf.py's module docstring
for the frames, the motion model and the measurement models these functions implement.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .frames import (
    NADIR_ELEVATION_RAD,
    CameraPose,
    R_body_from_cam,
    camera_pose,
    rpy_from_R_enu_from_body,
)
from .ground_homography import apply_H, frame2_H_frame1

__all__ = [
    'POSE_DIM',
    'STATE_DIM',
    'GROUND',
    'SLOT_PREV',
    'SLOT_CUR',
    'CameraMount',
    'UkfParams',
    'corner_jacobian',
    'homography_model',
    'homography_model_batch',
    'nearest_positive_definite',
    'transition_matrix',
    'wrap_angle',
]

POSE_DIM = 6
STATE_DIM = 13
GROUND = 12
SLOT_PREV = slice(0, 6)
SLOT_CUR = slice(6, 12)
_EPS_VAR = 1e-10  # keeps P positive definite where a block is exactly singular by construction


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) in radians wrapped to [-pi, pi)."""
    wrapped = np.mod(np.asarray(a, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


@dataclass(frozen=True)
class CameraMount:
    """How the camera sits on the body: gimbal angles (rad) and lever arm (body frame, m).

    Defaults: nadir, image top toward the nose, image right toward the right wing (see frames).
    """

    gimbal_azimuth_rad: float = 0.0
    gimbal_elevation_rad: float = NADIR_ELEVATION_RAD
    lever_arm_body_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def camera_pose(self, pose6: np.ndarray) -> CameraPose:
        """Camera optical frame of a body pose (east, north, up, roll, pitch, yaw)."""
        return camera_pose(pose6[:3], pose6[3], pose6[4], pose6[5], gimbal_azimuth_rad=self.gimbal_azimuth_rad,
                           gimbal_elevation_rad=self.gimbal_elevation_rad, lever_arm_body_m=self.lever_arm_body_m)

    def body_pose(self, camera: CameraPose) -> np.ndarray:
        """(6,) body pose (east, north, up, roll, pitch, yaw) of a camera pose: the inverse of camera_pose."""
        R_enu_from_body = camera.R_enu_from_cam @ R_body_from_cam(self.gimbal_azimuth_rad,
                                                                  self.gimbal_elevation_rad).T
        position = np.asarray(camera.center_enu_m, dtype=np.float64) - R_enu_from_body @ np.asarray(
            self.lever_arm_body_m, dtype=np.float64)
        return np.r_[position, rpy_from_R_enu_from_body(R_enu_from_body)]



@dataclass(frozen=True)
class UkfParams:
    """Noise and numerics of :class:`PoseUkf` (SI units, radians)."""

    accel_sigma_h_m_s2: float = 2.0
    accel_sigma_v_m_s2: float = 1.0
    angular_accel_sigma_rad_s2: float = math.radians(20.0)
    initial_speed_sigma_m_s: float = 15.0
    initial_rate_sigma_rad_s: float = math.radians(30.0)
    ground_walk_m_per_sqrt_s: float = 0.05
    gate_probability: float = 0.99999
    max_gated_in_a_row: int = 5
    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    iterations: int = 5  # passes of the nonlinear (homography, gyro) updates; 1: the plain UKF update
    max_attitude_step_sigma_rad: float = math.radians(20.0)  # bound of the attitude process noise per step


def corner_jacobian(H: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(2N, 8) Jacobian of the mapped corners (u1, v1, u2, v2, ...) w.r.t. (h00 .. h21), h22 = 1.

    H (3, 3) normalised to h22 = 1; corners (N, 2). u = (h00 x + h01 y + h02) / w,
    v = (h10 x + h11 y + h12) / w, w = h20 x + h21 y + 1.
    """
    H = np.asarray(H, dtype=np.float64) / H[2, 2]
    out = np.zeros((2 * len(corners), 8))
    for i, (x, y) in enumerate(np.asarray(corners, dtype=np.float64)):
        w = H[2, 0] * x + H[2, 1] * y + 1.0
        u = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w
        v = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
        out[2 * i, 0:3] = (x / w, y / w, 1.0 / w)
        out[2 * i, 6:8] = (-u * x / w, -u * y / w)
        out[2 * i + 1, 3:6] = (x / w, y / w, 1.0 / w)
        out[2 * i + 1, 6:8] = (-v * x / w, -v * y / w)
    return out



def homography_model(K: np.ndarray, mount: CameraMount,
                     corners: np.ndarray, K_prev: np.ndarray | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """hx(x) -> (2N,): the current frame's ``corners`` (N, 2) mapped into the previous frame by
    the flat-ground homography of the two camera poses of state x (4.28, 4.29), ground at x[12].
    K: the current frame's intrinsics; K_prev: the previous frame's (a zoom), None: the same."""
    K = np.asarray(K, dtype=np.float64)
    corners = np.asarray(corners, dtype=np.float64)

    def hx(x: np.ndarray) -> np.ndarray:
        prev = mount.camera_pose(x[SLOT_PREV])
        cur = mount.camera_pose(x[SLOT_CUR])
        prev_H_cur = frame2_H_frame1(K, cur.R_enu_from_cam, cur.center_enu_m, prev.R_enu_from_cam,
                                     prev.center_enu_m, K2=K_prev, ground_z_m=x[GROUND])
        return apply_H(prev_H_cur, corners).ravel()

    return hx

def homography_model_batch(K: np.ndarray, mount: CameraMount,
                           corners: np.ndarray, K_prev: np.ndarray | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """:func:`homography_model` for every row of xs (N, STATE_DIM) at once -> (N, 2 corners).

    The same 4.28: prev_H_cur = K R_prev^T (I - (C_cur - C_prev) n^T / d) R_cur K^-1 with
    R = R_enu_from_cam, d = C_cur,z - g, n = (0, 0, 1) (scale left out: the corners are
    dehomogenised)."""
    K_inv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    K = np.asarray(K if K_prev is None else K_prev, dtype=np.float64)  # the previous frame's, on the left
    pts = np.c_[np.asarray(corners, dtype=np.float64), np.ones(len(corners))]          # (M, 3)
    R_bc = R_body_from_cam(mount.gimbal_azimuth_rad, mount.gimbal_elevation_rad)
    lever = np.asarray(mount.lever_arm_body_m, dtype=np.float64)

    def hx_batch(xs: np.ndarray) -> np.ndarray:
        r_eb_prev, r_eb_cur = _R_enu_from_body_batch(xs[:, 3:6]), _R_enu_from_body_batch(xs[:, 9:12])
        c_prev = xs[:, 0:3] + r_eb_prev @ lever
        c_cur = xs[:, 6:9] + r_eb_cur @ lever
        d = c_cur[:, 2] - xs[:, GROUND]
        if np.any(np.abs(d) < 1e-12):
            msg = 'camera 1 lies on the ground plane; the plane-induced homography is undefined.'
            raise ValueError(msg)
        plane = np.broadcast_to(np.eye(3), (len(xs), 3, 3)).copy()
        plane[:, :, 2] -= (c_cur - c_prev) / d[:, None]                # I - (C1 - C2) n^T / d
        H = K @ np.swapaxes(r_eb_prev @ R_bc, 1, 2) @ plane @ (r_eb_cur @ R_bc) @ K_inv
        q = pts @ np.swapaxes(H, 1, 2)                                  # (N, M, 3)
        return (q[:, :, :2] / q[:, :, 2:3]).reshape(len(xs), -1)

    return hx_batch


def _sym(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def _interpolation_matrix(first: int, a: float) -> np.ndarray:
    """(3, STATE_DIM) M with M x = (1 - a) x[first:first+3] + a x[first+6:first+9] (slot interpolation)."""
    m = np.zeros((3, STATE_DIM))
    i = np.arange(3)
    m[i, first + i] = 1.0 - a
    m[i, first + POSE_DIM + i] = a
    return m


def _R_enu_from_body_batch(rpy: np.ndarray) -> np.ndarray:
    """(N, 3, 3) frames.R_enu_from_body of each row (roll, pitch, yaw) of rpy (N, 3): Rz Ry Rx."""
    cr, cp, cy = np.cos(rpy).T
    sr, sp, sy = np.sin(rpy).T
    out = np.empty((len(rpy), 3, 3))
    out[:, 0, 0] = cy * cp
    out[:, 0, 1] = cy * sp * sr - sy * cr
    out[:, 0, 2] = cy * sp * cr + sy * sr
    out[:, 1, 0] = sy * cp
    out[:, 1, 1] = sy * sp * sr + cy * cr
    out[:, 1, 2] = sy * sp * cr - cy * sr
    out[:, 2, 0] = -sp
    out[:, 2, 1] = cp * sr
    out[:, 2, 2] = cp * cr
    return out


def nearest_positive_definite(P: np.ndarray, floor: float = 1e-9) -> np.ndarray:
    """P symmetrised with its eigenvalues clipped to >= ``floor`` (a numerical repair)."""
    w, v = np.linalg.eigh(_sym(P))
    return _sym((v * np.maximum(w, floor)) @ v.T)


def transition_matrix(ratio: float) -> np.ndarray:
    """(13, 13) F of the motion model: [y_prev, y_cur, g] -> [y_cur, (1 + r) y_cur - r y_prev, g]."""
    F = np.zeros((STATE_DIM, STATE_DIM))
    F[SLOT_PREV, SLOT_CUR] = np.eye(POSE_DIM)
    F[SLOT_CUR, SLOT_PREV] = -ratio * np.eye(POSE_DIM)
    F[SLOT_CUR, SLOT_CUR] = (1.0 + ratio) * np.eye(POSE_DIM)
    F[GROUND, GROUND] = 1.0
    return F


