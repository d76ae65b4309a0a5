"""Keyframe-to-mosaic registration: every few frames, register the frame to the mosaic itself.

Chaining frame-to-frame homographies (4.6) lets small errors add up: the mosaic drifts, and where
the flight comes back over ground it has seen (the return legs of a lawnmower survey), the new
frames no longer line up with the old ones. A keyframe is registered to the mosaic already on the
canvas instead: the canvas is rendered into the frame's predicted view,

    view(x) = mosaic(seg_H_frame_pred @ x)          (x: frame pixels),

the frame is registered to that view (view_H_cur, by the same registrar as frame pairs), and

    seg_H_frame = seg_H_frame_pred @ view_H_cur

places the frame where it agrees with everything painted under it (old legs included), not only
with the previous frame. The next frames chain from the corrected keyframe. By default a keyframe
(every `keyframe_interval`-th frame of a segment) is registered only where it revisits ground
painted at least `keyframe_revisit_frames` frames before by another pass (one that ended by moving
away, or by turning: an orbit looking at its centre; Pipeline._revisits): along a straight leg the
rendered (blended, twice resampled) view is a slightly worse reference than the previous frame
itself (bench/drift.py compares the settings). A correction larger than
`keyframe_max_correction_px` at the frame corners or smaller than `keyframe_min_correction_px`
(the rendered view's own error), a view the mosaic covers too little, or a failed registration
leaves the predicted placement as it was (and is counted).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..homography import corner_shift_px
from .canvas import TiledCanvas

__all__ = ['KeyframeResult', 'corner_shift_px', 'render_view']


@dataclass(frozen=True)
class KeyframeResult:
    """Outcome of one keyframe registration.

    seg_H_frame: the corrected placement (3, 3), or None when the prediction was kept.
    coverage: fraction of the frame's view the mosaic covered; shift_px: largest corner move of
    the correction (NaN when none was estimated); reason: why it was not applied ('' if applied).
    """

    seg_H_frame: np.ndarray | None
    coverage: float
    shift_px: float
    reason: str = ''


def render_view(canvas: TiledCanvas, seg_H_frame: np.ndarray, width: int, height: int, *,
                gray: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The mosaic's feather composite (TiledCanvas.render_reference, whatever the blend) as the frame
    would see it under seg_H_frame.

    Returns (view, covered): view float32 (height, width, C) in [0, 1] (C = 1 with ``gray``: the
    Rec. 601 luminance, all that registration uses, a third of the warping), uncovered pixels
    filled with the covered mean (flat: no features there); covered bool (height, width).
    """
    corners = np.array([[0.0, 0.0, 1.0], [width, 0.0, 1.0], [width, height, 1.0], [0.0, height, 1.0]]) @ seg_H_frame.T
    xy = corners[:, :2] / corners[:, 2:3]
    bx0, by0, bx1, by1 = canvas.bounds()
    x0 = max(int(np.floor(xy[:, 0].min())) - 2, bx0)
    y0 = max(int(np.floor(xy[:, 1].min())) - 2, by0)
    x1 = min(int(np.ceil(xy[:, 0].max())) + 3, bx1)
    y1 = min(int(np.ceil(xy[:, 1].max())) + 3, by1)
    channels = 1 if gray else canvas.channels
    if x1 - x0 < 2 or y1 - y0 < 2:
        return np.zeros((height, width, channels), np.float32), np.zeros((height, width), bool)
    image, covered = canvas.render_reference((x0, y0, x1, y1))
    if gray and image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2GRAY)
    if image.ndim == 2:
        image = image[:, :, None]
    # dst(x) = src(M x) with M = T(-x0, -y0) seg_H_frame (WARP_INVERSE_MAP).
    m = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ seg_H_frame
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    view = cv2.warpPerspective(np.ascontiguousarray(image, np.float32), m, (width, height), flags=flags,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    cov = cv2.warpPerspective(covered.astype(np.uint8) * 255, m, (width, height), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 127
    if view.ndim == 2:
        view = view[:, :, None]
    if cov.any():
        fill = view[cov].mean(axis=0)
        view[~cov] = fill
    return view, cov
