"""Telemetry as the pose filter's measurements: a GNSS fix's covariance, an Imu orientation and a
measured camera attitude as the body's roll, pitch and yaw with their covariance (REP 103/145: body x
forward, y left, z up, in ENU). What cannot be used is skipped with its reason (SkipLog), never raised.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .frames import R_body_from_cam, matrix_from_quat_xyzw, matrix_from_rotvec, rpy_from_R_enu_from_body
from .ukf import wrap_angle

if TYPE_CHECKING:
    from ..types import CameraAttitude, GeoFix, ImuSample
    from .georef_config import GeorefConfig
    from .skip_log import SkipLog
    from .ukf import CameraMount

__all__ = ['MIN_AXIS_DEPRESSION_DEG', 'camera_attitude', 'fix_covariance', 'imu_attitude', 'sees_the_ground']

#: A measured camera attitude whose optical axis is less than this far below the horizon is not fused.
MIN_AXIS_DEPRESSION_DEG = 5.0


def sees_the_ground(R_enu_from_cam: np.ndarray) -> bool:
    """Whether a camera of this orientation (optical frame in ENU, (3, 3)) looks at least
    MIN_AXIS_DEPRESSION_DEG below the horizon: nearer the horizon the flat-ground model cannot place
    its frames, and the georeferencer leaves the attitude out."""
    return bool(R_enu_from_cam[2, 2] <= -math.sin(math.radians(MIN_AXIS_DEPRESSION_DEG)))


def fix_covariance(fix: GeoFix, config: GeorefConfig, log: SkipLog) -> np.ndarray:
    """(3, 3) ENU position covariance (m^2) of a fix: its own where usable, else the configured sigmas."""
    cfg = config
    default = np.diag([cfg.gps_sigma_h_m**2, cfg.gps_sigma_h_m**2, cfg.gps_sigma_v_m**2])
    cov = np.asarray(fix.position_covariance_m2, dtype=np.float64)
    if fix.covariance_type <= 0 or cov.size != 9:
        return default
    cov = cov.reshape(3, 3)
    cov = 0.5 * (cov + cov.T)
    if not np.all(np.isfinite(cov)):
        log.skip('fix_covariance_nan', 'GNSS fix covariance with NaN fields: the default sigmas are used')
        return default
    if np.trace(cov) <= 0.0 or np.min(np.linalg.eigvalsh(cov)) < 0.0:
        return default
    return cov + 1e-4 * np.eye(3)


def imu_attitude(imu: ImuSample, config: GeorefConfig, log: SkipLog) -> tuple[np.ndarray, np.ndarray] | None:
    """The body's (roll, pitch, yaw) (3,) rad and covariance (3, 3) of an Imu orientation, or None (skipped)."""
    q = imu.orientation_xyzw
    if q is None:
        log.skip('imu_no_orientation', 'Imu messages without orientation (covariance[0] = -1): only their '
                   'angular velocity is used')
        return None
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or not 0.5 < np.linalg.norm(q) < 1.5:
        log.skip('imu_nan', 'Imu orientation with NaN fields or not a unit quaternion ignored')
        return None
    rpy = np.array(rpy_from_R_enu_from_body(matrix_from_quat_xyzw(q)))
    cov = np.asarray(imu.orientation_covariance, dtype=np.float64)
    default = math.radians(config.imu_sigma_deg) ** 2 * np.eye(3)
    cov = cov.reshape(3, 3) if cov.size == 9 else default
    known = np.all(np.isfinite(cov)) and np.trace(cov) > 0.0
    if not (known and np.all(np.linalg.eigvalsh(0.5 * (cov + cov.T)) >= 0.0)):
        cov = default
    return rpy, 0.5 * (cov + cov.T) + 1e-10 * np.eye(3)


def camera_attitude(attitude: CameraAttitude, config: GeorefConfig, mount: CameraMount,
                    log: SkipLog) -> tuple[np.ndarray, np.ndarray] | None:
    """A measured camera orientation (gimbal angles, KLV sensor angles) in ENU as the body attitude the
    mount implies (``R_enu_from_body = R_enu_from_cam R_body_from_cam^T``): (roll, pitch, yaw) (3,) rad
    and covariance (3, 3), its isotropic sigma (else ``imu_sigma_deg``) carried through the Jacobian of
    that map; None for cameras looking at or above the horizon (less than MIN_AXIS_DEPRESSION_DEG below
    it), which cannot see a ground plane."""
    R_ec = np.asarray(attitude.R_enu_from_cam, dtype=np.float64)
    if R_ec.shape != (3, 3) or not np.all(np.isfinite(R_ec)) or abs(np.linalg.det(R_ec) - 1.0) > 1e-3:
        log.skip('camera_attitude_nan', 'camera attitude with NaN fields or not a rotation ignored')
        return None
    if not sees_the_ground(R_ec):
        log.skip('camera_attitude_horizon', 'camera attitude looking at or above the horizon ignored: the '
                   'flat-ground model cannot place such frames')
        return None
    sigma = attitude.sigma_rad if math.isfinite(attitude.sigma_rad) and attitude.sigma_rad > 0 \
        else math.radians(config.imu_sigma_deg)
    R_cb = R_body_from_cam(mount.gimbal_azimuth_rad, mount.gimbal_elevation_rad).T

    def rpy_of(dv: np.ndarray) -> np.ndarray:
        return np.array(rpy_from_R_enu_from_body(matrix_from_rotvec(dv) @ R_ec @ R_cb))

    rpy = rpy_of(np.zeros(3))
    J = np.empty((3, 3))  # d rpy / d small rotation of the camera (ENU rotation vector)
    for i in range(3):
        d = np.zeros(3)
        d[i] = 1e-6
        diff = rpy_of(d) - rpy_of(-d)
        J[:, i] = np.array([wrap_angle(v) for v in diff]) / 2e-6
    cov = sigma**2 * J @ J.T
    return rpy, 0.5 * (cov + cov.T) + 1e-10 * np.eye(3)
