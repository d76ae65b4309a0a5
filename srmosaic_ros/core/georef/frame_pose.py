"""FramePose: the fused pose of the body at one frame, with its covariance, as the Georeferencer
returns it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .frames import CameraPose

__all__ = ['FramePose']


@dataclass(frozen=True)
class FramePose:
    """The fused pose of the body at one frame.

    position_enu_m (3,): body origin in the georeferencer's ENU plane; rpy_rad (3,): roll, pitch,
    yaw of the body in ENU (REP 103); covariance (6, 6) of (east, north, up, roll, pitch, yaw) in
    m^2 / rad^2; ground_z_m: the ground plane's height in the ENU plane as estimated with this
    pose (the frame's footprint lies on it); camera: the camera pose (mounting applied).
    latitude/longitude in degrees, altitude in metres above the WGS84 ellipsoid. ``valid`` False
    (no fix yet, frame out of order): NaN pose. info_rate (6, 6): information per second of the
    absolute measurements fused before this frame (GNSS positions in the position block, IMU
    attitudes in the attitude block: the sum of their R^-1 over the last ``INFO_RATE_WINDOW_S``,
    divided by that span), in the order of ``covariance``; drift control takes the correlation
    time of the pose errors from it (drift.py). None: not known. ground_covariance (7,): the
    covariance of ground_z_m with (east, north, up, roll, pitch, yaw) and, last, its variance (the
    footprint scales with the height above the ground, whose uncertainty is mostly the ground's at
    first); None: the ground is taken as exact. :attr:`pose_ground_covariance` assembles the two.
    """

    stamp_ns: int
    valid: bool
    position_enu_m: np.ndarray
    rpy_rad: np.ndarray
    covariance: np.ndarray
    latitude_deg: float = float('nan')
    longitude_deg: float = float('nan')
    altitude_m: float = float('nan')
    camera: CameraPose | None = field(default=None, repr=False)
    ground_z_m: float = float('nan')
    homography_used: bool = False
    fixes_used: int = 0
    imu_used: int = 0
    reason: str = ''
    info_rate: np.ndarray | None = field(default=None, repr=False)
    ground_covariance: np.ndarray | None = field(default=None, repr=False)

    @property
    def std_enu_m(self) -> np.ndarray:
        """(3,) standard deviations of east, north, up (m)."""
        return np.sqrt(np.clip(np.diag(self.covariance)[:3], 0.0, None))

    @property
    def std_rpy_rad(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance)[3:], 0.0, None))

    @property
    def pose6(self) -> np.ndarray:
        return np.r_[self.position_enu_m, self.rpy_rad]

    @property
    def pose_ground_covariance(self) -> np.ndarray:
        """(7, 7) joint covariance of (east, north, up, roll, pitch, yaw, ground_z_m); the ground row
        and column are zero when ground_covariance is not known."""
        out = np.zeros((7, 7))
        out[:6, :6] = self.covariance
        g = self.ground_covariance
        if g is not None and np.shape(g) == (7,) and np.all(np.isfinite(g)):
            out[6, :] = out[:, 6] = g
        return out

    @classmethod
    def invalid(cls, stamp_ns: int, reason: str) -> FramePose:
        nan3 = np.full(3, np.nan)
        return cls(int(stamp_ns), False, nan3, nan3.copy(), np.full((6, 6), np.nan), reason=reason)
