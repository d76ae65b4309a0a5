"""ROS messages <-> numpy arrays and the plain dataclasses of :mod:`srmosaic_ros.core.types`.

Readers are pure functions over the fields that rclpy and rosbags messages share, so one function
serves both (ROS 1 messages deserialised by rosbags too). Builders take ``flavor='rclpy'`` or
``flavor='rosbags'``; rclpy message modules are imported only when asked for.
"""
from __future__ import annotations

from ._flavor import FLAVORS, Flavor
from .camera_info import camera_info_to_intrinsics, intrinsics_to_camera_info
from .image import (
    COMPRESSED_FORMATS,
    SUPPORTED_ENCODINGS,
    image_to_numpy,
    image_to_rgb_or_mono,
    is_compressed_image,
    numpy_to_compressed,
    numpy_to_image,
)
from .imu import imu_to_sample, sample_to_imu
from .navsat import fix_to_navsat, navsat_to_fix
from .stamps import header_to_ns_frame, make_header, ns_to_stamp, stamp_to_ns

__all__ = [
    'COMPRESSED_FORMATS',
    'FLAVORS',
    'SUPPORTED_ENCODINGS',
    'Flavor',
    'camera_info_to_intrinsics',
    'fix_to_navsat',
    'header_to_ns_frame',
    'image_to_numpy',
    'image_to_rgb_or_mono',
    'imu_to_sample',
    'intrinsics_to_camera_info',
    'is_compressed_image',
    'make_header',
    'navsat_to_fix',
    'ns_to_stamp',
    'numpy_to_compressed',
    'numpy_to_image',
    'sample_to_imu',
    'stamp_to_ns',
]
