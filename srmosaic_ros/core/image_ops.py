"""Conversions between edge images (numpy uint8/uint16) and what the core works on.

Convention: numpy (H, W) mono or (H, W, 3) RGB at the edges; float32 in [0, 1] inside.
"""
from __future__ import annotations

import numpy as np

__all__ = ['to_float01', 'to_gray_u8', 'to_gray_float01']


def _stretch_u16(image: np.ndarray) -> np.ndarray:
    """Map a uint16 image (e.g. 14-bit radiometric IR) to [0, 1] by its 0.5 and 99.5 percentiles.

    Raw IR counts use a small part of the 16-bit range; a fixed /65535 would leave the image
    almost constant. The stretch is per frame, which is what registration needs (contrast, not
    radiometry).
    """
    lo, hi = np.percentile(image, (0.5, 99.5))
    if hi <= lo:
        hi = lo + 1.0
    return np.clip((image.astype(np.float32) - lo) / (hi - lo), 0.0, 1.0)


def to_float01(image: np.ndarray) -> np.ndarray:
    """uint8 / uint16 / float image -> float32 in [0, 1], same shape ((H, W) or (H, W, C))."""
    if image.dtype == np.uint8:
        return image.astype(np.float32) * (1.0 / 255.0)
    if image.dtype == np.uint16:
        return _stretch_u16(image)
    if np.issubdtype(image.dtype, np.floating):
        return np.clip(image.astype(np.float32), 0.0, 1.0)
    msg = f'image dtype {image.dtype} is not supported; expected uint8, uint16 or float.'
    raise TypeError(msg)


def to_gray_float01(image: np.ndarray) -> np.ndarray:
    """Any edge image -> (H, W) float32 luminance in [0, 1] (Rec. 601 weights for RGB)."""
    f = to_float01(image)
    if f.ndim == 3:
        if f.shape[2] == 1:
            return f[:, :, 0]
        f = f[:, :, :3] @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return f


def to_gray_u8(image: np.ndarray) -> np.ndarray:
    """Any edge image -> (H, W) uint8 luminance."""
    if image.dtype == np.uint8 and image.ndim == 2:
        return image
    return np.clip(to_gray_float01(image) * 255.0 + 0.5, 0, 255).astype(np.uint8)
