"""sensor_msgs/Imu <-> :class:`~srmosaic_ros.core.types.ImuSample`.

Conventions (sensor_msgs/Imu, REP 145): ``orientation_covariance[0] == -1`` means the message
carries no orientation; likewise ``angular_velocity_covariance[0]`` and
``linear_acceleration_covariance[0]`` for those vectors.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from srmosaic_ros.core.types import ImuSample
from srmosaic_ros.errors import MessageError

from ._flavor import check_flavor, float_field, new_message
from .stamps import header_to_ns_frame, make_header

__all__ = ['imu_to_sample', 'sample_to_imu']

_MIN_QUATERNION_NORM = 1e-6


def _covariance(msg: Any, name: str) -> np.ndarray:
    values = np.asarray(getattr(msg, name), dtype=np.float64).reshape(-1)
    if values.size != 9:
        msg_ = f'Imu.{name} has {values.size} values; expected 9.'
        raise MessageError(msg_)
    return values


def _vector(msg: Any, name: str) -> np.ndarray:
    """(3,) values of a Vector3 field; all NaN when its covariance[0] == -1 marks it missing (so that
    the zeros a driver sends then are not read as a measurement of no rotation)."""
    vec = getattr(msg, name)
    values = np.array([vec.x, vec.y, vec.z], dtype=np.float64)
    provided = _covariance(msg, f'{name}_covariance')[0] != -1.0
    if not provided:
        return np.full(3, np.nan)
    if not np.all(np.isfinite(values)):
        msg_ = (
            f'Imu.{name} {values.tolist()} is not finite although Imu.{name}_covariance[0] '
            'is not -1; the driver should mark missing data with covariance[0] = -1.'
        )
        raise MessageError(msg_)
    return values


def imu_to_sample(msg: Any) -> ImuSample:
    """ImuSample from a sensor_msgs/Imu of either flavour.

    ``orientation_xyzw`` is the unit (normalised) quaternion, or None when
    ``orientation_covariance[0] == -1``. A vector marked missing (its covariance[0] == -1) becomes
    NaN, whatever was sent in it.

    Raises:
        MessageError: NaN/infinite or zero-norm orientation quaternion (when provided), or a
            non-finite vector that is marked as provided; the message names the field.

    """
    stamp_ns, frame_id = header_to_ns_frame(msg)
    cov = _covariance(msg, 'orientation_covariance')
    orientation: np.ndarray | None = None
    if cov[0] != -1.0:
        q = msg.orientation
        quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
        if not np.all(np.isfinite(quat)):
            msg_ = (
                f'Imu.orientation {quat.tolist()} (x, y, z, w) is not finite; if the IMU gives no '
                'orientation, the driver must set orientation_covariance[0] = -1.'
            )
            raise MessageError(msg_)
        norm = float(np.linalg.norm(quat))
        if norm < _MIN_QUATERNION_NORM:
            msg_ = (
                'Imu.orientation is the zero quaternion, which is no rotation at all; if the IMU '
                'gives no orientation, the driver must set orientation_covariance[0] = -1.'
            )
            raise MessageError(msg_)
        orientation = quat / norm
        if not np.all(np.isfinite(cov)):
            msg_ = f'Imu.orientation_covariance has non-finite values {cov.tolist()}.'
            raise MessageError(msg_)
    return ImuSample(
        stamp_ns=stamp_ns,
        orientation_xyzw=orientation,
        angular_velocity_rad_s=_vector(msg, 'angular_velocity'),
        linear_acceleration_m_s2=_vector(msg, 'linear_acceleration'),
        orientation_covariance=cov.reshape(3, 3).copy(),
        frame_id=frame_id,
    )


def sample_to_imu(sample: ImuSample, *, flavor: str = 'rclpy') -> Any:
    """sensor_msgs/Imu of ``flavor``; a None orientation becomes covariance[0] = -1.

    Angular velocity and linear acceleration covariances are written as zeros (unknown); a NaN
    vector (not provided) is written as zeros with covariance[0] = -1.
    """
    flavor = check_flavor(flavor)
    if sample.orientation_xyzw is None:
        quat = np.array([0.0, 0.0, 0.0, 1.0])
        cov = np.zeros(9)
        cov[0] = -1.0
    else:
        quat = np.asarray(sample.orientation_xyzw, dtype=np.float64).reshape(4)
        cov = np.asarray(sample.orientation_covariance, dtype=np.float64).reshape(9)

    def vector3(values: np.ndarray) -> Any:
        values = np.asarray(values, dtype=np.float64).reshape(3)
        x, y, z = (float(v) for v in (np.zeros(3) if np.all(np.isnan(values)) else values))
        return new_message(flavor, 'geometry_msgs/msg/Vector3', x=x, y=y, z=z)

    def vector_covariance(values: np.ndarray) -> Any:
        cov = np.zeros(9)
        if np.all(np.isnan(np.asarray(values, dtype=np.float64))):
            cov[0] = -1.0
        return float_field(cov, flavor)

    return new_message(
        flavor,
        'sensor_msgs/msg/Imu',
        header=make_header(sample.stamp_ns, sample.frame_id, flavor),
        orientation=new_message(
            flavor,
            'geometry_msgs/msg/Quaternion',
            x=float(quat[0]),
            y=float(quat[1]),
            z=float(quat[2]),
            w=float(quat[3]),
        ),
        orientation_covariance=float_field(cov, flavor),
        angular_velocity=vector3(sample.angular_velocity_rad_s),
        angular_velocity_covariance=vector_covariance(sample.angular_velocity_rad_s),
        linear_acceleration=vector3(sample.linear_acceleration_m_s2),
        linear_acceleration_covariance=vector_covariance(sample.linear_acceleration_m_s2),
    )
