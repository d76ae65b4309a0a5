"""The message types of srmosaic/registration and srmosaic/raster: portable or typed.

``live.message_types: portable`` (the default) carries them in standard messages any ROS 2
installation has: std_msgs/Float64MultiArray (REGISTRATION_LAYOUT in common.py) and std_msgs/String
(JSON, live/raster.py). ``typed`` carries them as srmosaic_interfaces/Registration and
RasterGeoreference (interfaces/srmosaic_interfaces, built with colcon: docs/guide/live.md, "Typed messages").
A graph must use one kind on both ends of a topic (DDS matches publishers and subscriptions by
type), so set it for the whole graph, as live.georef_standalone.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from std_msgs.msg import Float64MultiArray, String

from ..errors import SrMosaicError
from ..live.live_config import MESSAGE_TYPES  # re-exported: the nodes name it here
from ..live.raster import LiveRaster
from .common import RegistrationMsg, decode_registration, encode_registration

__all__ = ['MESSAGE_TYPES', 'Messages', 'message_kind']


def message_kind(node: Any) -> str:
    """live.message_types of ``node``, checked (SrMosaicError: the values, or how to get the typed
    messages when this Python cannot import them)."""
    from .node_checks import check_message_types

    return check_message_types(node.get_parameter('live.message_types').value)


class Messages:
    """Types and conversions of the two topics for one kind (see the module docstring)."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        if kind == 'typed':
            from srmosaic_interfaces.msg import RasterGeoreference, Registration

            self.registration_type: type = Registration
            self.raster_type: type = RasterGeoreference
        else:
            self.registration_type, self.raster_type = Float64MultiArray, String

    def registration(self, stamp_ns: int, painted: bool, inliers: int, rms_px: float, segment: int,
                     seg_H_frame: np.ndarray | None, prev_H_cur: np.ndarray | None, reg_ok: bool,
                     covariance: np.ndarray | None) -> Any:
        """The srmosaic/registration message of one processed frame (NaN where a matrix is unknown)."""
        if self.kind != 'typed':
            return encode_registration(stamp_ns, painted, inliers, rms_px, segment, seg_H_frame, prev_H_cur, reg_ok,
                                       covariance)
        msg = self.registration_type()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
        msg.version = self.registration_type.VERSION
        msg.ok, msg.inliers, msg.rms_px, msg.segment = bool(painted), int(inliers), float(rms_px), int(segment)
        msg.seg_h_frame = _flat(seg_H_frame, 9)
        msg.prev_h_cur = _flat(prev_H_cur, 9)
        msg.reg_ok = bool(reg_ok)
        msg.prev_h_cur_covariance = _flat(covariance, 64)
        return msg

    def read_registration(self, msg: Any) -> RegistrationMsg:
        """A received srmosaic/registration message; SrMosaicError when it is malformed."""
        if self.kind != 'typed':
            return decode_registration(msg)
        seg_H, prev_H = _matrix(msg.seg_h_frame, 3), _matrix(msg.prev_h_cur, 3)
        cov = _matrix(msg.prev_h_cur_covariance, 8)
        return RegistrationMsg(stamp_ns=int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec),
                               ok=bool(msg.ok), inliers=int(msg.inliers), rms_px=float(msg.rms_px),
                               segment=int(msg.segment), seg_H_frame=seg_H, prev_H_cur=prev_H, reg_ok=bool(msg.reg_ok),
                               covariance=cov)

    def raster(self, raster: LiveRaster, stamp_ns: int = 0) -> Any:
        """The srmosaic/raster message of ``raster``."""
        if self.kind != 'typed':
            return String(data=raster.text())
        msg = self.raster_type()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
        msg.version = self.raster_type.VERSION
        msg.epsg, msg.gsd_m_per_px = int(raster.epsg), float(raster.gsd_m_per_px)
        msg.origin_easting_m, msg.origin_northing_m = float(raster.origin_easting_m), float(raster.origin_northing_m)
        msg.rotation_rad = float(raster.rotation_rad)
        msg.canvas_h_raster = _flat(raster.canvas_H_raster, 9)
        return msg

    def read_raster(self, msg: Any) -> LiveRaster:
        """A received srmosaic/raster message; SrMosaicError when it is malformed."""
        if self.kind != 'typed':
            return LiveRaster.parse(msg.data)
        if msg.epsg <= 0 or not (np.isfinite(msg.gsd_m_per_px) and msg.gsd_m_per_px > 0):
            text = f'srmosaic/raster with epsg {msg.epsg} and gsd {msg.gsd_m_per_px}: not a raster.'
            raise SrMosaicError(text)
        return LiveRaster(int(msg.epsg), float(msg.gsd_m_per_px), float(msg.origin_easting_m),
                          float(msg.origin_northing_m), float(msg.rotation_rad), _matrix(msg.canvas_h_raster, 3))


def _flat(matrix: np.ndarray | None, size: int) -> np.ndarray:
    """A matrix as the float64[size] field (NaN when unknown or of another size)."""
    values = np.full(size, np.nan) if matrix is None else np.asarray(matrix, dtype=np.float64).ravel()
    return values if values.size == size else np.full(size, np.nan)


def _matrix(values: Any, n: int) -> np.ndarray | None:
    """A float64[n * n] field as an (n, n) matrix, or None when it holds NaN (unknown)."""
    m = np.asarray(values, dtype=np.float64).reshape(n, n)
    return m if np.all(np.isfinite(m)) else None
