"""Image quality figures of SR tiles against a ground truth: PSNR, SSIM, overshoot; a comparison strip.

All images are numpy (H, W) or (H, W, C) float in [0, 1] (uint8 is accepted and scaled by 1/255),
estimate and truth on the same pixel grid. Used by ``srmosaic evaluate`` and bench/sr.py.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

__all__ = ['as_float01', 'mse', 'psnr', 'ssim', 'overshoot', 'overshoot_map', 'edge_mask', 'side_by_side']


def as_float01(img: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, C) uint8 / uint16 / float -> float64 in [0, 1] (floats are taken as they are)."""
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a.astype(np.float64) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float64) / 65535.0
    return a.astype(np.float64)


def mse(a: np.ndarray, b: np.ndarray) -> float:
    """Mean squared difference over all pixels and channels, intensities in [0, 1]."""
    return float(np.mean((as_float01(a) - as_float01(b)) ** 2))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) for a peak of 1 (5.12): 10 log10(1 / MSE) over all pixels and channels."""
    return 10.0 * math.log10(1.0 / max(mse(a, b), 1e-20))


def ssim(a: np.ndarray, b: np.ndarray, *, border: int = 5) -> float:
    """SSIM (Wang et al. 2004): Gaussian window (sigma 1.5, 11 px), K1 0.01, K2 0.03, data range 1.

    Per channel, then averaged; ``border`` pixels at each side are left out of the mean.
    """
    a, b = as_float01(a), as_float01(b)
    if a.ndim == 2:
        a, b = a[:, :, None], b[:, :, None]
    c1, c2 = 0.01**2, 0.03**2

    def f(z: np.ndarray) -> np.ndarray:
        return gaussian_filter(z, 1.5, truncate=3.5, mode='reflect')

    vals = []
    for ch in range(a.shape[2]):
        x, y = a[:, :, ch], b[:, :, ch]
        mx, my = f(x), f(y)
        sxx, syy, sxy = f(x * x) - mx * mx, f(y * y) - my * my, f(x * y) - mx * my
        m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        inner = m[border:m.shape[0] - border, border:m.shape[1] - border] if border else m
        vals.append(float(inner.mean()))
    return float(np.mean(vals))


def overshoot_map(img: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(H, W) grey levels (of 255) by which mono ``img`` leaves the [min, max] of the truth's 3 x 3
    neighbourhood at each pixel (0 where it stays inside the local range)."""
    k = np.ones((3, 3), np.uint8)
    t = as_float01(truth).astype(np.float32)
    x = as_float01(img).astype(np.float32)
    hi, lo = cv2.dilate(t, k), cv2.erode(t, k)
    return (np.maximum(x - hi, 0) + np.maximum(lo - x, 0)) * 255.0


def edge_mask(truth: np.ndarray, *, fraction: float = 0.1, width: int = 2) -> np.ndarray:
    """(H, W) bool: pixels within ``width`` px of the ``fraction`` strongest gradients of mono ``truth``."""
    t = as_float01(truth).astype(np.float32)
    g = np.hypot(cv2.Sobel(t, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(t, cv2.CV_32F, 0, 1, ksize=3))
    strong = ((g >= np.quantile(g, 1.0 - fraction)) & (g > 1e-6)).astype(np.uint8)   # flat images: no edges
    return cv2.dilate(strong, np.ones((2 * width + 1, 2 * width + 1), np.uint8)) > 0


def overshoot(img: np.ndarray, truth: np.ndarray, *, border: int = 4, mask: np.ndarray | None = None) -> float:
    """Ringing figure of merit: mean of :func:`overshoot_map` (grey levels of 255) over the image less
    ``border`` px, or over ``mask`` (e.g. :func:`edge_mask`: overshoot near edges).

    0 for an estimate that never over- or undershoots the local range of the truth; ringing around
    edges (the LM artefact of the reference's IR results) raises it.
    """
    e = overshoot_map(img, truth)
    keep = np.zeros(e.shape, bool)
    keep[border:e.shape[0] - border, border:e.shape[1] - border] = True
    if mask is not None:
        keep &= mask
    return float(e[keep].mean()) if keep.any() else 0.0


def side_by_side(images: Sequence[np.ndarray], labels: Sequence[str], *, zoom: int = 1,
                 gap: int = 6, header: int = 22) -> np.ndarray:
    """Panels left to right with a text header over each: (H z + header, n W z + gaps, 3) uint8 RGB.

    images: equally sized (H, W) or (H, W, 3) in [0, 1] (or uint8); zoom: nearest-neighbour
    magnification so single pixels stay visible.
    """
    panels = []
    for img in images:
        a = np.clip(as_float01(img), 0.0, 1.0)
        if a.ndim == 2:
            a = np.repeat(a[:, :, None], 3, axis=2)
        elif a.shape[2] == 1:
            a = np.repeat(a, 3, axis=2)
        u8 = (a * 255.0 + 0.5).astype(np.uint8)
        if zoom > 1:
            u8 = cv2.resize(u8, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
        panels.append(u8)
    h, w = panels[0].shape[:2]
    if any(p.shape[:2] != (h, w) for p in panels):
        msg = 'side_by_side needs panels of one size.'
        raise ValueError(msg)
    n = len(panels)
    canvas = np.full((h + header, n * w + (n - 1) * gap, 3), 255, np.uint8)
    for i, (p, label) in enumerate(zip(panels, labels, strict=True)):
        x = i * (w + gap)
        canvas[header:, x:x + w] = p
        cv2.putText(canvas, label, (x + 4, header - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas
