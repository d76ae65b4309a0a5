"""How each frame of a real run agrees with its mosaic: NCC and sharpness, in the mosaic's pixels and in
the frame's (the figures are defined in evaluate_real.py's module docstring).

Convention: frame and mosaic pixels x right, y down, pixel centres at integers (the canvas's, and
cv2.warpPerspective's); mosaic_H_frame maps pixels of the frame as the pipeline saw it, i.e. after
lens undistortion (core/undistort.py), which is applied here the same way.

Cost: a frame is compared over its bounding box in the mosaic, at most ``MAX_COMPARE_PX`` pixels:
larger footprints are compared on every k-th mosaic pixel across and down (k the smallest integer
that keeps the count under the bound), as point samples of both the mosaic and the frame warped as
the canvas warps it, so that the comparison stays exact (a frame alone under itself still scores
1.0), only sparser; gradients are then taken between samples k mosaic pixels apart. mosaic.tif is read window by window; without it,
mosaic.png is read whole (a mosaic that is not georeferenced).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..core.mosaic import resample
from ..core.mosaic.best_view import clip_depth, clipped_polygon, depth_map
from ..core.mosaic.minify import finest_stretch, minify_level, reduce_frame
from ..core.metrics import apply_homography
from ..errors import InputError

__all__ = ['MAX_COMPARE_PX', 'FrameAgreement']

#: Most mosaic pixels one frame is compared over; larger footprints are sampled every k-th pixel.
MAX_COMPARE_PX = 1_000_000
#: Fewer footprint pixels than this and a frame's NCC / sharpness are not computed (NaN).
MIN_COMPARE_PX = 400
#: Gaussian sigma (frame px) both images are smoothed by before the view from the frame compares them.
DETAIL_SIGMA_PX = 1.0
#: Most times finer than a frame pixel the mosaic is rendered before the average onto it.
SUPERSAMPLE = 4
#: Most pixels of a supersampled render onto one frame (the factor drops to keep under it).
MAX_RENDER_PX = 8_000_000
#: Most mosaic pixels read to render one frame's view (larger windows are read every k-th pixel).
MAX_WINDOW_PX = 16_000_000
_FRAME_ERODE_PX = 2  # the warped frame's edge pixels mix in the replicated border
_READ_ROWS = 512  # mosaic.tif rows read at a time (its tile height): memory bounded whatever the footprint
_GREY = np.array([0.299, 0.587, 0.114], dtype=np.float32)  # Rec. 601, as core.image_ops


@dataclass(frozen=True)
class FrameAgreement:
    """How one frame of the main mosaic agrees with mosaic.png.

    stamp_ns: the frame's stamp (frames.csv); ncc: normalised cross-correlation in [-1, 1] of the
    warped frame and the mosaic in its footprint; sharpness_ratio: mosaic over frame gradient
    energy there; pixels: footprint pixels compared; scale: 1 / k, the comparison's sampling step
    k in mosaic pixels (1.0, or less for footprints over MAX_COMPARE_PX). ncc and sharpness_ratio are
    NaN when the footprint is too small or flat; ``note`` then says why ('' otherwise). ncc_frame,
    sharpness_frame, frame_pixels: the same figures in the frame's pixels (module docstring).
    """

    stamp_ns: int
    ncc: float
    sharpness_ratio: float
    pixels: int
    scale: float
    note: str = ''
    ncc_frame: float = math.nan          # the mosaic seen from the frame (module docstring); NaN: not computed
    sharpness_frame: float = math.nan
    frame_pixels: int = 0                # frame pixels compared (at the compared width)


class _MosaicWindows:
    """Grey levels (float32 in [0, 1]) and alpha (uint8) of windows of the main mosaic.

    mosaic.tif (tiled, the same pixels as mosaic.png) is read window by window when present;
    otherwise mosaic.png is read once, whole.
    """

    def __init__(self, out_dir: Path) -> None:
        tif, png = out_dir / 'mosaic.tif', out_dir / 'mosaic.png'
        self._ds: Any = None
        self._grey: np.ndarray | None = None
        self._alpha: np.ndarray | None = None
        if tif.is_file():
            import rasterio
            from rasterio.enums import ColorInterp

            try:
                self._ds = rasterio.open(tif)
            except rasterio.errors.RasterioError as exc:
                msg = f'cannot read {tif} ({exc}); re-run `srmosaic process` to write it again.'
                raise InputError(msg) from None
            interp = self._ds.colorinterp
            self._has_alpha = interp[-1] == ColorInterp.alpha
            self._colour = self._ds.count - int(self._has_alpha)
            self.width, self.height = self._ds.width, self._ds.height
            return
        img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        if img is None:
            msg = f'cannot read {png}; re-run `srmosaic process` to write it again.'
            raise InputError(msg)
        if img.ndim == 2:
            self._grey, self._alpha = img.astype(np.float32) / 255.0, np.full(img.shape, 255, np.uint8)
        else:
            colour = img[:, :, :3] if img.shape[2] >= 3 else img[:, :, :1]
            grey = colour[:, :, ::-1] @ _GREY if colour.shape[2] == 3 else colour[:, :, 0].astype(np.float32)
            self._grey = (grey / 255.0).astype(np.float32)
            self._alpha = img[:, :, -1] if img.shape[2] in (2, 4) else np.full(img.shape[:2], 255, np.uint8)
        self.height, self.width = self._grey.shape

    def window(self, x0: int, y0: int, x1: int, y1: int, step: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(grey float32, alpha uint8) of mosaic pixels x0, x0 + step, ... < x1 across and y0, y0 +
        step, ... < y1 down (point samples, no filtering)."""
        if self._ds is None:
            return (np.ascontiguousarray(self._grey[y0:y1:step, x0:x1:step]),
                    np.ascontiguousarray(self._alpha[y0:y1:step, x0:x1:step]))
        from rasterio.windows import Window

        strips = []
        rows_per_read = max(step, (_READ_ROWS // step) * step)  # a multiple of step: the sampling stays regular
        for top in range(y0, y1, rows_per_read):
            bottom = min(y1, top + rows_per_read)
            strips.append(self._ds.read(window=Window(x0, top, x1 - x0, bottom - top))[:, ::step, ::step])
        bands = np.concatenate(strips, axis=1)
        colour = bands[:self._colour].astype(np.float32) / 255.0
        grey = np.tensordot(_GREY, colour, axes=1) if self._colour == 3 else colour[0]
        alpha = bands[-1] if self._has_alpha else np.full(grey.shape, 255, np.uint8)
        return np.ascontiguousarray(grey, dtype=np.float32), np.ascontiguousarray(alpha)

    def close(self) -> None:
        if self._ds is not None:
            self._ds.close()


def _agreement(stamp_ns: int, grey: np.ndarray, mosaic_H_frame: np.ndarray,
               mosaic: _MosaicWindows, max_stretch: float = 0.0, max_width: int = 0,
               interpolation: str = 'linear') -> FrameAgreement:
    """NCC and sharpness ratio of one frame (grey (h, w) float32) against the mosaic under it, in the
    mosaic's pixels and in the frame's (:func:`_seen_from_frame`).

    max_stretch: the run's mosaic.max_stretch: only the part of the frame the canvas painted (its
    far field and sky cut off, core/mosaic/best_view.py) is compared. max_width: the run's
    mosaic.max_width (0: none): wider frames are compared at that width in the frame's pixels.
    interpolation: the run's mosaic.interpolation (core/mosaic/resample.py; runs from before the key
    were painted bilinearly): the frame is warped into the mosaic as the canvas painted it.
    """
    h, w = grey.shape
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    if not np.all(np.isfinite(mosaic_H_frame)):
        return FrameAgreement(stamp_ns, math.nan, math.nan, 0, 1.0, 'mosaic_H_frame is not finite')
    m = mosaic_H_frame if (np.c_[corners, np.ones(4)] @ mosaic_H_frame[2]).max() > 0 else -mosaic_H_frame
    d_min = clip_depth(m, w, h, max_stretch)
    corners = clipped_polygon(m, corners, d_min if d_min is not None else (0.0 if max_stretch > 0 else None))
    depth = np.c_[corners, np.ones(len(corners))] @ m[2]
    if len(corners) < 3 or np.any(depth <= 0):
        return FrameAgreement(stamp_ns, math.nan, math.nan, 0, 1.0, 'footprint crosses the horizon')
    kept = None if d_min is None else depth_map(m, h, w) >= np.float32(d_min)  # what the canvas painted
    foot = apply_homography(m, corners)
    x0, y0 = max(0, math.floor(foot[:, 0].min())), max(0, math.floor(foot[:, 1].min()))
    x1, y1 = min(mosaic.width, math.ceil(foot[:, 0].max()) + 1), min(mosaic.height, math.ceil(foot[:, 1].max()) + 1)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return FrameAgreement(stamp_ns, math.nan, math.nan, 0, 1.0, 'footprint outside mosaic.png')
    # the window under the footprint, read once: every MAX_WINDOW_PX-th pixel for the view from the
    # frame, and every k-th of it for the comparison in the mosaic's pixels below
    step = max(1, math.ceil(math.sqrt((x1 - x0) * (y1 - y0) / MAX_WINDOW_PX)))
    window = mosaic.window(x0, y0, x1, y1, step)
    seen = _seen_from_frame(grey, kept, m, d_min, window, (x0, y0, step), max_width)
    level = minify_level(m, w, h, d_min)
    if level:  # reduced as the canvas reduces frames that shrink on the mosaic
        fill = grey if kept is None else np.where(kept, grey, np.float32(grey[kept].mean() if kept.any() else 0.0))
        reduced, kept, m_red = reduce_frame(np.ascontiguousarray(fill[:, :, None], np.float32), kept, m, level)
        grey = reduced[:, :, 0]
    else:
        m_red = m
    if kept is not None:
        grey = np.where(kept, grey, np.float32(np.nan))
    # footprints over MAX_COMPARE_PX: every k-th mosaic pixel across and down, point samples of
    # both images (no filtering of either), so the comparison stays exact, only sparser
    k = max(1, math.ceil(math.sqrt((x1 - x0) * (y1 - y0) / MAX_COMPARE_PX)))
    if step == 1:  # the same point samples as reading the window every k-th pixel
        m_grey, m_alpha = (np.ascontiguousarray(a[::k, ::k]) for a in window)
    else:
        m_grey, m_alpha = mosaic.window(x0, y0, x1, y1, k)
    bh, bw = m_grey.shape
    scale = 1.0 / k
    grid_H_mosaic = np.array([[scale, 0.0, -x0 * scale], [0.0, scale, -y0 * scale], [0.0, 0.0, 1.0]])
    grid_H_frame = grid_H_mosaic @ m_red
    # as the canvas paints: its interpolation, replicated border, and a separate validity mask
    kept = np.isfinite(grey)
    warped = resample.warp(np.where(kept, grey, np.float32(0.0)), grid_H_frame, (bw, bh), interpolation)
    valid = cv2.warpPerspective(kept.astype(np.uint8), grid_H_frame, (bw, bh), flags=cv2.INTER_NEAREST,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    kernel = np.ones((2 * _FRAME_ERODE_PX + 1,) * 2, np.uint8)
    covered = (m_alpha > 0).astype(np.uint8)
    mask = (cv2.erode(valid, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0) & (covered > 0)
    n = int(np.count_nonzero(mask))
    if n < MIN_COMPARE_PX:
        return FrameAgreement(stamp_ns, math.nan, math.nan, n, scale, f'footprint of {n} px is too small to compare',
                              *seen)
    ncc, ratio = _ncc_and_sharpness(warped, m_grey, mask, covered)
    note = '' if math.isfinite(ncc) and math.isfinite(ratio) else 'flat footprint (no contrast)'
    return FrameAgreement(stamp_ns, ncc, ratio, n, scale, note, *seen)


def _ncc_and_sharpness(frame: np.ndarray, mosaic: np.ndarray, mask: np.ndarray,
                       covered: np.ndarray) -> tuple[float, float]:
    """(NCC, gradient energy of ``mosaic`` over that of ``frame`` at the mosaic's level) of two grey
    images (same shape, float32 in [0, 1]) over ``mask``; the energies over ``mask`` eroded to the
    pixels whose 3x3 neighbourhood is ``covered`` (uint8, non-zero where the mosaic has pixels).
    NaN where flat."""
    a = frame[mask].astype(np.float64)
    b = mosaic[mask].astype(np.float64)
    a -= a.mean()
    b -= b.mean()
    denom = math.sqrt(float(a @ a) * float(b @ b))
    ncc = float(a @ b) / denom if denom > 1e-12 else math.nan
    sharp_mask = mask & (cv2.erode(covered, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                                   borderValue=0) > 0)
    e_frame, e_mosaic = _gradient_energy(frame, sharp_mask), _gradient_energy(mosaic, sharp_mask)
    if sharp_mask.any():  # the frame at the mosaic's level: an exposure gain is not blur
        level = float(frame[sharp_mask].mean())
        e_frame *= (float(mosaic[sharp_mask].mean()) / level) ** 2 if level > 1e-6 else 1.0
    ratio = e_mosaic / e_frame if e_frame > 1e-12 else math.nan
    return ncc, ratio


def _seen_from_frame(grey: np.ndarray, kept: np.ndarray | None, m: np.ndarray, d_min: float | None,
                     window: tuple[np.ndarray, np.ndarray], origin: tuple[int, int, int],
                     max_width: int) -> tuple[float, float, int]:
    """(ncc_frame, sharpness_frame, frame pixels compared) of a frame (grey (h, w) float32, the part
    painted ``kept`` (h, w) bool or None: all; mosaic_H_frame ``m`` (3, 3) with positive depth there,
    >= ``d_min``) against the mosaic ``window`` (grey float32, alpha uint8: _MosaicWindows.window)
    under it, whose pixel (0, 0) is mosaic pixel (x0, y0) of ``origin`` (x0, y0, step) and which
    samples every step-th mosaic pixel, rendered onto the frame's pixels (module docstring); NaN
    figures where fewer than MIN_COMPARE_PX pixels compare."""
    h, w = grey.shape
    c_H_frame = np.eye(3)  # compared pixels -> frame pixels
    if max_width and w > max_width:  # at the width the mosaic was painted at (its area mean)
        r = max_width / w
        wc, hc = max_width, max(1, round(h * r))
        sx, sy = w / wc, h / hc
        c_H_frame = np.array([[sx, 0.0, (sx - 1) / 2], [0.0, sy, (sy - 1) / 2], [0.0, 0.0, 1.0]])
        grey = cv2.resize(grey, (wc, hc), interpolation=cv2.INTER_AREA)
        if kept is not None:
            kept = cv2.resize(kept.astype(np.float32), (wc, hc), interpolation=cv2.INTER_AREA) > 0.999
        h, w = hc, wc
    x0, y0, k = origin
    m_grey, m_alpha = window
    win_H_c = np.array([[1.0 / k, 0.0, -x0 / k], [0.0, 1.0 / k, -y0 / k], [0.0, 0.0, 1.0]]) @ m @ c_H_frame
    # rendered s times finer where frame pixels land larger than window pixels, then area-averaged
    s = max(1, min(SUPERSAMPLE, math.ceil(finest_stretch(win_H_c, w, h, d_min) - 1e-9)))
    while s > 1 and w * h * s * s > MAX_RENDER_PX:
        s -= 1
    win_H_super = win_H_c @ np.array([[1.0 / s, 0.0, 0.5 / s - 0.5], [0.0, 1.0 / s, 0.5 / s - 0.5], [0.0, 0.0, 1.0]])
    flags = cv2.WARP_INVERSE_MAP  # the matrix maps the render's pixels to the window's
    render = cv2.warpPerspective(m_grey, win_H_super, (w * s, h * s), flags=cv2.INTER_LINEAR | flags,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    cover = cv2.warpPerspective(m_alpha, win_H_super, (w * s, h * s), flags=cv2.INTER_NEAREST | flags,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if s > 1:
        render = cv2.resize(render, (w, h), interpolation=cv2.INTER_AREA)
        cover = cover.reshape(h, s, w, s).min(axis=(1, 3))  # covered: every sample of the pixel
    covered = (cover > 0).astype(np.uint8)
    inside = covered if kept is None else covered & kept.view(np.uint8)
    kernel = np.ones((2 * _FRAME_ERODE_PX + 1,) * 2, np.uint8)  # the frame's rim too (constant 0 border)
    mask = cv2.erode(inside, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    n = int(np.count_nonzero(mask))
    if n < MIN_COMPARE_PX:
        return math.nan, math.nan, n
    ncc, _ = _ncc_and_sharpness(grey, render, mask, inside)
    # sharpness at the scale of a few frame pixels: the loss of two bilinear resamplings near
    # Nyquist (a third of the gradient energy) is not what this figure is for
    ksize = 2 * math.ceil(3 * DETAIL_SIGMA_PX) + 1
    grey = cv2.GaussianBlur(grey, (ksize, ksize), DETAIL_SIGMA_PX)
    render = cv2.GaussianBlur(render, (ksize, ksize), DETAIL_SIGMA_PX)
    inside = cv2.erode(inside, np.ones((ksize, ksize), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    _, ratio = _ncc_and_sharpness(grey, render, mask & (inside > 0), inside)
    return ncc, ratio, n


def _gradient_energy(grey: np.ndarray, mask: np.ndarray) -> float:
    """Mean of gx^2 + gy^2 (3x3 Sobel of the grey image in [0, 1]) over ``mask``; 0.0 for an empty mask."""
    if not mask.any():
        return 0.0
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    return float(np.mean((gx * gx + gy * gy)[mask], dtype=np.float64))

