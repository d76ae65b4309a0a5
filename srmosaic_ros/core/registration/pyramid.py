"""Registration of large frames on a pyramid level: describe and register the frame reduced by
2**level, return homographies, covariances and residuals of the full-size frame.

A 1920 x 1080 frame holds four times the pixels that registration needs for a sub-pixel estimate:
features and photometric refinement on the 960 x 540 level cost a quarter, and the estimate,
mapped back, keeps most of its accuracy in full-size pixels (bench/throughput.py measures the
cost on simulated truth). The level comes from the frame width (``RegistrationConfig.max_width``).

Pixel centres are at integers on every level: the centre of level pixel x covers full-size pixels
s x .. s x + s - 1, so full = s * level + (s - 1) / 2 with s = 2**level (the matrix ``T``), and

    H_full = T @ H_level @ inv(T),    normalised to h22 = 1,

with the (8, 8) covariance of (h00 .. h21) carried through the Jacobian of that map.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from ..homography import h8_jacobian
from .registrar import Registration

__all__ = ['LevelFeatures', 'PyramidRegistrar', 'level_for_width']


def level_for_width(width: int, max_width: int) -> int:
    """The pyramid level (0: full size) that brings a frame ``width`` px wide to ``max_width`` or
    less, each level halving it; 0 when max_width is 0 (always full size)."""
    level = 0
    while max_width > 0 and width >> level > max_width and width >> (level + 1) >= 16:
        level += 1
    return level


def reduce_image(image: np.ndarray, level: int) -> np.ndarray:
    """The frame (H, W[, C]) averaged over 2**level x 2**level blocks (pixel area: no aliasing from
    point sampling), cropped to a multiple of the block; same dtype."""
    if level == 0:
        return image
    s = 1 << level
    h, w = (image.shape[0] // s) * s, (image.shape[1] // s) * s
    return cv2.resize(image[:h, :w], (w // s, h // s), interpolation=cv2.INTER_AREA)


def full_from_level(level: int) -> np.ndarray:
    """(3, 3) T: level pixels -> full-size pixels (module docstring)."""
    s = float(1 << level)
    o = (s - 1.0) / 2.0
    return np.array([[s, 0.0, o], [0.0, s, o], [0.0, 0.0, 1.0]])


def _h8(h: np.ndarray) -> np.ndarray:
    h = h / h[2, 2]
    return h.ravel()[:8]


def _H(h8: np.ndarray) -> np.ndarray:
    return np.append(h8, 1.0).reshape(3, 3)


def to_full(reg: Registration, level: int) -> Registration:
    """The registration of level-``level`` frames as one of the full-size frames."""
    if level == 0 or reg.prev_H_cur is None:
        return reg
    t = full_from_level(level)
    t_inv = np.linalg.inv(t)
    full = t @ _H(_h8(np.asarray(reg.prev_H_cur, dtype=np.float64))) @ t_inv
    h_full = _h8(full)
    cov = reg.covariance
    if cov is not None:
        jac = h8_jacobian(t, t_inv, full)  # d h_full / d h_level, exact
        cov = jac @ np.asarray(cov, dtype=np.float64) @ jac.T
    s = float(1 << level)
    return replace(reg, prev_H_cur=_H(h_full), covariance=cov, rms_px=reg.rms_px * s,
                   extras={**reg.extras, 'level': float(level)})


@dataclass
class LevelFeatures:
    """Features of a frame described on pyramid ``level`` by the inner registrar; ``size`` (w, h) of
    the full-size frame."""

    inner: Any
    level: int
    size: tuple[int, int]

    def __len__(self) -> int:
        return len(self.inner)


class PyramidRegistrar:
    """A registrar (torch, OpenCV or with fallback) run on the pyramid level that brings frames to
    ``max_width`` pixels or less; homographies, covariances and RMS in full-size pixels."""

    def __init__(self, inner: Any, max_width: int) -> None:
        self.inner = inner
        self.max_width = max_width
        self.config = inner.config
        self.device = getattr(inner, 'device', None)
        self.has_second_opinion = getattr(inner, 'has_second_opinion', False)
        self.tracks = getattr(inner, 'tracks', False)

    def describe(self, image: np.ndarray, **kwargs: Any) -> LevelFeatures:
        """Features of a frame ((H, W) or (H, W, 3), uint8/uint16/float) on its level (kwargs: the
        inner registrar's, e.g. keypoints)."""
        h, w = image.shape[:2]
        level = level_for_width(w, self.max_width)
        return LevelFeatures(self.inner.describe(reduce_image(image, level), **kwargs), level, (w, h))

    def track(self, prev: LevelFeatures, cur: LevelFeatures, predicted: np.ndarray, **kwargs: Any) -> Registration:
        """The inner registrar's track (photometric, from ``predicted``: full-size prev_H_cur) on the
        frames' level; the result in full-size pixels."""
        if prev.level != cur.level:
            return Registration(False, None, reason=f'frames described on pyramid levels {prev.level} and {cur.level} '
                                'cannot be tracked')
        t = full_from_level(prev.level)
        level_H = np.linalg.inv(t) @ np.asarray(predicted, dtype=np.float64) @ t
        return to_full(self.inner.track(prev.inner, cur.inner, level_H, **kwargs), prev.level)

    def register(self, prev: LevelFeatures, cur: LevelFeatures, **kwargs: Any) -> Registration:
        """prev_H_cur of the full-size frames (kwargs: the inner registrar's, e.g. second_opinion)."""
        if prev.level != cur.level:
            return Registration(False, None, reason=f'frames described on pyramid levels {prev.level} and {cur.level} '
                                f'(sizes {prev.size} and {cur.size}) cannot be registered')
        return to_full(self.inner.register(prev.inner, cur.inner, **kwargs), prev.level)
