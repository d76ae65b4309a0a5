"""The classic multi-frame SR peer: robust (median) shift-and-add, then Wiener deconvolution with the same PSF.

OpenCV's BTV-L1 (``cv2.superres``) is not in the contrib build of OpenCV 5 that the registry ships
(docs/results.md), so the peer a user could pick instead is the textbook two-step method (Farsiu et
al. 2004, "Fast and robust multiframe super resolution", sections on the median shift-and-add):

1. shift-and-add: every LR pixel of every registered frame is placed at its point on the HR tile grid
   (through the same homographies SR uses, pixel centres at integers) and rounded to the nearest HR
   pixel; each HR pixel takes the **median** of the values that land on it (robust to outliers:
   moving objects, misregistration); HR pixels no frame lands on are filled by normalised
   convolution (a Gaussian-weighted mean of the filled pixels around them);
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

from srmosaic_ros.core.sr.operators import hr_H_lr

__all__ = ['WIENER_K', 'median_shift_and_add', 'peer_sr', 'wiener_deconvolve']

#: Wiener noise-to-signal power ratio (a constant, as the textbook filter takes it).
WIENER_K = 0.01
_FILL_SIGMA_HR = 1.0
_PAD = 16


def median_shift_and_add(frames: Sequence[np.ndarray], tile_H_frames: Sequence[np.ndarray], tile_shape: tuple[int, int],
                         factor: int) -> np.ndarray:
    """(H s, W s, C) float32 in [0, 1]: the per-HR-pixel median of the frames' LR pixels rounded onto the HR grid."""
    s = int(factor)
    hs, ws = int(tile_shape[0]) * s, int(tile_shape[1]) * s
    channels = 1 if np.asarray(frames[0]).ndim == 2 else 3
    idx_all, val_all = [], []
    for frame, tile_H in zip(frames, tile_H_frames, strict=True):
        img = np.asarray(frame, dtype=np.float32).reshape(frame.shape[0], frame.shape[1], -1)[:, :, :channels] / 255.0
        hr_H_frame = hr_H_lr(s) @ np.asarray(tile_H, dtype=np.float64)
        ys, xs = np.mgrid[0:img.shape[0], 0:img.shape[1]]
        p = hr_H_frame @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
        u = np.rint(p[0] / p[2]).astype(np.int64)
        v = np.rint(p[1] / p[2]).astype(np.int64)
        inside = (u >= 0) & (u < ws) & (v >= 0) & (v < hs)
        idx_all.append(v[inside] * ws + u[inside])
        val_all.append(img.reshape(-1, channels)[inside])
    idx = np.concatenate(idx_all)
    val = np.concatenate(val_all)
    out = np.zeros((hs * ws, channels), np.float32)
    filled = np.zeros(hs * ws, bool)
    if idx.size:
        order = np.argsort(idx, kind='stable')
        idx, val = idx[order], val[order]
        keys, starts = np.unique(idx, return_index=True)
        for key, part in zip(keys, np.split(val, starts[1:]), strict=True):
            out[key] = np.median(part, axis=0)
        filled[keys] = True
    out = out.reshape(hs, ws, channels)
    mask = filled.reshape(hs, ws).astype(np.float32)
    if not mask.all():  # normalised convolution over the holes
        num = cv2.GaussianBlur(out * mask[:, :, None], (0, 0), _FILL_SIGMA_HR).reshape(hs, ws, channels)
        den = cv2.GaussianBlur(mask, (0, 0), _FILL_SIGMA_HR)[:, :, None]
        grown = np.where(den > 1e-3, num / np.maximum(den, 1e-3), np.nan)
        out = np.where(mask[:, :, None] > 0, out, grown)
        if np.isnan(out).any():  # holes wider than the kernel: the nearest filled value
            holes = np.isnan(out[:, :, 0])
            _, (iy, ix) = _nearest_filled(~holes)
            out[holes] = out[iy[holes], ix[holes]]
    return out.astype(np.float32)


def _nearest_filled(filled: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    from scipy.ndimage import distance_transform_edt

    dist, (iy, ix) = distance_transform_edt(~filled, return_indices=True)
    return dist, (iy, ix)


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
