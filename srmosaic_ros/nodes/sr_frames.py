"""SRFrameDecoder: the SR node's frames decoded on first use and undistorted as the mosaic node's are.

Images are kept as their messages until a tile uses them (live/sr_scheduler.py); then they are
decoded (nodes.common.camera_image: the newest /camera/camera_info scaled to the image) and lens
distortion removed (core/undistort.py), because the registrations are of undistorted frames.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from sensor_msgs.msg import Image

from ..core.types import CameraIntrinsics
from ..core.undistort import Undistorter
from ..errors import SrMosaicError
from ..live.sr import LiveFrame
from .common import camera_image

__all__ = ['SRFrameDecoder', 'header_size']


def header_size(payload: Any) -> tuple[int, int] | None:
    """(width, height) a kept image's message says (sensor_msgs/Image), None for others (compressed)."""
    return (int(payload.width), int(payload.height)) if isinstance(payload, Image) else None


class SRFrameDecoder:
    """Decodes kept frames (module docstring). ``warn``: the node's WarnOnce."""

    def __init__(self, undistort: Any, warn: Any) -> None:
        self.camera: CameraIntrinsics | None = None  # the newest CameraInfo's intrinsics
        self._undistorter = Undistorter(undistort)
        self._warn = warn

    def __call__(self, frame: LiveFrame) -> np.ndarray | None:
        """The frame's pixels (H, W[, 3]) uint8/uint16, decoded on first use and kept decoded."""
        if isinstance(frame.payload, np.ndarray):
            return frame.payload
        decoded = camera_image(frame.payload, self.camera, self._warn)
        if decoded is None:
            return None
        image, camera = decoded
        try:
            image = self._undistorter.image(image, camera)
        except SrMosaicError as exc:
            self._warn(f'image: {type(exc).__name__}', f'image skipped: {exc}')
            return None
        frame.payload = image
        return image
