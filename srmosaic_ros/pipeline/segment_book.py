"""The segments of a run, and which of them owns the shared georeferenced canvas."""
from __future__ import annotations

import numpy as np

from ..config import PipelineConfig
from ..core.mosaic.segments import Segment
from .checkpointed import Checkpointed

__all__ = ['SegmentBook', 'plane_scale']


def plane_scale(max_width: int, width: int) -> float:
    """Mosaic pixels per frame pixel of a segment's first frame, ``width`` px wide: 1, or
    max_width / width when the frame is wider than ``max_width`` (mosaic.max_width; <= 0: no limit)."""
    return 1.0 if max_width <= 0 or width <= max_width else max_width / width


def first_frame_plane(max_width: int, width: int) -> np.ndarray:
    """(3, 3) seg_H_frame of a segment's first frame in its own pixel plane: diag(s, s, 1), s = plane_scale."""
    s = plane_scale(max_width, width)
    return np.diag([s, s, 1.0])


class SegmentBook(Checkpointed):
    """segments: every segment, in order; geo_canvas: the first georeferenced one, whose canvas (the
    Georeferencer's UTM raster) later georeferenced segments share; active: the one being extended."""

    STATE = (('segments', 'segments'), ('_geo_canvas', 'geo_canvas'), ('_active', 'active'))

    def __init__(self, config: PipelineConfig) -> None:
        self.config = config
        self.segments: list[Segment] = []
        self.geo_canvas: Segment | None = None
        self.active: Segment | None = None

    def open(self, channels: int, *, georeferenced: bool) -> Segment:
        """A new segment of ``channels`` channels, on the shared canvas when georeferenced and one exists."""
        shared = self.geo_canvas.canvas if (georeferenced and self.geo_canvas is not None) else None
        seg = Segment.create(len(self.segments), channels, self.config.mosaic, canvas=shared)
        seg.georeferenced = georeferenced
        if georeferenced and self.geo_canvas is None:
            self.geo_canvas = seg
        self.segments.append(seg)
        return seg
