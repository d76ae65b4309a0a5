"""The classic multi-frame SR peer: robust (median) shift-and-add, then Wiener deconvolution with the same PSF.

OpenCV's BTV-L1 (``cv2.superres``) is not in the contrib build of OpenCV 5 that the registry ships
(docs/results.md), so the peer a user could pick instead is the textbook two-step method (Farsiu et
al. 2004, "Fast and robust multiframe super resolution", sections on the median shift-and-add):

1. shift-and-add: every frame is registered onto the HR tile grid (through the same homographies SR
   uses, pixel centres at integers; its LR pixels interpolated bicubically at the HR points) and each
   HR pixel takes the **median** over the frames (robust to outliers: moving objects,
   misregistration). Placing each LR pixel on its nearest HR pixel instead, as the method is often
   drawn, leaves holes wherever the frames' sub-pixel offsets cluster (a hover: most frames at the
   same phase), and the deconvolution then turns the holes' fill into a checkerboard;
2. deconvolution: the fused image is still blurred by the camera's PSF (a Gaussian of the same sigma
   SR models, in HR pixels ``psf_sigma * s``); Wiener deconvolution X = conj(H) Y / (|H|^2 + K)
   with a constant noise-to-signal ratio ``K`` (``WIENER_K``), on the image reflected at its border.

Input and output as app/sr_protocol.py's TileMethod: frames (h, w, 3) uint8 RGB, tile_H_frames LR
frame pixels -> LR tile pixels, tile_shape (H, W), factor s, psf sigma (LR px) -> (H s, W s, 3)
float in [0, 1].
"""
from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from srmosaic_ros.core.sr.fallback import frame_upsampled

__all__ = ['WIENER_K', 'median_shift_and_add', 'peer_sr', 'wiener_deconvolve']

#: Wiener noise-to-signal power ratio (a constant, as the textbook filter takes it).
WIENER_K = 0.01
_PAD = 16


def median_shift_and_add(frames: Sequence[np.ndarray], tile_H_frames: Sequence[np.ndarray], tile_shape: tuple[int, int],
                         factor: int) -> np.ndarray:
    """(H s, W s, C) float32 in [0, 1]: the per-HR-pixel median over the frames, each registered onto the HR grid."""
    stack = np.stack([frame_upsampled(f, h, tile_shape, factor) for f, h in zip(frames, tile_H_frames, strict=True)])
    return np.median(stack, axis=0).astype(np.float32)


def wiener_deconvolve(image: np.ndarray, sigma_hr: float, k: float = WIENER_K) -> np.ndarray:
    """(H, W, C) float image deconvolved by a Gaussian PSF of std ``sigma_hr`` (its pixels) with the Wiener filter."""
    if sigma_hr <= 0:
        return image
    padded = cv2.copyMakeBorder(image, _PAD, _PAD, _PAD, _PAD, cv2.BORDER_REFLECT_101).reshape(
        image.shape[0] + 2 * _PAD, image.shape[1] + 2 * _PAD, -1)
    h, w = padded.shape[:2]
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    otf = np.exp(-2.0 * (np.pi * sigma_hr) ** 2 * (fx**2 + fy**2))  # the Gaussian's transform, real and even
    gain = otf / (otf**2 + k)
    out = np.empty_like(padded)
    for c in range(padded.shape[2]):
        out[:, :, c] = np.real(np.fft.ifft2(np.fft.fft2(padded[:, :, c]) * gain))
    return out[_PAD:-_PAD, _PAD:-_PAD].reshape(image.shape)


def peer_sr(frames: Sequence[np.ndarray], tile_H_frames: Sequence[np.ndarray], tile_shape: tuple[int, int], factor: int,
            psf_sigma: float) -> np.ndarray:
    """The peer: median shift-and-add, then Wiener deconvolution with the PSF SR models (module docstring)."""
    fused = median_shift_and_add(frames, tile_H_frames, tile_shape, factor)
    return np.clip(wiener_deconvolve(fused, psf_sigma * factor), 0.0, 1.0)
