"""Plain data that crosses from the edges (bags, topics, video) into the core.

These dataclasses are what msg_adapters produce from ROS messages (rclpy or rosbags) and what the
simulator emits. Times are integer nanoseconds, angles radians, lengths metres, frames as in
REP 103 (ENU world, body x forward / y left / z up).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['CameraIntrinsics', 'CameraAttitude', 'GeoFix', 'ImuSample', 'Frame', 'FIX_STATUS_NO_FIX']

FIX_STATUS_NO_FIX = -1  # sensor_msgs/NavSatStatus.STATUS_NO_FIX


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of an image stream (sensor_msgs/CameraInfo).

    Convention: pixel coordinates x right, y down, pixel centres at integers.
    ``distortion`` holds the coefficients of ``distortion_model`` (``plumb_bob``: k1 k2 t1 t2 k3).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion_model: str = ''
    distortion: tuple[float, ...] = ()

    @property
    def K(self) -> np.ndarray:  # the usual name of the matrix
        """(3, 3) float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(c) > 0.0 for c in self.distortion)

    def scaled_to(self, width: int, height: int) -> CameraIntrinsics | None:
        """These intrinsics for ``width`` x ``height`` px images of the same camera mode (the field
        of view kept, pixel centres scaled about the image corner), or None when the aspect ratio
        differs by more than a pixel (another mode: a crop, which no scaling describes)."""
        if (width, height) == (self.width, self.height) or self.width <= 0 or self.height <= 0:
            return self
        if abs(self.width * height - self.height * width) > max(self.width, width):
            return None
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(int(width), int(height), self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                                (self.cy + 0.5) * sy - 0.5, self.distortion_model, self.distortion)


@dataclass(frozen=True)
class GeoFix:
    """A GNSS fix (sensor_msgs/NavSatFix) in WGS84.

    ``position_covariance_m2`` is the (3, 3) ENU covariance in m^2 (row-major in the message);
    ``covariance_type`` follows NavSatFix (0 unknown, 1 approximated, 2 diagonal known, 3 known).
    ``status`` follows NavSatStatus (-1 no fix, 0 fix, 1 SBAS, 2 GBAS).
    """

    stamp_ns: int
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    status: int = 0
    position_covariance_m2: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    covariance_type: int = 0
    frame_id: str = ''


@dataclass(frozen=True)
class ImuSample:
    """An IMU sample (sensor_msgs/Imu).

    ``orientation_xyzw``: unit quaternion of the body (x forward, y left, z up) in ENU (REP 145),
    or None when the message says orientation is not provided (covariance[0] == -1).
    Angular velocity rad/s and linear acceleration m/s^2 in the body frame; all NaN when not
    provided (the message's covariance[0] == -1, or a source without rates: a flight log, EXIF).
    """

    stamp_ns: int
    orientation_xyzw: np.ndarray | None
    angular_velocity_rad_s: np.ndarray
    linear_acceleration_m_s2: np.ndarray
    orientation_covariance: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    frame_id: str = ''


@dataclass(frozen=True)
class CameraAttitude:
    """The orientation of the camera itself in ENU, measured per frame (a gimbal's angles in EXIF/XMP,
    MISB KLV platform attitude composed with the sensor's relative angles).

    ``R_enu_from_cam``: (3, 3) optical frame (x right in the image, y down, z along the optical axis)
    in ENU. ``sigma_rad``: isotropic standard deviation of the orientation (rad), NaN when the source
    gives none. It replaces the fixed camera mount of the body for that instant: the georeferencer
    turns it into the body attitude that its mount implies.
    """

    stamp_ns: int
    R_enu_from_cam: np.ndarray  # the frames are in the name
    sigma_rad: float = float('nan')


@dataclass
class Frame:
    """One camera image at the edge of the core.

    ``image``: numpy (H, W) for mono, (H, W, 3) RGB for colour, dtype uint8 or uint16.
    ``camera``: the intrinsics in force for this frame, when known.
    """

    stamp_ns: int
    image: np.ndarray
    camera: CameraIntrinsics | None = None
    frame_id: str = ''
