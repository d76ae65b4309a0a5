"""Per-pixel arithmetic of painting a frame: its conversion to float32, exposure gains, the fill of
invalid pixels and the weighted sums into tiles.

Every array is float32 unless said otherwise; (h, w, C) images, (h, w) weights.
"""
from __future__ import annotations

import cv2
import numpy as np

from .scratch import scratch

__all__ = ['add_into', 'fill_invalid', 'scaled', 'times_weight', 'to_float']


def fill_invalid(img: np.ndarray, valid: np.ndarray, rings: int = 1) -> np.ndarray:
    """Replace invalid pixels by the mean of their valid 8-neighbours, ``rings`` times over (each
    ring filled from the last; 0 beyond).

    Where the warped weight is non-zero, bilinear interpolation reads invalid pixels one pixel from
    a valid one, bicubic two, Lanczos-4 four (:data:`.resample.FILL_RINGS`), so this is all the fill
    that the colour needs (garbage or NaN never leaks in).
    """
    clean = np.where(valid[..., None], img, np.float32(0.0)).astype(np.float32, copy=False)
    known = valid
    for _ in range(rings):
        m = known.astype(np.float32)
        num = cv2.boxFilter(clean, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT).reshape(img.shape)
        den = cv2.boxFilter(m, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        fill = num / np.maximum(den, np.float32(1.0))[..., None]
        clean = np.where(known[..., None], clean, fill).astype(np.float32, copy=False)
        known = den > 0
    return clean


def to_float(image: np.ndarray, gains: np.ndarray | None, out: np.ndarray | None = None) -> np.ndarray:
    """float32 (h, w, C) of uint8 (h, w, C): values / 255, times ``gains`` (C,) per channel and
    clipped to 1 where a gain exceeds 1 (None: no gains); into ``out`` when given."""
    h, w, c = image.shape
    if out is None:
        out = np.empty(image.shape, np.float32)
    if gains is None:  # one factor: numpy's scalar product, faster here than OpenCV's (same values for all 256 inputs)
        return np.multiply(image, np.float32(1.0 / 255.0), out=out, dtype=np.float32)
    factor = gains / np.float32(255.0)
    saturates = float(gains.max()) > 1.0  # only a gain above 1 can saturate
    if c <= 4:  # OpenCV's per-channel scalar product, faster than numpy's broadcast (same values)
        shape = (h, w, c) if c > 1 else (h, w)  # OpenCV takes (h, w, 1) as (h, w)
        scalar = tuple(float(f) for f in factor) + (0.0,) * (4 - c)
        res = cv2.multiply(image.reshape(shape), scalar, dst=out.reshape(shape), dtype=cv2.CV_32F)
        if saturates:
            res = cv2.min(res, (1.0, 1.0, 1.0, 1.0), dst=res)  # a 4-tuple: every channel (a bare 1.0 is channel 0's)
        if not np.shares_memory(res, out):  # a layout OpenCV could not write in place
            out[...] = res.reshape(out.shape)
        return out
    np.multiply(image, factor, out=out, dtype=np.float32)  # one rounding: as astype, then the product
    if saturates:
        np.minimum(out, np.float32(1.0), out=out)
    return out


def scaled(image: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """float32 (H, W, C) image times ``gains`` (C,), clipped to 1 where a gain exceeds 1 (a new array)."""
    out = np.multiply(image, gains, dtype=np.float32)
    if float(gains.max()) > 1.0:
        np.minimum(out, np.float32(1.0), out=out)
    return out


def times_weight(colour: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """float32 (h, w, C) ``colour * weight[..., None]`` of colour (h, w, C) and weight (h, w), in this
    thread's scratch array 'weighted' (:mod:`.scratch`).

    The same products (one float32 rounding each) as numpy's broadcast, which runs element by element
    over the channel axis; OpenCV multiplies whole rows of a weight expanded to C channels instead.
    """
    h, w, c = colour.shape
    if c == 1:
        return np.multiply(colour[:, :, 0], weight, out=scratch('weighted', (h, w)))[:, :, None]
    expanded = scratch('expanded', colour.shape)
    if c == 3:
        expanded = cv2.cvtColor(weight, cv2.COLOR_GRAY2RGB, dst=expanded)
    else:
        expanded = cv2.merge([weight] * c, dst=expanded)
    return cv2.multiply(colour, expanded, dst=scratch('weighted', colour.shape)).reshape(colour.shape)


def add_into(dst: np.ndarray, src: np.ndarray) -> None:
    """dst += src in place (float32 views of one shape); OpenCV's add is the faster on these tile views,
    with the same sums as numpy's."""
    if cv2.add(dst, src, dst=dst) is not dst:  # a layout OpenCV could not write in place: numpy's way
        np.add(dst, src, out=dst)
