"""Anti-aliased painting of frames that shrink on the mosaic (a zoom out, a forward flight seen from
its first frame's plane): the frame is reduced by pyramid levels before it is warped.

``cv2.warpPerspective`` with INTER_LINEAR samples the frame at the mosaic pixels' preimages, so a
frame whose pixels land 0.1 mosaic px apart is point-sampled one pixel in ten: aliased, and
disagreeing with every other view of that ground. Mip-mapping fixes it: with s the linear stretch
of frame pixels on the mosaic (sqrt(det J) of the homography; an oblique frame's varies over it: the
geometric mean of its least and largest over the part of the frame that is painted), the frame goes ``L = floor(log2(1 / s))`` levels
down ``cv2.pyrDown`` (the Burt kernel, eq. 4.8), which keeps s >= 1/2 after reduction, and the
homography follows: level-L pixel (u', v') is frame pixel (2**L u', 2**L v') (pyrDown keeps the
even rows and columns).

A frame two or more times finer than the mosaic everywhere (4K video painted at mosaic.max_width)
is first averaged over k x k blocks (:func:`area_reduce`, on its integer pixels, before any float
copy), k the largest that keeps its finest part at one mosaic pixel per block or more: nothing the
mosaic can show is lost, and conversion, weights and warp run on the smaller image.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ['MAX_LEVELS', 'area_factor', 'area_reduce', 'finest_stretch', 'minify_level', 'reduce_frame']

#: Most pyramid levels a frame is reduced by (1/64 linear).
MAX_LEVELS = 6


def _depth_extremes(m: np.ndarray, w: int, h: int, d_min: float | None) -> tuple[float, float, float]:
    """(|det m|, least depth, largest depth) of a (w, h) frame's corners through mosaic_H_frame ``m``
    (3, 3); the least depth raised to ``d_min`` (the part painted) when given. The stretch at depth d
    is sqrt(|det m| / d**3)."""
    corners = np.array([[-0.5, -0.5, 1.0], [w - 0.5, -0.5, 1.0], [w - 0.5, h - 0.5, 1.0], [-0.5, h - 0.5, 1.0]])
    depth = corners @ m[2]
    lo = float(depth.min()) if d_min is None else max(float(depth.min()), d_min)
    return abs(float(np.linalg.det(m))), lo, float(depth.max())


def minify_level(m: np.ndarray, w: int, h: int, d_min: float | None = None) -> int:
    """Pyramid levels to reduce a (w, h) frame by before warping it through mosaic_H_frame ``m`` (3, 3)
    (positive depth over the part painted: depth >= ``d_min``, the cut of best_view.clip_depth, or the
    whole frame for None); 0 when that part does not shrink by 2 or more."""
    det, lo, hi = _depth_extremes(m, w, h, d_min)
    if not (det > 0 and lo > 0):
        return 0
    s = math.sqrt(det / (lo * hi) ** 1.5)  # geometric mean of the extreme stretches
    if not s < 0.5:
        return 0
    level = min(int(math.floor(math.log2(1.0 / s))), MAX_LEVELS)
    while level > 0 and min(w, h) >> level < 8:  # a frame is kept at least 8 px on its smaller side
        level -= 1
    return level


def reduce_frame(img: np.ndarray, valid: np.ndarray | None, m: np.ndarray, level: int,
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(image (h', w', C), valid (h', w') bool or None, mosaic_H_reduced (3, 3)) of a frame reduced by
    ``level`` pyramid levels. img: float32 (h, w, C) with its invalid pixels already filled (invalid
    colour would bleed through the kernel); valid: bool (h, w) or None (all valid); a reduced pixel
    stays valid only where its whole kernel was."""
    c = img.shape[2]
    mask = None if valid is None else valid.astype(np.float32)
    for _ in range(level):
        img = cv2.pyrDown(img).reshape((img.shape[0] + 1) // 2, (img.shape[1] + 1) // 2, c)
        if mask is not None:
            mask = cv2.pyrDown(mask)
    scale = float(2**level)
    m_red = m @ np.diag([scale, scale, 1.0])
    return img, (None if mask is None else mask > 0.999), m_red


def finest_stretch(m: np.ndarray, w: int, h: int, d_min: float | None = None) -> float:
    """The largest linear stretch sqrt(det J) of a (w, h) frame's pixels on the mosaic through
    mosaic_H_frame ``m`` (3, 3), over the part painted (depth >= ``d_min``; the nearest ground, where
    depth is least); 0 when the frame does not face the mosaic."""
    det, lo, _ = _depth_extremes(m, w, h, d_min)
    if not (det > 0 and lo > 0):
        return 0.0
    return math.sqrt(det / lo ** 3)


def area_factor(stretch: float) -> int:
    """The integer k >= 2 a frame whose finest part lands at ``stretch`` mosaic px per frame px is
    averaged down by (k x k blocks: each block still at least one mosaic pixel), or 1: none."""
    return int(1.0 / stretch) if 0.0 < stretch <= 0.5 else 1


def area_reduce(image: np.ndarray, m: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(the image averaged over k x k blocks, cropped to a multiple of k; mosaic_H_reduced (3, 3));
    ``image`` (h, w) or (h, w, C) uint8 or float32. Pixel centres stay at integers: reduced pixel u'
    covers frame pixels k u' .. k u' + k - 1, centre k u' + (k - 1) / 2."""
    h, w = (image.shape[0] // k) * k, (image.shape[1] // k) * k
    out = cv2.resize(image[:h, :w], (w // k, h // k), interpolation=cv2.INTER_AREA)
    if image.ndim == 3 and out.ndim == 2:  # OpenCV drops a single channel
        out = out[:, :, None]
    o = (k - 1) / 2.0
    frame_from_reduced = np.array([[float(k), 0.0, o], [0.0, float(k), o], [0.0, 0.0, 1.0]])
    return out, m @ frame_from_reduced
