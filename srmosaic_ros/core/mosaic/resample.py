"""How the canvas samples a frame at the preimages of the mosaic pixels (``mosaic.interpolation``).

A bilinear resample at a sub-pixel offset t is a low-pass filter: its response at f cycles per
pixel is ``|1 - t + t exp(-2 pi i f)|``, ``cos(pi f)`` at t = 1/2 (0.71 at f = 1/4, nothing at
Nyquist). A frame painted with it has lost detail before any blending, and a mosaic that shows
each ground pixel from one frame is softer than that frame wherever its pixels fall between the
mosaic's. Keys' cubic convolution (OpenCV's INTER_CUBIC, a = -0.75, 4 x 4 taps) and Lanczos-4
(8 x 8) keep most of that band, at the price of overshoot (ringing) next to strong edges.

``'cubic'`` and ``'lanczos'`` are therefore clamped: each sample lies between the least and the
largest of the 2 x 2 source pixels around its preimage, the cell bilinear interpolation reads
(the anti-ringing rule of mpv's scalers). Whatever a bilinear resample could produce there is
still reachable, nothing beyond it is: no halo, no value outside the frame's own local range
(so none outside [0, 1] either). The bounds are the frame's 2 x 2 cell minima and maxima (the
frame padded by one replicated row and column on the top and left, as the warp's border extends
it, then eroded and dilated with the kernel anchored at the cell's top-left pixel), sampled at
cell ``(floor(u), floor(v))``: the nearest sample of ``(u - 1/2, v - 1/2)``. At an integer
preimage both cells around it contain the pixel, so an exact sample is never clamped.

Convention: frame and mosaic pixels x right, y down, pixel centres at integers; ``dst_H_src`` maps
a source pixel (u, v) to destination pixel ``dst_H_src @ (u, v, 1)`` (``cv2.warpPerspective``'s);
images (h, w, C) uint8 or float32, borders replicated.
"""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ['DEFAULT_INTERPOLATION', 'FILL_RINGS', 'INTERPOLATIONS', 'FrameSampler', 'warp']

#: mosaic.interpolation's choices (config.INTERPOLATION_MODES) and the OpenCV flag each warps with.
INTERPOLATIONS = {'cubic': cv2.INTER_CUBIC, 'lanczos': cv2.INTER_LANCZOS4, 'linear': cv2.INTER_LINEAR}
DEFAULT_INTERPOLATION = 'cubic'
#: Rings of invalid pixels around the valid ones that each interpolation reads from a painted
#: pixel's preimage (the kernel's half-width beyond the 2 x 2 cell, plus the cell): the canvas fills
#: that many before warping, so no unfilled colour leaks in.
FILL_RINGS = {'linear': 1, 'cubic': 2, 'lanczos': 4}

_CELL = np.ones((2, 2), np.uint8)
#: bound pixel (the padded frame's) of source pixel (u, v), minus a half: composed under dst_H_src,
#: a nearest sample reads bound pixel round(u + 1/2) = floor(u) + 1, cell (floor(u), floor(v)).
_SRC_H_BOUND = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])


class FrameSampler:
    """A frame (H, W, C) uint8 or float32, warped as ``mosaic.interpolation`` says.

    The bounds of the clamp (the frame's 2 x 2 cell minima and maxima) are made once, so one frame
    warped over several boxes (a canvas painting tile by tile) pays for them once.
    """

    def __init__(self, src: np.ndarray, interpolation: str = DEFAULT_INTERPOLATION) -> None:
        if interpolation not in INTERPOLATIONS:
            msg = f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {interpolation!r}."
            raise ValueError(msg)
        self.src = src
        self.interpolation = interpolation
        self._flag = INTERPOLATIONS[interpolation]
        self._lo: np.ndarray | None = None
        self._hi: np.ndarray | None = None
        if interpolation != 'linear':
            padded = cv2.copyMakeBorder(src, 1, 0, 1, 0, cv2.BORDER_REPLICATE)
            shape = (src.shape[0] + 1, src.shape[1] + 1, *src.shape[2:])
            self._lo = cv2.erode(padded, _CELL, anchor=(0, 0), borderType=cv2.BORDER_REPLICATE).reshape(shape)
            self._hi = cv2.dilate(padded, _CELL, anchor=(0, 0), borderType=cv2.BORDER_REPLICATE).reshape(shape)

    def warp(self, dst_H_src: np.ndarray, size: tuple[int, int], dst: np.ndarray | None = None) -> np.ndarray:
        """The frame warped through ``dst_H_src`` (3, 3) onto ``size`` = (w, h): (h, w, C) of the
        frame's dtype, into ``dst`` when given (a (h, w, C) or (h, w) array of that dtype)."""
        w, h = size
        c = self.src.shape[2] if self.src.ndim == 3 else 1
        if c > 4 and self._lo is not None:  # OpenCV's cubic and Lanczos warp 4 channels at most
            out = np.empty((h, w, c), self.src.dtype) if dst is None else dst.reshape(h, w, c)
            for k in range(0, c, 4):
                out[:, :, k:k + 4] = cv2.warpPerspective(np.ascontiguousarray(self.src[:, :, k:k + 4]), dst_H_src, (w, h),
                                                         flags=self._flag, borderMode=cv2.BORDER_REPLICATE
                                                         ).reshape(h, w, -1)
        else:
            out = cv2.warpPerspective(self.src, dst_H_src, (w, h), dst=dst, flags=self._flag,
                                      borderMode=cv2.BORDER_REPLICATE).reshape(h, w, c)
        if self._lo is None or self._hi is None:
            return out
        cell_H = dst_H_src @ _SRC_H_BOUND
        for bound, clamp in ((self._lo, cv2.max), (self._hi, cv2.min)):
            sampled = cv2.warpPerspective(bound, cell_H, (w, h), flags=cv2.INTER_NEAREST,
                                          borderMode=cv2.BORDER_REPLICATE).reshape(h, w, c)
            res = clamp(out, sampled, dst=out)
            if not np.shares_memory(res, out):  # a layout OpenCV could not write in place
                out[...] = res.reshape(out.shape)
        return out


def warp(src: np.ndarray, dst_H_src: np.ndarray, size: tuple[int, int], interpolation: str = DEFAULT_INTERPOLATION,
         ) -> np.ndarray:
    """``src`` (h, w, C) or (h, w) warped through ``dst_H_src`` onto ``size`` = (w, h) as the canvas
    paints it (:class:`FrameSampler`); (h, w, C), or (h, w) for a 2-D ``src``."""
    out = FrameSampler(src, interpolation).warp(dst_H_src, size)
    return out[:, :, 0] if src.ndim == 2 else out
