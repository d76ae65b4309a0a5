"""MosaicOutputs: the mosaic node's per-frame publishers (registration, poses, footprint).

The worker (live/mosaic_worker.py) hands each processed frame's record here, outside the pipeline
lock: /srmosaic/registration (REGISTRATION_LAYOUT in nodes/common.py), /srmosaic/pose, /srmosaic/fix
and /srmosaic/odom (nodes.common.PosePublisher; not with live.georef_standalone, where the georef
node publishes them) and, with the map tiles on, /srmosaic/footprint (geometry_msgs/PolygonStamped
in pixels of the /srmosaic/raster grid, frame_id srmosaic_raster).
"""
from __future__ import annotations

from typing import Any

import numpy as np
from geometry_msgs.msg import Point32, PolygonStamped

from ..live.map_tiles import FOOTPRINT_FRAME
from ..pipeline import FrameRecord
from .common import TOPICS, PosePublisher

__all__ = ['MosaicOutputs', 'footprint_message']


def footprint_message(stamp_ns: int, corners: np.ndarray) -> PolygonStamped:
    """/srmosaic/footprint: ``corners`` (N, 2) raster pixels, stamped with the frame's stamp (ns)."""
    msg = PolygonStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.header.frame_id = FOOTPRINT_FRAME
    msg.polygon.points = [Point32(x=float(x), y=float(y), z=0.0) for x, y in corners]
    return msg


class MosaicOutputs:
    """Publishers of what each frame gives (module docstring). ``poses``: publish the fused poses;
    ``footprints``: publish the footprint."""

    def __init__(self, node: Any, messages: Any, *, poses: bool, footprints: bool) -> None:
        self._messages = messages
        self._registration = node.create_publisher(messages.registration_type, TOPICS['registration'], 50)
        self._poses = PosePublisher(node) if poses else None  # one publisher of the poses per graph
        self._footprint = node.create_publisher(PolygonStamped, TOPICS['footprint'], 10) if footprints else None

    def registration(self, record: FrameRecord) -> None:
        reg = record.registration
        self._registration.publish(self._messages.registration(
            record.stamp_ns, record.painted, reg.inliers if reg else 0, reg.rms_px if reg else float('nan'),
            record.segment, record.seg_H_frame, reg.prev_H_cur if reg is not None else None,
            bool(reg is not None and reg.ok), getattr(reg, 'covariance', None)))

    def pose(self, record: FrameRecord) -> None:
        if self._poses is not None:
            self._poses.publish(record.stamp_ns, record.pose)

    def footprint(self, stamp_ns: int, corners: np.ndarray) -> None:
        if self._footprint is not None:
            self._footprint.publish(footprint_message(stamp_ns, corners))
