"""The camera's Gaussian PSF measured on straight edges in the frames (slanted-edge method).

The SR observation model (5.1) needs the blur B of the camera: the std ``psf_sigma`` (LR pixels)
of the Gaussian that, with point sampling D, maps the ground to a frame pixel. A wrong value costs
dearly (bench/psf.py: over-estimating it by 0.3 px loses more than the whole SR gain), and the
reference lists PSF estimation as future work. This module measures it as camera MTFs are
measured in the field: the *slanted-edge* method (ISO 12233; Reichenbach et al. 1991), with a model
fit in place of the binned derivative.

A straight step edge blurred by a Gaussian of std sigma has the profile (edge spread function)

    I(d) = a + b * Phi((d - d0) / sigma),        Phi the standard normal CDF,

across it, d the signed distance of a pixel centre from the line. An edge slanted against the pixel
grid samples d at every sub-pixel phase, so the fit resolves sigma well below a pixel. Line
segments come from OpenCV's LSD; each one's pixels within ``band`` px of the line are fitted for
(a, b, d0, tilt, sigma) (tilt: a small correction of the segment's angle) by least squares, and kept
when the profile is a clean step: enough contrast, a residual small against the contrast, phases
covering a pixel, sigma inside the bounds.

Ground edges are never perfectly sharp (kerbs, shadows, soil, the world photo's own blur in a
simulated flight): every edge measures ``sqrt(sigma_camera^2 + sigma_edge^2) >= sigma_camera``, and
no image-only method can tell the two apart (a sharper ground blurred more gives the same frames,
so the multi-frame data cannot either). On natural terrain at 0.1 to 0.2 m per pixel the sharpest
edges are about 1.4 px wide whatever the camera (bench/psf.py), so the estimate is meant for frames
of a *target* with sharp straight edges (a printed slanted-edge chart, the checkerboard of the
camera calibration, roofs and road markings at low altitude). There all edges agree: the
interquartile range of the edge sigmas (``spread``) is a few hundredths of a pixel, against 0.3 to
0.5 px on terrain; :attr:`PsfEstimate.scene_limited` flags a spread above ``max_spread`` (the estimate
is then an upper bound of the camera's blur, and an over-estimated PSF makes SR ring: use it only
with that in mind). The estimate is a quantile of the accepted edges (default the lower quartile,
which leans to the sharpest edges without being the noisiest).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.special import ndtr

from ...errors import SrMosaicError

__all__ = ['EdgeFit', 'PsfEstimate', 'PsfEstimationError', 'estimate_psf_sigma', 'fit_edge_profile']


class PsfEstimationError(SrMosaicError):
    """The frames hold too few clean straight edges to measure the PSF."""


@dataclass(frozen=True)
class EdgeFit:
    """One fitted edge: sigma (LR px), contrast b (intensity in [0, 1]), residual RMS, samples."""

    sigma: float
    contrast: float
    rms: float
    samples: int
    length_px: float


@dataclass
class PsfEstimate:
    """The estimate: ``sigma`` (LR px), from ``edges`` accepted edges of ``frames`` frames.

    edge_sigmas: (edges,) per accepted edge, sorted; quantile: the one taken as ``sigma``;
    spread: the interquartile range of edge_sigmas (px), a measure of how much the scene's own
    edge widths vary.
    """

    sigma: float
    edges: int
    frames: int
    quantile: float
    edge_sigmas: np.ndarray = field(repr=False)
    spread: float = 0.0
    max_spread: float = 0.1

    @property
    def scene_limited(self) -> bool:
        """True when the edges disagree (spread > max_spread): the scene's edges, not the camera, set
        their widths, and ``sigma`` only bounds the camera's blur from above."""
        return self.spread > self.max_spread

    def as_dict(self) -> dict[str, float | int]:
        """The figures for a report (JSON-friendly)."""
        return {'sigma_px': round(self.sigma, 4), 'edges': self.edges, 'frames': self.frames,
                'quantile': self.quantile, 'spread_px': round(self.spread, 4),
                'median_edge_sigma_px': round(float(np.median(self.edge_sigmas)), 4),
                'scene_limited': self.scene_limited}


def _gray01(frame: np.ndarray) -> np.ndarray:
    """(h, w) float64 in [0, 1] of an (h, w) / (h, w, C) uint8, uint16 or float frame (alpha dropped)."""
    img = np.asarray(frame)
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(img.dtype, 1.0)
    img = img.astype(np.float64) / scale
    if img.ndim == 3:
        img = img[:, :, :3].mean(axis=2)
    return np.clip(img, 0.0, 1.0)


def fit_edge_profile(gray: np.ndarray, p0: np.ndarray, p1: np.ndarray, *, band: float = 5.0,
                     trim: float = 2.0, sigma_bounds: tuple[float, float] = (0.05, 4.0),
                     ) -> EdgeFit | None:
    """Fit the blurred-step profile across the segment p0 -> p1 (pixel coordinates, x right, y down).

    gray: (h, w) float in [0, 1]. Pixels within ``band`` px of the line and more than ``trim`` px
    inside the segment's ends are used. Returns None when the samples cannot be fitted (too few,
    or the phases of d do not cover a pixel: an edge aligned with the pixel grid).
    """
    p0 = np.asarray(p0, dtype=np.float64)
    p1 = np.asarray(p1, dtype=np.float64)
    length = float(np.hypot(*(p1 - p0)))
    if length < 2 * trim + 4:
        return None
    t_hat = (p1 - p0) / length
    n_hat = np.array([-t_hat[1], t_hat[0]])
    h, w = gray.shape
    lo = np.floor(np.minimum(p0, p1) - band - 1).astype(int)
    hi = np.ceil(np.maximum(p0, p1) + band + 1).astype(int)
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0], w - 1), min(hi[1], h - 1)
    if x1 <= x0 or y1 <= y0:
        return None
    ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
    rel = np.stack([xs.ravel() - p0[0], ys.ravel() - p0[1]], axis=1)
    t = rel @ t_hat
    d = rel @ n_hat
    keep = (np.abs(d) <= band) & (t >= trim) & (t <= length - trim)
    if keep.sum() < 40:
        return None
    t, d = t[keep], d[keep]
    v = gray[ys.ravel()[keep], xs.ravel()[keep]]
    # The slant must sweep the pixel phase of d over at least one pixel along the segment, or the
    # profile is sampled at one phase only and sigma is ill-determined below a pixel.
    slant = abs(t_hat[0] * t_hat[1]) / max(abs(t_hat[0]), abs(t_hat[1]))  # |sin| of the angle to the nearer axis
    if (length - 2 * trim) * slant < 1.0:
        return None
    t_c = t - t.mean()
    neg, pos = v[d < -1.5], v[d > 1.5]
    if neg.size < 10 or pos.size < 10:
        return None
    a0, b0 = float(np.median(neg)), float(np.median(pos) - np.median(neg))
    lo_s, hi_s = sigma_bounds

    def residual(q: np.ndarray) -> np.ndarray:
        a, b, d0, tilt, log_s = q
        return a + b * ndtr((d - d0 - tilt * t_c) / math.exp(log_s)) - v

    q0 = np.array([a0, b0, 0.0, 0.0, math.log(0.7)])
    bounds = ([-1.0, -2.0, -2.0, -0.1, math.log(lo_s)], [2.0, 2.0, 2.0, 0.1, math.log(hi_s)])
    try:
        sol = least_squares(residual, q0, bounds=bounds, method='trf', x_scale=[0.1, 0.1, 0.5, 0.01, 0.3])
    except (ValueError, np.linalg.LinAlgError):
        return None
    a, b, d0, tilt, log_s = sol.x
    rms = float(np.sqrt(np.mean(sol.fun**2)))
    return EdgeFit(sigma=float(math.exp(log_s)), contrast=float(b), rms=rms, samples=int(v.size), length_px=length)


def _segments(gray: np.ndarray, min_length: float) -> np.ndarray:
    """(M, 4) LSD segments x0, y0, x1, y1 of at least ``min_length`` px, longest first."""
    lsd = cv2.createLineSegmentDetector()
    lines = lsd.detect(np.clip(gray * 255.0 + 0.5, 0, 255).astype(np.uint8))[0]
    if lines is None or len(lines) == 0:
        return np.zeros((0, 4))
    seg = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    order = np.argsort(-length)
    seg, length = seg[order], length[order]
    return seg[length >= min_length]


def estimate_psf_sigma(frames: Sequence[np.ndarray], *, min_length: float = 16.0, band: float = 5.0,
                       min_contrast: float = 0.08, max_rel_rms: float = 0.1, max_edges_per_frame: int = 80,
                       min_edges: int = 8, quantile: float = 0.25, max_spread: float = 0.1,
                       sigma_bounds: tuple[float, float] = (0.1, 3.0)) -> PsfEstimate:
    """The Gaussian PSF std (LR px) of the camera that took ``frames``, from their straight edges.

    frames: images (h, w) or (h, w, C), uint8 / uint16 / float in [0, 1], all from one camera at
        one focus (undistorted, as the SR stage sees them).
    min_length: shortest LSD segment used (px). band: half-width of the profile (px); an edge
        whose neighbour is nearer than that is rejected by its residual.
    min_contrast: smallest step |b| (intensity in [0, 1]); max_rel_rms: largest fit residual RMS
        relative to |b|. max_edges_per_frame: longest segments fitted per frame.
    min_edges: fewer accepted edges raise :class:`PsfEstimationError`.
    quantile: of the accepted edges' sigmas taken as the estimate (see the module docstring).
    max_spread: interquartile range of the edge sigmas (px) above which the estimate is flagged
        :attr:`PsfEstimate.scene_limited`.
    sigma_bounds: an edge whose sigma reaches them is rejected (no edge, or a ramp).

    Returns a :class:`PsfEstimate`.
    """
    if not 0.0 < quantile < 1.0:
        msg = f'quantile must be in (0, 1), got {quantile}.'
        raise ValueError(msg)
    sigmas: list[float] = []
    used = 0
    for frame in frames:
        gray = _gray01(frame)
        if min(gray.shape) < 2 * band + 8:
            continue
        used += 1
        for x0, y0, x1, y1 in _segments(gray, min_length)[:max_edges_per_frame]:
            fit = fit_edge_profile(gray, np.array([x0, y0]), np.array([x1, y1]), band=band,
                                   sigma_bounds=(sigma_bounds[0] * 0.5, sigma_bounds[1] * 1.5))
            if fit is None or abs(fit.contrast) < min_contrast or fit.rms > max_rel_rms * abs(fit.contrast):
                continue
            if not sigma_bounds[0] < fit.sigma < sigma_bounds[1]:
                continue
            sigmas.append(fit.sigma)
    if len(sigmas) < min_edges:
        msg = (f'only {len(sigmas)} clean straight edges in {used} frames (need {min_edges}) to measure the '
               'camera PSF; image a target with sharp straight edges (a printed chart, the calibration checkerboard) or set '
               'sr.psf_sigma from the camera\'s data sheet.')
        raise PsfEstimationError(msg)
    arr = np.sort(np.asarray(sigmas))
    q25, q75 = np.quantile(arr, [0.25, 0.75])
    return PsfEstimate(sigma=float(np.quantile(arr, quantile)), edges=int(arr.size), frames=used,
                       quantile=quantile, edge_sigmas=arr, spread=float(q75 - q25), max_spread=max_spread)
