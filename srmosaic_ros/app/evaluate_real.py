"""`srmosaic evaluate DIR` without --truth: figures of a real run that need no ground truth.

A process output (mosaic.png, frames.csv, report.json, and mosaic.tif when georeferenced) is
judged against its own input, re-read in frame order:

- ``fraction_in_main``: frames in the main mosaic (frames.csv ok=1) over frames.csv rows.
- Consistency: each frame of the main mosaic is warped into mosaic.png by its mosaic_H_frame,
  over the frame's bounding box in the mosaic only, and the normalised cross-correlation (NCC) of
  the grey levels of the warped frame and of the mosaic is taken inside the frame's footprint
  (the warped frame's valid mask eroded by 2 px, and mosaic alpha > 0). The mosaic is partly made
  of the frame itself, so a frame alone under itself scores 1.0 by construction: this figure says
  how well each frame agrees with the composite, and ghosting, misregistration, wedges between
  frames and blur all lower it. It is not an absolute registration error.
- Sharpness: per frame, the gradient energy (mean squared 3x3 Sobel gradient of the grey image,
  intensities in [0, 1]) of the mosaic over that of the warped frame, in the same footprint (its
  mosaic alpha eroded by 1 px more, so that no gradient reads a transparent pixel), the frame's
  taken at the mosaic's mean level there (energy scales with the square of an exposure gain, and
  the mosaic may have matched the frames' exposures). 1.0: the composite is as sharp as the frames;
  below: it is blurred, by averaging frames that do not line up, or by resampling.
- Seen from the frames (``ncc_frame``, ``sharpness_frame``): the same two figures the other way
  round, the mosaic resampled onto the frame's own pixels (over the part of the frame the canvas
  painted, where the mosaic covers it) and compared there, every frame pixel counting once. Where a
  frame lands on the mosaic smaller than it is (an oblique forward flight mosaicked in its first
  frame's plane: the later frames' near ground is crushed into the first frame's far field), the
  mosaic keeps little of what the frame saw: the mosaic-space figures cannot tell (they compare at
  the mosaic's sampling, where that frame is reduced too), these do. The mosaic is averaged over
  each frame pixel's footprint (rendered SUPERSAMPLE times finer where the frame is magnified on it,
  then area-reduced), so a mosaic finer than the frame is not charged with aliasing. Sharpness is
  taken at the scale of a few frame pixels (both images smoothed by DETAIL_SIGMA_PX): a frame alone
  under its own warp then scores NCC 1 and sharpness about 0.85 to 0.9 painted bilinearly, what the two bilinear
  resamplings there and back cost (0.7 unsmoothed). Frames wider than the run's mosaic.max_width are
  compared at that width, the sampling the user chose for the mosaic.
- Position error, when mosaic.tif exists and frames.csv carries ``meta_latitude,meta_longitude``
  (WGS84 degrees, where the footage's own metadata puts the frame centre on the ground): each
  frame's centre pixel ((w - 1) / 2, (h - 1) / 2) through mosaic_H_frame and mosaic.tif's
  geotransform, against the metadata position in mosaic.tif's CRS (pyproj), in metres.

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

import csv
import json
import math
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from tqdm import tqdm

from ..core.image_ops import to_gray_float01
from ..core.mosaic import resample
from ..core.mosaic.best_view import clip_depth, clipped_polygon, depth_map
from ..core.mosaic.minify import finest_stretch, minify_level, reduce_frame
from ..core.metrics import apply_homography
from ..core.types import CameraIntrinsics, Frame
from ..core.undistort import Undistorter
from ..errors import InputError
from ..io.mosaic_files import read_frames_csv

if TYPE_CHECKING:
    from ..io.bags import TopicConfig

__all__ = [
    'REPORT_SHAPE',
    'load_report',
    'MAX_COMPARE_PX',
    'META_COLUMNS',
    'FrameAgreement',
    'evaluate_real',
    'format_real_figures',
    'read_meta_positions',
]

#: Most mosaic pixels one frame is compared over; larger footprints are sampled every k-th pixel.
MAX_COMPARE_PX = 1_000_000
#: Optional trailing columns of frames.csv: the frame centre on the ground by the footage's metadata.
META_COLUMNS = ('meta_latitude', 'meta_longitude')
#: Fewer footprint pixels than this and a frame's NCC / sharpness are not computed (NaN).
MIN_COMPARE_PX = 400
#: Below this median sharpness seen from the frames (a frame alone: about 0.85) evaluate says the
#: mosaic is much coarser than its frames.
COARSE_MOSAIC_SHARPNESS = 0.5
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


def read_meta_positions(frames_csv: Path) -> dict[int, tuple[float, float]]:
    """stamp_ns -> (meta_latitude, meta_longitude) in WGS84 degrees, for the rows of ``frames_csv``
    whose metadata gives both as finite numbers; {} when the file has no such columns. A row with a
    value that is not a number is left out (as unknown), never an error."""
    out: dict[int, tuple[float, float]] = {}
    with open(frames_csv, newline='') as handle:
        reader = csv.DictReader(handle)
        if not set(META_COLUMNS) <= set(reader.fieldnames or []):
            return out
        for rec in reader:
            try:
                stamp = int(rec['stamp_ns'])
                lat, lon = float(rec['meta_latitude']), float(rec['meta_longitude'])
            except (TypeError, ValueError):
                continue
            if math.isfinite(lat) and math.isfinite(lon):
                out[stamp] = (lat, lon)
    return out


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


def _position_figures(out_dir: Path, main: list[dict[str, Any]], meta: dict[int, tuple[float, float]],
                      size: tuple[int, int], report: dict[str, Any]) -> tuple[dict[str, Any] | None, dict[int, float], str]:
    """(position summary or None, stamp_ns -> error_m, why None) of the main frames with metadata.

    ``size``: (w, h) of the frames (a flight's frames share one size: a size change ends a run);
    ``report``: the run's report.json (its not_georeferenced_reason says why there is no mosaic.tif).
    """
    tif = out_dir / 'mosaic.tif'
    if not tif.is_file():
        # its first clause (report.json keeps the whole reason, the way out included)
        why = re.split(r'\. |: |; ', str(report.get('not_georeferenced_reason') or ''))[0].rstrip('.')
        return None, {}, f'no mosaic.tif (the run is not georeferenced{": " + why if why else ""})'
    if not meta:
        with open(out_dir / 'frames.csv', newline='') as handle:
            has_columns = set(META_COLUMNS) <= set(next(csv.reader(handle), []))
        return None, {}, ('no frame has a metadata position: meta_latitude/meta_longitude all NaN' if has_columns
                          else 'frames.csv has no meta_latitude/meta_longitude')
    use = [r for r in main if r['stamp_ns'] in meta]
    if not use:
        return None, {}, 'no frame of the main mosaic has a metadata position'
    import rasterio
    from pyproj import Transformer

    with rasterio.open(tif) as ds:
        affine, crs = ds.transform, ds.crs
    if crs is None:
        return None, {}, f'{tif} has no CRS'
    w, h = size
    centre = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
    # rasterio's affine maps pixel corners: the centre of pixel (x, y) is at (x + 0.5, y + 0.5)
    est = np.array([affine @ tuple(apply_homography(r['mosaic_H_frame'], centre)[0] + 0.5) for r in use])
    to_map = Transformer.from_crs('EPSG:4326', crs, always_xy=True)
    lon_lat = np.array([(meta[r['stamp_ns']][1], meta[r['stamp_ns']][0]) for r in use])
    ref = np.c_[to_map.transform(lon_lat[:, 0], lon_lat[:, 1])]
    err = np.linalg.norm(est - ref, axis=1)
    epsg = crs.to_epsg()
    summary = {'frames': len(use), 'rms_m': float(np.sqrt(np.mean(err ** 2))), 'median_m': float(np.median(err)),
               'max_m': float(err.max()), 'crs': f'EPSG:{epsg}' if epsg is not None else crs.to_string()}
    return summary, {r['stamp_ns']: float(e) for r, e in zip(use, err)}, ''


#: What evaluate reads of report.json: dotted key -> (accepted types, what it should hold). A key may be
#: absent or null; present, it must have one of its types.
REPORT_SHAPE: dict[str, tuple[tuple[type, ...], str]] = {
    'input': ((str,), 'the input path, a string'),
    'input_kind': ((str,), "'bag', 'video' or 'images'"),
    'segments': ((list,), 'a list of segments'),
    'not_georeferenced_reason': ((str,), 'a sentence'),
    'video': ((dict,), 'an object'),
    'video.select': ((str,), "a frame selection such as 'all'"),
    'video.camera': ((str,), 'a camera YAML path'),
    'video.deinterlace': ((str,), "'auto', 'on' or 'off'"),
    'config': ((dict,), 'an object'),
    'config.undistort': ((bool,), 'true or false'),
    'config.mosaic': ((dict,), 'an object'),
    'config.mosaic.max_stretch': ((int, float), 'a number'),
    'config.mosaic.max_width': ((int,), 'an integer'),
    'sr': ((dict,), 'an object'),
    'sr.psf_sigma_px': ((int, float), 'a number'),
}


def load_report(path: Path) -> dict[str, Any]:
    """report.json of a run, checked against REPORT_SHAPE; InputError saying what is wrong with it
    (unreadable, not an object, a key of the wrong type) and to re-run process."""
    from ..bounded_yaml import preview

    again = 're-run `srmosaic process` to write it again'
    try:
        report = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        msg = f'{path} is not readable JSON ({" ".join(str(exc).split())[:120]}); {again}.'
        raise InputError(msg) from None
    def said(value: Any) -> str:  # as JSON names it
        kind = {dict: 'an object', list: 'an array', str: 'a string', bool: 'a boolean', int: 'a number',
                float: 'a number'}.get(type(value), type(value).__name__)
        return 'null' if value is None else f'{kind}, {preview(value)}'

    if not isinstance(report, dict):
        msg = f'{path} holds {said(report)}, not the object `srmosaic process` writes; {again}.'
        raise InputError(msg)
    for key, (types, what) in REPORT_SHAPE.items():
        *parents, leaf = key.split('.')
        node: Any = report
        for part in parents:
            node = node.get(part) if isinstance(node, dict) else None
        value = node.get(leaf) if isinstance(node, dict) else None
        if value is not None and (not isinstance(value, types) or (bool not in types and isinstance(value, bool))):
            msg = f'{path}: "{key}" is {said(value)}, but it should be {what}; the file was edited or damaged: {again}.'
            raise InputError(msg)
    return report


def _load_run(out_dir: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(report.json, frames.csv rows), InputError naming what is missing."""
    for name in ('frames.csv', 'report.json', 'mosaic.png'):
        if not (out_dir / name).is_file():
            msg = f'{out_dir / name} not found; run `srmosaic process INPUT --out {out_dir}` first.'
            raise InputError(msg)
    report = load_report(out_dir / 'report.json')
    try:
        rows = read_frames_csv(out_dir / 'frames.csv')
    except (ValueError, KeyError) as exc:
        msg = f'{out_dir / "frames.csv"} is not a frames.csv of `srmosaic process` ({exc}); re-run process.'
        raise InputError(msg) from None
    return report, rows


def _pick(n: int, max_frames: int | None) -> np.ndarray:
    """Indices of at most max_frames of n, spread evenly over the run (first and last included)."""
    if max_frames is None or max_frames >= n:
        return np.arange(n)
    if max_frames < 1:
        msg = f'max_frames must be at least 1, got {max_frames}.'
        raise InputError(msg)
    return np.unique(np.round(np.linspace(0, n - 1, max_frames)).astype(int))


def _nan_stat(values: list[float], fn: Any) -> float | None:
    v = np.array([x for x in values if math.isfinite(x)])
    return float(fn(v)) if v.size else None


def evaluate_real(out_dir: Path, *, progress: bool = True, max_frames: int | None = None,
                  input_path: Path | None = None, camera_yaml: Path | None = None,
                  topics: TopicConfig | None = None, undistort: bool | None = None) -> dict[str, Any]:
    """Truth-free figures of the process output ``out_dir`` (see the module docstring).

    Args:
        out_dir: a `srmosaic process` output directory (frames.csv, report.json, mosaic.png).
        progress: a tqdm bar on stderr while the input is re-read.
        max_frames: compare at most this many frames of the main mosaic, spread evenly over the
            run (None: all). The position figures use every frame with metadata regardless.
        input_path: the input to re-read instead of report.json's 'input' (moved or relative).
        camera_yaml, topics: what `process` was given (--camera, topic options), so that the
            frames are re-read, and undistorted, as that run saw them. Default: the camera YAML
            report.json names (a video run records its --camera), read again.
        undistort: whether that run undistorted its frames (default: report.json's config, else
            True); the video's deinterlace mode is report.json's.

    Returns a JSON-serialisable dict: input (str), input_kind, frames_rows, frames_in_main,
    fraction_in_main (0..1), frames_compared (frames with a finite NCC), frames_not_in_input
    (main frames whose stamp the input no longer has), frames_reduced (compared on every k-th mosaic pixel, k > 1),
    ncc_median, ncc_p10, sharpness_median (None when no frame could be compared),
    frames_compared_in_frame, ncc_frame_median, ncc_frame_p10, sharpness_frame_median (the same, seen
    from the frames: the mosaic rendered onto each frame's pixels), position (None,
    or {frames, rms_m, median_m, max_m, crs}), position_note (why it is None, '' otherwise), and
    per_frame: one entry per main frame compared, {stamp_ns, ncc, sharpness_ratio, pixels, scale,
    note, ncc_frame, sharpness_frame, frame_pixels, position_error_m (metres, or None)} (NaN
    figures as None).

    Raises InputError when a file of the run is missing or unreadable, the input is gone, no frame
    is in the main mosaic, or no frame of the input has a stamp of frames.csv.
    """
    from .process import open_source

    out_dir = Path(out_dir)
    report, rows = _load_run(out_dir)
    main = [r for r in rows if r['ok']]
    if not main:
        msg = (f'{out_dir / "frames.csv"} has no frame in the main mosaic (ok=1 in none of {len(rows)} rows); '
               'nothing to evaluate: see report.json failure_reasons and re-run process.')
        raise InputError(msg)
    if input_path is None:
        if not report.get('input'):
            msg = f'{out_dir / "report.json"} does not name its input; pass the input (input_path).'
            raise InputError(msg)
        source = Path(report['input'])
        if not source.exists():
            msg = (f'the input of {out_dir}, {source} (report.json "input"), no longer exists; '
                   're-run process or pass the input (input_path).')
            raise InputError(msg)
    else:
        source = Path(input_path)
        if not source.exists():
            msg = f'input {source} does not exist; pass the input that {out_dir} was processed from.'
            raise InputError(msg)
    kind = report.get('input_kind', '')
    video = (report.get('video') or {}) if kind == 'video' else {}
    select = str(video.get('select', 'all'))
    if camera_yaml is None and video.get('camera'):
        camera_yaml = Path(video['camera'])
        if not camera_yaml.is_file():
            msg = (f'{out_dir} was processed with the camera calibration {camera_yaml} (report.json video.camera), '
                   'which no longer exists; pass it (--camera) so that the frames are undistorted as that run saw them.')
            raise InputError(msg)
    if undistort is None:
        undistort = bool(((report.get('config') or {}).get('undistort', True)))
    reread = {'deinterlace': video['deinterlace']} if video.get('deinterlace') else {}
    items, _, kind_now = open_source(source, topics=topics, select=select, camera_yaml=camera_yaml, **reread)
    meta = read_meta_positions(out_dir / 'frames.csv')
    mosaic_config = (report.get('config') or {}).get('mosaic') or {}
    max_stretch = float(mosaic_config.get('max_stretch', 0.0))
    max_width = int(mosaic_config.get('max_width', 0))
    interpolation = str(mosaic_config.get('interpolation', 'linear'))  # before the key: bilinear
    if interpolation not in resample.INTERPOLATIONS:
        msg = (f"{out_dir / 'report.json'} says the mosaic was painted with interpolation {interpolation!r}, which "
               f"this version does not know ({', '.join(resample.INTERPOLATIONS)}); evaluate it with the version that made it.")
        raise InputError(msg)

    wanted = {main[i]['stamp_ns']: main[i] for i in _pick(len(main), max_frames)}
    mosaic = _MosaicWindows(out_dir)
    undistorter, camera = Undistorter(undistort), None
    results: dict[int, FrameAgreement] = {}
    size: tuple[int, int] | None = None
    try:
        with tqdm(total=len(wanted), unit='frame', desc='evaluate', disable=not progress) as bar:
            for item in items:
                if isinstance(item, CameraIntrinsics):
                    camera = item
                if not isinstance(item, Frame) or item.stamp_ns not in wanted or item.stamp_ns in results:
                    continue
                frame = undistorter.frame(item, camera)  # as the pipeline saw it
                size = size or (frame.image.shape[1], frame.image.shape[0])
                results[item.stamp_ns] = _agreement(item.stamp_ns, to_gray_float01(frame.image),
                                                    wanted[item.stamp_ns]['mosaic_H_frame'], mosaic, max_stretch,
                                                    max_width, interpolation)
                bar.update(1)
                if len(results) == len(wanted):
                    break  # the rest of the input holds no frame to compare
    finally:
        mosaic.close()
    if not results or size is None:
        msg = (f'no frame of {source} has a stamp of {out_dir / "frames.csv"}: is it the input of that run '
               '(and, for video, the same --select)? Re-run process or pass the input (input_path).')
        raise InputError(msg)
    position, pos_err, pos_note = _position_figures(out_dir, main, meta, size, report)

    ordered = [results[s] for s in wanted if s in results]
    nccs = [a.ncc for a in ordered]
    sharp = [a.sharpness_ratio for a in ordered]
    per_frame = []
    for a in ordered:
        entry = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(a).items()}
        entry['position_error_m'] = pos_err.get(a.stamp_ns)
        per_frame.append(entry)
    return {
        'input': str(source),
        'input_kind': kind_now,
        'frames_rows': len(rows),
        'frames_in_main': len(main),
        'fraction_in_main': len(main) / len(rows),
        'frames_compared': int(sum(math.isfinite(v) for v in nccs)),
        'frames_not_in_input': len(wanted) - len(results),
        'frames_reduced': int(sum(a.scale < 1.0 for a in ordered)),
        'ncc_median': _nan_stat(nccs, np.median),
        'ncc_p10': _nan_stat(nccs, lambda v: np.percentile(v, 10)),
        'sharpness_median': _nan_stat(sharp, np.median),
        'frames_compared_in_frame': int(sum(math.isfinite(a.ncc_frame) for a in ordered)),
        'ncc_frame_median': _nan_stat([a.ncc_frame for a in ordered], np.median),
        'ncc_frame_p10': _nan_stat([a.ncc_frame for a in ordered], lambda v: np.percentile(v, 10)),
        'sharpness_frame_median': _nan_stat([a.sharpness_frame for a in ordered], np.median),
        'position': position,
        'position_note': pos_note,
        'per_frame': per_frame,
    }


def format_real_figures(figures: dict[str, Any]) -> list[str]:
    """The lines `srmosaic evaluate DIR` prints for :func:`evaluate_real`'s figures."""
    n_main, n_rows = figures['frames_in_main'], figures['frames_rows']
    lines = [f'frames in main mosaic: {n_main}/{n_rows} ({100.0 * figures["fraction_in_main"]:.0f}%)']
    n = figures['frames_compared']
    if figures['ncc_median'] is None:
        lines.append('consistency (NCC frame vs mosaic): no frame could be compared')
    else:
        lines.append(f'consistency (NCC frame vs mosaic): median {figures["ncc_median"]:.3f}, '
                     f'p10 {figures["ncc_p10"]:.3f} over {n} frames (1.0: frames agree with the composite)')
    if figures['sharpness_median'] is not None:
        lines.append(f'sharpness (mosaic vs frame gradient energy): median {figures["sharpness_median"]:.3f} '
                     '(1.0: as sharp as the frames)')
    if figures.get('ncc_frame_median') is not None:
        lines.append(f'seen from the frames (the mosaic on each frame\'s pixels): consistency median '
                     f'{figures["ncc_frame_median"]:.3f}, p10 {figures["ncc_frame_p10"]:.3f}, sharpness median '
                     f'{figures["sharpness_frame_median"]:.3f} over {figures["frames_compared_in_frame"]} frames '
                     '(a frame alone under its own warp: 1.0 and about 0.85; lower sharpness: the mosaic keeps '
                     'less of the detail the frames saw)')
        if figures['sharpness_frame_median'] < COARSE_MOSAIC_SHARPNESS:
            lines.append('  the mosaic is much coarser than its frames: they land on it smaller than they are (a '
                         'forward or oblique flight drawn in its first frame\'s plane, or a zoom in), or it is blurred; '
                         'docs/guide/compositing.md, "Oblique views"')
    if figures.get('frames_reduced'):
        lines.append(f'  {figures["frames_reduced"]} frames cover more than {MAX_COMPARE_PX / 1e6:g} Mpx of the mosaic: '
                     'compared on every k-th mosaic pixel')
    if figures.get('frames_not_in_input'):
        lines.append(f'  {figures["frames_not_in_input"]} frames of frames.csv not found in the input: not compared')
    pos = figures.get('position')
    if pos is None:
        lines.append(f'position vs metadata: not available ({figures.get("position_note") or "no data"})')
    else:
        lines.append(f'position vs metadata (frame centres): RMS {pos["rms_m"]:.2f} m, median {pos["median_m"]:.2f} m, '
                     f'max {pos["max_m"]:.2f} m over {pos["frames"]} frames ({pos["crs"]})')
    return lines
