"""Mosaic segments: the frames chained into one common plane (eq. 4.6) and their canvas.

A frame that fails to register does not smear the mosaic: it is held as an orphan. The next frame
is tried against the last good frame first (a single bad frame is skipped), then against the
orphan (the scene changed: the orphan starts a new segment with the next frame). A segment's
plane is the pixel plane of its first frame, or, when georeferenced, the shared north-up raster of
the Georeferencer: georeferenced segments then share one canvas.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .canvas import TiledCanvas
from .config import MosaicConfig

__all__ = ['Segment']


@dataclass
class Segment:
    """One connected mosaic: frame indices and their seg_H_frame homographies, and the canvas."""

    index: int
    canvas: TiledCanvas
    frames: list[int] = field(default_factory=list)
    seg_H_frames: dict[int, np.ndarray] = field(default_factory=dict)
    georeferenced: bool = False

    @classmethod
    def create(cls, index: int, channels: int, config: MosaicConfig, *, canvas: TiledCanvas | None = None) -> Segment:
        """A new segment on a new canvas, or on `canvas` (shared with the other georeferenced segments)."""
        if canvas is not None:
            return cls(index, canvas)
        return cls(index, TiledCanvas(channels, tile_size=config.tile_size, blend=config.blend,
                                      max_canvas_side_px=config.max_canvas_side_px,
                                      max_tiles_in_memory=config.max_tiles_in_memory, spill_dir=config.spill_dir,
                                      max_stretch=config.max_stretch, recency_frames=config.recency_frames, agree=config.agree, moving=config.moving,
                                      moving_history=config.moving_history, seams=config.seams,
                                      interpolation=config.interpolation))

    def add(self, frame_index: int, image: np.ndarray, seg_H_frame: np.ndarray) -> None:
        """Paint a frame (float32 (H, W, C) in [0, 1]) into the segment at seg_H_frame."""
        self.canvas.paint(image, seg_H_frame)
        self.place(frame_index, seg_H_frame)

    def place(self, frame_index: int, seg_H_frame: np.ndarray) -> None:
        """Record a frame as part of the segment at seg_H_frame (its paint is the caller's: add() does both)."""
        self.frames.append(frame_index)
        self.seg_H_frames[frame_index] = seg_H_frame

    def unplace(self, frame_index: int) -> None:
        """Forget a placed frame (its paint was refused after all)."""
        if frame_index in self.seg_H_frames:
            del self.seg_H_frames[frame_index]
            self.frames.remove(frame_index)
