"""Revisit corrections spread back over the frames that led to them (a windowed solve of the chain).

A keyframe that flies over old ground is registered to the mosaic there (keyframe.py), and its
placement moves from the chain's prediction H_k to the mosaic's answer H_k'. The chain between the
last fixed placement (the previous applied keyframe, or the last frame already painted) and frame k
drifted by that much, a little per registration: chaining adds independent errors, so the drift is
a random walk, and pinned at both ends (zero at the anchor, the correction at k) its expected value
at frame j is the straight line between them (the mean of a Brownian bridge):

    c_j' = c_j + t_j (D c_j - c_j),   D = H_k' inv(H_k),   t_j = (j - a) / (k - a)

for the mosaic corners c_j = H_j x_corner of each frame j between the anchor a and k. Moving those
frames before they are painted leaves no step of the whole correction between frame k-1 and k (a
tear across the strip the flight paints) and puts the frames approaching the old ground on it.
"""
from __future__ import annotations

import numpy as np

from ..georef.ground_homography import homographies_from_corners
from ..homography import apply_homography

__all__ = ['footprint_pose', 'spread_correction']


def _corners(width: int, height: int) -> np.ndarray:
    """(4, 2) frame corners (pixel centres at integers), as corner_shift_px measures them."""
    return np.array([[0.0, 0.0], [width - 1.0, 0.0], [width - 1.0, height - 1.0], [0.0, height - 1.0]])


def footprint_pose(seg_H_frame: np.ndarray, width: int, height: int) -> np.ndarray:
    """(3,) where a frame lies on the mosaic: its centre (x, y, mosaic px) and the direction of its
    x axis there (radians, counter-clockwise from the mosaic's x axis in image coordinates), from
    seg_H_frame (3, 3) and its size in px."""
    centre_and_right = apply_homography(seg_H_frame, np.array([[width / 2, height / 2], [width * 0.75, height / 2]]))
    dx, dy = centre_and_right[1] - centre_and_right[0]
    return np.array([*centre_and_right[0], np.arctan2(dy, dx)])


def spread_correction(seg_H_frames: list[np.ndarray], sizes: list[tuple[int, int]], predicted: np.ndarray,
                      corrected: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Move the frames between the anchor and a corrected keyframe by their share of its correction.

    seg_H_frames: the m frames' placements (3, 3), oldest first, strictly between the anchor (t = 0)
    and the keyframe (t = 1), so frame i (0-based) takes t = (i + 1) / (m + 1); sizes: their
    (width, height) in px; predicted, corrected: the keyframe's placement (3, 3) before and after
    its registration to the mosaic.

    Returns (placements (3, 3) each, h22 = 1; shifts (m,) the largest corner move of each, px in
    the segment plane).
    """
    m = len(seg_H_frames)
    if m == 0:
        return [], np.zeros(0)
    D = corrected @ np.linalg.inv(predicted)
    out: list[np.ndarray | None] = [None] * m
    shifts = np.zeros(m)
    for size in sorted(set(sizes)):
        idx = [i for i in range(m) if sizes[i] == size]
        src = _corners(*size)
        before = np.stack([apply_homography(seg_H_frames[i], src) for i in idx])          # (B, 4, 2)
        moved = apply_homography(D, before)
        t = (np.asarray(idx, float) + 1.0) / (m + 1.0)
        after = before + t[:, None, None] * (moved - before)
        for i, h in zip(idx, homographies_from_corners(src, after), strict=True):
            out[i] = h
        shifts[idx] = np.linalg.norm(after - before, axis=2).max(axis=1)
    return [h for h in out if h is not None], shifts
