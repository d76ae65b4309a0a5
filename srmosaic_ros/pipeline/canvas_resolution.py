"""When and how finely a segment's canvas samples its plane (mosaic.resolution, mosaic.oversample;
the rule is core/mosaic/resolution.py's).

``first``: the zoom is known with the first frame (mosaic.oversample): its plane is refined at once.
``finest``: a segment's first frames are held as a georeferenced segment's are (mosaic.settle_s,
mosaic.settle_max_frames; Settler), placed on the unrefined plane; when they settle their scales on
it decide the zoom, and their placements (and the raster's gsd, for the georeferenced canvas) are
refined before any of them is painted. A georeferenced segment that shares a canvas already painted
keeps its sampling.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.homography import project_points
from ..core.mosaic.config import MosaicConfig
from ..core.mosaic.resolution import canvas_zoom, frame_scale

__all__ = ['decided_at_settle', 'footprint_area_px', 'settled_zoom', 'start_zoom']


def decided_at_settle(cfg: MosaicConfig) -> bool:
    """Whether a segment's first frames are held for its sampling (``finest`` with a settling span)."""
    return cfg.resolution == 'finest' and cfg.settle_s > 0 and cfg.settle_max_frames > 1


def footprint_area_px(plane_H_frame: np.ndarray, w: int, h: int) -> float:
    """Area (plane pixels squared) of a w x h frame's corners through ``plane_H_frame`` (3, 3) (shoelace)."""
    pts, _ = project_points(np.asarray(plane_H_frame, dtype=np.float64),
                            np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]))
    x, y = pts[:, 0], pts[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def start_zoom(cfg: MosaicConfig, plane_H_first: np.ndarray, w: int, h: int) -> float:
    """The zoom of a segment whose sampling is known with its first frame (w x h at ``plane_H_first``)."""
    return canvas_zoom('first', cfg.oversample, [], first_area_px=footprint_area_px(plane_H_first, w, h),
                       tile_size=cfg.tile_size, max_tiles_in_memory=cfg.max_tiles_in_memory)


def settled_zoom(cfg: MosaicConfig, plane_H_frames: Sequence[np.ndarray], sizes: Sequence[tuple[int, int]]) -> float:
    """The zoom of a segment whose first frames (sizes (w, h)) settled at ``plane_H_frames`` on its plane."""
    scales = [frame_scale(m, w, h) for m, (w, h) in zip(plane_H_frames, sizes, strict=True)]
    w0, h0 = sizes[0]
    return canvas_zoom(cfg.resolution, cfg.oversample, scales, first_area_px=footprint_area_px(plane_H_frames[0], w0, h0),
                       tile_size=cfg.tile_size, max_tiles_in_memory=cfg.max_tiles_in_memory)
