"""Where a frame lands on the canvas: the checks of its homography and the box of mosaic pixels it
touches (the refusals of absurd homographies and of canvases beyond their bound)."""
from __future__ import annotations

import math

import numpy as np

from ..homography import project_points
from .best_view import clip_depth, clipped_polygon
from .canvas_settings import CanvasError, PlacementSettings

__all__ = ['checked_homography', 'placement_box']


def checked_homography(mosaic_h_frame: np.ndarray, w: int, h: int, max_stretch: float) -> np.ndarray:
    """Checked float64 (3, 3) homography of a w x h frame, signed so that its projective depth is positive
    over the frame (``max_stretch`` > 0: over the part of it the canvas paints)."""
    m = np.asarray(mosaic_h_frame, dtype=np.float64)
    if m.shape != (3, 3):
        msg = f'mosaic_H_frame must be a 3x3 matrix, got shape {m.shape}.'
        raise CanvasError(msg)
    if not np.isfinite(m).all():
        msg = f'mosaic_H_frame has non-finite entries:\n{m}\nthe registration or chain diverged; skip this frame.'
        raise CanvasError(msg)
    if not np.abs(m).max() > 0:
        msg = 'mosaic_H_frame is the zero matrix; skip this frame.'
        raise CanvasError(msg)
    corners = np.array([[-1.0, -1.0], [w, -1.0], [w, h], [-1.0, h]])
    _, depth = project_points(m, corners)
    if (depth <= 0).all():
        m = -m
        depth = -depth
    tol = 1e-9 * np.abs(depth).max()
    if not (depth > tol).all() and not max_stretch > 0:
        msg = ('mosaic_H_frame maps part of the frame beyond the horizon (the projective depth '
               f'changes sign over the frame: {depth.tolist()}); the homography is absurd, skip this frame '
               '(or set mosaic.max_stretch to paint the part of the frame below the horizon).')
        raise CanvasError(msg)
    corners = clipped_polygon(m, corners, clip_depth(m, w, h, max_stretch))
    if len(corners) < 3:
        msg = 'mosaic_H_frame maps the whole frame beyond the horizon; the homography is absurd, skip this frame.'
        raise CanvasError(msg)
    pts, _ = project_points(m, corners)
    x, y = pts[:, 0], pts[:, 1]
    area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    if not area > 1e-6 * (w + 1) * (h + 1):
        msg = f'mosaic_H_frame is (nearly) singular, it collapses the frame to area {area:.3g} px^2:\n{m}\nskip this frame.'
        raise CanvasError(msg)
    return m


def placement_box(m: np.ndarray, w: int, h: int, limits: PlacementSettings,
                  bounds: tuple[int, int, int, int] | None) -> tuple[int, int, int, int]:
    """Bounding box (x0, y0, x1, y1) of the mosaic pixels a w x h frame at m (a checked homography)
    touches; CanvasError when it is absurd or would make a canvas of ``bounds`` (None: empty) exceed
    ``limits.max_canvas_side_px``."""
    # Bilinear sampling gives non-zero weight to mosaic pixels mapping inside (-1, W) x (-1, H)
    # (one pixel beyond the cut of max_stretch: the depth changes by |m20| + |m21| per pixel).
    d_min = clip_depth(m, w, h, limits.max_stretch)
    if d_min is not None:
        d_min = max(d_min - abs(m[2, 0]) - abs(m[2, 1]), 0.5 * d_min)
    support, _ = project_points(m, clipped_polygon(m, np.array([[-1.0, -1.0], [w, -1.0], [w, h], [-1.0, h]]), d_min))
    lo = support.min(axis=0)
    hi = support.max(axis=0)
    bw_f, bh_f = hi[0] - lo[0], hi[1] - lo[1]
    if bw_f * bh_f > limits.max_area_ratio * max(w * h, 64):
        msg = (f'the footprint of a {w}x{h} frame spans {bw_f:.0f}x{bh_f:.0f} mosaic pixels, more than '
               f'{limits.max_area_ratio:g} times the frame area; mosaic_H_frame is absurd:\n{m}\n'
               'skip this frame (or raise max_area_ratio if such a zoom is intended).')
        raise CanvasError(msg)
    x0, y0 = math.floor(lo[0]), math.floor(lo[1])
    x1, y1 = math.floor(hi[0]) + 1, math.floor(hi[1]) + 1
    ux0, uy0, ux1, uy1 = (x0, y0, x1, y1) if bounds is None else (
        min(x0, bounds[0]), min(y0, bounds[1]), max(x1, bounds[2]), max(y1, bounds[3]))
    if max(ux1 - ux0, uy1 - uy0) > limits.max_canvas_side_px:
        msg = (f'painting this frame would make the canvas {ux1 - ux0}x{uy1 - uy0} px, beyond '
               f'max_canvas_side_px={limits.max_canvas_side_px} (footprint bbox x [{x0}, {x1}), y [{y0}, {y1})); '
               'the chain has drifted or the homography is absurd: skip the frame or start a new segment.')
        raise CanvasError(msg)
    return x0, y0, x1, y1
