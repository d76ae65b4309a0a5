"""A frame's image as the canvas paints it: averaged down to the mosaic's sampling when it is much
finer (core/mosaic/minify.py), and converted to the canvas's channel count."""
from __future__ import annotations

import numpy as np

from ..config import PipelineConfig
from ..core.image_ops import to_float01
from ..core.mosaic.best_view import clip_depth
from ..core.mosaic.minify import area_factor, area_reduce, finest_stretch
from ..core.mosaic.scratch import scratch
from .checkpointed import Checkpointed

__all__ = ['PaintInput']


class PaintInput(Checkpointed):
    """channels: the canvas's channel count, that of the first frame (later ones are converted to it)."""

    STATE = (('_channels', 'channels'),)

    def __init__(self, config: PipelineConfig) -> None:
        self.config = config
        self.channels: int | None = None

    def note_first(self, image: np.ndarray) -> None:
        """Take the canvas's channel count from ``image`` (H, W) or (H, W, C) unless it is known."""
        if self.channels is None:
            self.channels = 1 if image.ndim == 2 else image.shape[2]

    def prepare(self, raw: np.ndarray, seg_H_frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(image, seg_H_image) to paint for a frame: a frame much finer than the mosaic is averaged
        down to the mosaic's sampling first, on its integer pixels (minify.area_reduce). float32,
        or uint8 as it came when its channels are the canvas's (the canvas warps integers faster)."""
        k = self.area_factor(raw, seg_H_frame)
        if k == 1:
            return self.as_paintable(raw), seg_H_frame
        if raw.dtype == np.uint8:
            small, seg_H_small = area_reduce(raw, seg_H_frame, k)
            return self.as_paintable(small), seg_H_small
        small, seg_H_small = area_reduce(self.as_canvas_image(raw), seg_H_frame, k)
        return np.ascontiguousarray(small, dtype=np.float32), seg_H_small

    def area_factor(self, image: np.ndarray, seg_H_frame: np.ndarray) -> int:
        """The block size (minify.area_factor) a frame at seg_H_frame is averaged down by before it is painted."""
        h, w = image.shape[:2]
        return area_factor(finest_stretch(seg_H_frame, w, h, clip_depth(seg_H_frame, w, h, self.config.mosaic.max_stretch)))

    def as_paintable(self, image: np.ndarray) -> np.ndarray:
        """A uint8 image with the canvas's channel count as it is, else :meth:`as_canvas_image`."""
        if image.dtype == np.uint8 and (image.shape[2] if image.ndim == 3 else 1) == (self.channels or 0):
            return image
        return self.as_canvas_image(image)

    def as_canvas_image(self, image: np.ndarray) -> np.ndarray:
        """Edge image -> float32 (H, W, C) in [0, 1] with the channel count of the first frame. A uint8
        image is converted into this thread's scratch array 'frame' (core.mosaic.scratch): valid until
        the next conversion on the thread, so only for the canvas's paint, which keeps no reference."""
        if image.dtype == np.uint8:  # to_float01's values, without a fresh full-frame array per frame
            f = np.multiply(image, np.float32(1.0 / 255.0), out=scratch('frame', image.shape), dtype=np.float32)
        else:
            f = to_float01(image)
        if f.ndim == 2:
            f = f[:, :, None]
        if self.channels is None:
            self.channels = f.shape[2]
        if f.shape[2] != self.channels:
            f = np.repeat(f, 3, axis=2) if f.shape[2] == 1 else f.mean(axis=2, keepdims=True)
        return np.ascontiguousarray(f, dtype=np.float32)
