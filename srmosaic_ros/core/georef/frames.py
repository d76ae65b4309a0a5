"""Frame transforms of a UAS camera: ENU -> vehicle -> body -> gimbal -> camera (dissertation 4.4.1).

Pure numpy, float64. The dissertation writes the chain in NED with a body frame x nose, y right
wing, z belly (4.13-4.20); this module follows REP 103 / REP 145 instead:

- world: ENU local tangent plane (x east, y north, z up);
- vehicle: ENU axes at the vehicle's position (4.13, 4.14 with ENU instead of NED);
- body: x forward (nose), y left (left wing), z up. Attitude as fixed-axis roll, pitch, yaw
  (REP 103): ``R_enu_from_body = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, the ENU counterpart of 4.16
  (which is the transposed, NED form). yaw is the heading counter-clockwise from east; positive
  pitch puts the nose down; positive roll puts the right wing down;
- gimbal: x along the optical axis, y left in the image, z up in the image (a ROS "camera_link"
  frame). ``R_body_from_gimbal = Rz(azimuth) @ Ry(-elevation)`` (the counterpart of 4.18):
  azimuth counter-clockwise seen from above, elevation positive above the horizon. At
  azimuth = 0, elevation = 0 the camera looks along the nose; nadir is elevation = -90 deg;
- camera: the optical frame (x right in the image, y down, z forward along the optical axis).
  ``R_gimbal_from_cam`` is the fixed permutation that plays the role of 4.20.

With the default mounting (azimuth 0, elevation -90 deg) the camera looks straight down, the image
top points toward the nose and the image right toward the right wing.

Rigid transforms as 4x4 matrices follow 4.11 / 4.12: ``a_T_b`` maps homogeneous points of frame b
to frame a. Quaternions are (x, y, z, w), unit, as in ROS messages.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    'R_GIMBAL_FROM_CAM',
    'R_BODY_FROM_CAM_NADIR',
    'NADIR_ELEVATION_RAD',
    'CameraPose',
    'rot_x',
    'rot_y',
    'rot_z',
    'R_enu_from_body',
    'rpy_from_R_enu_from_body',
    'R_body_from_gimbal',
    'R_body_from_cam',
    'camera_pose',
    'quat_xyzw_from_matrix',
    'matrix_from_quat_xyzw',
    'rotvec_from_matrix',
    'matrix_from_rotvec',
    'make_T',
    'invert_T',
    'R_enu_from_cam_aviation',
    'R_enu_from_cam_platform_sensor',
    'aviation_angles_from_R_enu_from_cam',
]

NADIR_ELEVATION_RAD = -np.pi / 2.0

#: Camera optical axes expressed in the gimbal frame (columns: x_cam, y_cam, z_cam): image right is
#: the gimbal's -y, image down its -z, the optical axis its +x. Plays the role of 4.20.
R_GIMBAL_FROM_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rot_x(angle_rad: float) -> np.ndarray:
    """(3, 3) active rotation by ``angle_rad`` about x."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    """(3, 3) active rotation by ``angle_rad`` about y."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    """(3, 3) active rotation by ``angle_rad`` about z."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def R_enu_from_body(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """(3, 3) attitude of the body (x fwd, y left, z up) in ENU: Rz(yaw) Ry(pitch) Rx(roll).

    REP 103 fixed-axis roll/pitch/yaw; the ENU/FLU counterpart of the dissertation's 4.16
    (there R_v^b, the transpose, in NED/FRD).
    """
    return rot_z(yaw_rad) @ rot_y(pitch_rad) @ rot_x(roll_rad)


def rpy_from_R_enu_from_body(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians of ``R_enu_from_body``; pitch in [-pi/2, pi/2], yaw in (-pi, pi]."""
    R = np.asarray(R, dtype=np.float64)
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    return roll, pitch, yaw


def R_body_from_gimbal(azimuth_rad: float = 0.0, elevation_rad: float = 0.0) -> np.ndarray:
    """(3, 3) gimbal axes in the body frame: Rz(azimuth) Ry(-elevation) (cf. 4.17, 4.18).

    azimuth: counter-clockwise seen from above (toward the left wing); elevation: positive above the
    horizon, -pi/2 is nadir.
    """
    return rot_z(azimuth_rad) @ rot_y(-elevation_rad)


def R_body_from_cam(azimuth_rad: float = 0.0, elevation_rad: float = NADIR_ELEVATION_RAD) -> np.ndarray:
    """(3, 3) camera optical axes in the body frame for the given gimbal angles (default nadir)."""
    return R_body_from_gimbal(azimuth_rad, elevation_rad) @ R_GIMBAL_FROM_CAM


#: Default mounting: nadir, image top toward the nose, image right toward the right wing.
R_BODY_FROM_CAM_NADIR = R_body_from_cam(0.0, NADIR_ELEVATION_RAD)


class CameraPose(NamedTuple):
    """Pose of the camera optical frame in ENU: ``X_enu = R_enu_from_cam @ X_cam + center_enu_m``."""

    R_enu_from_cam: np.ndarray
    center_enu_m: np.ndarray


def camera_pose(position_enu_m: np.ndarray, roll_rad: float, pitch_rad: float, yaw_rad: float, *,
                gimbal_azimuth_rad: float = 0.0, gimbal_elevation_rad: float = NADIR_ELEVATION_RAD,
                lever_arm_body_m: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0)) -> CameraPose:
    """Camera pose from the body position (ENU, m), attitude (rad) and gimbal angles (rad).

    The chain of 4.13-4.20 in REP 103 form: ``R_enu_from_cam = R_enu_from_body @ R_body_from_gimbal
    @ R_gimbal_from_cam``; the optical centre is ``position + R_enu_from_body @ lever_arm_body_m``
    (the lever arm, body frame, from the body origin, e.g. the GNSS antenna, to the optical centre;
    the dissertation's d_b^g and d_g^c together).
    """
    R_eb = R_enu_from_body(roll_rad, pitch_rad, yaw_rad)
    R_ec = R_eb @ R_body_from_cam(gimbal_azimuth_rad, gimbal_elevation_rad)
    center = np.asarray(position_enu_m, dtype=np.float64) + R_eb @ np.asarray(lever_arm_body_m, dtype=np.float64)
    return CameraPose(R_ec, center)


def quat_xyzw_from_matrix(R: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion (x, y, z, w), w >= 0, of a (3, 3) rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    diag = np.array([R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax(np.r_[diag, tr]))
    if k == 3:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    else:
        i, j, m = k, (k + 1) % 3, (k + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[m, m])
        q = np.empty(4)
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[m] = (R[m, i] + R[i, m]) / s
        q[3] = (R[m, j] - R[j, m]) / s
    q /= np.linalg.norm(q)
    return -q if q[3] < 0.0 else q


def matrix_from_quat_xyzw(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a quaternion (x, y, z, w) (normalised first)."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def matrix_from_rotvec(v: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of the rotation vector ``v`` (axis * angle, rad), Rodrigues' formula."""
    v = np.asarray(v, dtype=np.float64)
    theta = float(np.linalg.norm(v))
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    if theta < 1e-8:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + np.sin(theta) / theta * k + (1.0 - np.cos(theta)) / theta**2 * k @ k


def rotvec_from_matrix(R: np.ndarray) -> np.ndarray:
    """(3,) rotation vector (axis * angle, angle in [0, pi]) of a rotation matrix."""
    q = quat_xyzw_from_matrix(R)
    s = float(np.linalg.norm(q[:3]))
    if s < 1e-12:
        return 2.0 * q[:3]
    return 2.0 * np.arctan2(s, q[3]) * q[:3] / s


def make_T(R_a_from_b: np.ndarray, t_a_b: np.ndarray) -> np.ndarray:
    """(4, 4) ``a_T_b`` mapping homogeneous points of frame b into frame a: [[R, t], [0, 1]] (4.11).

    ``t_a_b`` is the origin of b expressed in a (the dissertation writes -d for it).
    """
    T = np.eye(4)
    T[:3, :3] = R_a_from_b
    T[:3, 3] = t_a_b
    return T


def invert_T(a_T_b: np.ndarray) -> np.ndarray:
    """(4, 4) ``b_T_a`` of a rigid ``a_T_b``: [[R^T, -R^T t], [0, 1]] (4.12)."""
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    return make_T(R.T, -R.T @ t)


#: NED (x north, y east, z down) axes in ENU.
R_ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Optical axes (x right, y down, z forward) in a forward-right-down "look" frame (x along the axis).
R_LOOK_FROM_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _R_ned_from_ypr(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Aviation Euler angles (Z-Y-X, NED): yaw clockwise from north, pitch up positive, roll right down positive."""
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    return rot_z(y) @ rot_y(p) @ rot_x(r)


def R_enu_from_cam_aviation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """(3, 3) optical frame in ENU of a camera whose line of sight has the absolute aviation angles given.

    The angles of a gimbal as drones record them (DJI XMP GimbalYaw/Pitch/RollDegree, SRT gimbal
    fields): yaw clockwise from true north, pitch of the optical axis above the horizon (-90 is
    nadir), roll about the optical axis (right side down positive), applied Z-Y-X in NED. At yaw 0
    and pitch -90 the image top points north and the image right east.
    """
    return R_ENU_FROM_NED @ _R_ned_from_ypr(yaw_deg, pitch_deg, roll_deg) @ R_LOOK_FROM_CAM


def R_enu_from_cam_platform_sensor(heading_deg: float, pitch_deg: float, roll_deg: float,
                                   rel_azimuth_deg: float, rel_elevation_deg: float,
                                   rel_roll_deg: float = 0.0) -> np.ndarray:
    """(3, 3) optical frame in ENU of a turret camera (MISB ST0601 / EG0104 angles).

    The platform's attitude (heading clockwise from north, pitch nose up, roll right wing down; NED
    Z-Y-X) composed with the sensor's angles relative to the platform (azimuth clockwise from the
    nose, elevation negative below the platform's horizontal plane, roll about the line of sight),
    applied in that order about the platform axes (ST0601 tags 5-7 and 18-20).
    """
    R_ned_from_body = _R_ned_from_ypr(heading_deg, pitch_deg, roll_deg)
    R_body_from_look = _R_ned_from_ypr(rel_azimuth_deg, rel_elevation_deg, rel_roll_deg)
    return R_ENU_FROM_NED @ R_ned_from_body @ R_body_from_look @ R_LOOK_FROM_CAM


def aviation_angles_from_R_enu_from_cam(R_enu_from_cam: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in degrees of a camera's line of sight, the inverse of R_enu_from_cam_aviation.

    Pitch in [-90, 90]; at nadir exactly, yaw and roll turn about the same axis and the split
    returned puts it all in yaw.
    """
    R = R_ENU_FROM_NED.T @ np.asarray(R_enu_from_cam, dtype=np.float64) @ R_LOOK_FROM_CAM.T
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    if abs(abs(pitch) - np.pi / 2) < 1e-9:
        yaw, roll = float(np.arctan2(-R[0, 1], R[1, 1])), 0.0
    else:
        yaw, roll = float(np.arctan2(R[1, 0], R[0, 0])), float(np.arctan2(R[2, 1], R[2, 2]))
    return float(np.degrees(yaw)), float(np.degrees(pitch)), float(np.degrees(roll))
