"""Plausibility checks of an inter-frame homography.

A homography between consecutive UAS frames is close to a similarity: small perspective, a scale
change of at most a few tens of percent, no fold-over. Anything else is a misregistration and must
be reported (Registration.ok = False) rather than painted.
"""
from __future__ import annotations

import math

import numpy as np


__all__ = ['check_homography', 'frame_corners']


def frame_corners(width: int, height: int) -> np.ndarray:
    """(4, 2) float64 corners of a width x height image, pixel centres at integers, clockwise."""
    return np.array(
        [[0.0, 0.0], [width - 1.0, 0.0], [width - 1.0, height - 1.0], [0.0, height - 1.0]],
    )


def check_homography(
    prev_H_cur: np.ndarray,
    width: int,
    height: int,
    *,
    max_scale_change: float = 1.6,
    max_perspective: float = 0.3,
) -> str:
    """Return '' if prev_H_cur is plausible for consecutive frames, else the reason.

    Args:
        prev_H_cur: (3, 3) homography from current-frame pixels to previous-frame pixels.
        width, height: current frame size in pixels.
        max_scale_change: largest accepted area scale factor change (and its inverse), per side.
        max_perspective: largest accepted relative change of the projective depth w = h20 x + h21 y + h22
            over the frame (0.3 means w varies by at most 30% between corners).
    """
    H = np.asarray(prev_H_cur, dtype=np.float64)
    if H.shape != (3, 3) or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
        return 'homography is not finite or has h22 = 0'
    # Plain floats on the four corners: this runs twice per registered pair, and on 4-point arrays
    # numpy's per-call overhead would dominate.
    h = (H / H[2, 2]).ravel().tolist()
    corners = ((0.0, 0.0), (width - 1.0, 0.0), (width - 1.0, height - 1.0), (0.0, height - 1.0))
    w = [h[6] * x + h[7] * y + h[8] for x, y in corners]
    if min(w) <= 0:
        return 'homography maps part of the frame through the horizon (w <= 0)'
    if max(w) / min(w) > 1.0 + max_perspective:
        return f'perspective change {max(w) / min(w) - 1.0:.2f} exceeds {max_perspective:.2f}'
    warped = [((h[0] * x + h[1] * y + h[2]) / wk, (h[3] * x + h[4] * y + h[5]) / wk)
              for (x, y), wk in zip(corners, w, strict=True)]
    # Convexity and orientation of the warped quadrilateral: the cross products of consecutive
    # edges must all share the sign of the original (a fold-over flips one of them).
    edges = [(warped[(i + 1) % 4][0] - warped[i][0], warped[(i + 1) % 4][1] - warped[i][1]) for i in range(4)]
    cross = [edges[i][0] * edges[(i + 1) % 4][1] - edges[i][1] * edges[(i + 1) % 4][0] for i in range(4)]
    if not (all(c > 0 for c in cross) or all(c < 0 for c in cross)):
        return 'warped frame is not convex (fold-over)'
    if all(c < 0 for c in cross):
        return 'homography mirrors the frame'
    area = 0.5 * abs(sum(warped[i][0] * warped[(i + 1) % 4][1] - warped[(i + 1) % 4][0] * warped[i][1]
                         for i in range(4)))
    area0 = (width - 1.0) * (height - 1.0)
    side_scale = math.sqrt(area / area0)
    if not (1.0 / max_scale_change <= side_scale <= max_scale_change):
        return f'scale change {side_scale:.2f} outside [{1.0 / max_scale_change:.2f}, {max_scale_change:.2f}]'
    return ''
