"""sensor_msgs/CameraInfo <-> :class:`~srmosaic_ros.core.types.CameraIntrinsics`.

ROS 2 names the matrices ``k, d, r, p``; ROS 1 bags read by rosbags name them ``K, D, R, P``.
Both are accepted. ``binning`` and ``roi`` are not applied: the intrinsics describe the full
``width`` x ``height`` sensor image, as the message does.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from srmosaic_ros.core.types import CameraIntrinsics
from srmosaic_ros.errors import MessageError

from ._flavor import check_flavor, float_field, new_message
from .stamps import make_header

__all__ = ['camera_info_to_intrinsics', 'intrinsics_to_camera_info']


def _matrix_field(msg: Any, name: str, size: int | None) -> np.ndarray:
    value = getattr(msg, name, None)
    if value is None:
        value = getattr(msg, name.upper(), None)
    if value is None:
        msg_ = f'CameraInfo.{name} is missing; is this a sensor_msgs/CameraInfo?'
        raise MessageError(msg_)
    values = np.asarray(value, dtype=np.float64).reshape(-1)
    if size is not None and values.size != size:
        msg_ = f'CameraInfo.{name} has {values.size} values; expected {size}.'
        raise MessageError(msg_)
    return values


def camera_info_to_intrinsics(msg: Any) -> CameraIntrinsics:
    """Intrinsics from a sensor_msgs/CameraInfo of either flavour (or a ROS 1 one from rosbags).

    fx, fy, cx, cy come from the camera matrix ``k`` (row-major 3x3).

    Raises:
        MessageError: zero or non-finite focal length (an uncalibrated camera), non-finite
            principal point or distortion, or zero width/height; the message names the field.

    """
    k = _matrix_field(msg, 'k', 9)
    d = _matrix_field(msg, 'd', None)
    fx, fy, cx, cy = (float(k[0]), float(k[4]), float(k[2]), float(k[5]))
    for name, value in (('fx', fx), ('fy', fy)):
        if not math.isfinite(value) or value <= 0.0:
            msg_ = (
                f'CameraInfo.k has focal length {name}={value}; it must be finite and positive. '
                'The camera is probably uncalibrated: calibrate it (camera_calibration) or give '
                'the intrinsics another way (--camera FILE or --hfov DEG).'
            )
            raise MessageError(msg_)
    for name, value in (('cx', cx), ('cy', cy)):
        if not math.isfinite(value):
            msg_ = (
                f'CameraInfo.k has principal point {name}={value}; it must be finite. '
                'Recalibrate the camera.'
            )
            raise MessageError(msg_)
    if not np.all(np.isfinite(d)):
        msg_ = f'CameraInfo.d has non-finite coefficients {d.tolist()}; recalibrate the camera.'
        raise MessageError(msg_)
    width, height = int(msg.width), int(msg.height)
    for name, value in (('width', width), ('height', height)):
        if value <= 0:
            msg_ = (
                f'CameraInfo.{name} is {value}; the camera info must state the calibrated image '
                'size. Fix the camera driver\'s calibration file.'
            )
            raise MessageError(msg_)
    return CameraIntrinsics(
        width=width,
        height=height,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        distortion_model=str(msg.distortion_model),
        distortion=tuple(float(x) for x in d),
    )


def intrinsics_to_camera_info(
    intr: CameraIntrinsics,
    *,
    stamp_ns: int = 0,
    frame_id: str = '',
    flavor: str = 'rclpy',
) -> Any:
    """sensor_msgs/CameraInfo of ``flavor``: ``k``, ``d``, ``r`` = identity, ``p`` = [K | 0]."""
    flavor = check_flavor(flavor)
    k = [intr.fx, 0.0, intr.cx, 0.0, intr.fy, intr.cy, 0.0, 0.0, 1.0]
    p = [intr.fx, 0.0, intr.cx, 0.0, 0.0, intr.fy, intr.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    return new_message(
        flavor,
        'sensor_msgs/msg/CameraInfo',
        header=make_header(stamp_ns, frame_id, flavor),
        height=int(intr.height),
        width=int(intr.width),
        distortion_model=str(intr.distortion_model),
        d=float_field(list(intr.distortion), flavor),
        k=float_field(k, flavor),
        r=float_field(r, flavor),
        p=float_field(p, flavor),
    )
