"""Direct photometric refinement of a homography: inverse-compositional Lucas-Kanade in torch.

Started from the feature estimate, it minimises over the 8 homography parameters the
intensity difference between a template frame T and an image frame I warped onto it,

    sum_x rho( a I(image_H_template x) + b - T(x) ),

coarse to fine over pyramid levels (by default the full-resolution level alone: the feature
estimate is well inside its convergence basin), on a sparse set of high-gradient template pixels
(the pixel of largest gradient in each block of a grid, the strongest ones kept). Inverse
compositional (Baker and Matthews 2004): the steepest-descent images dT/dx dW/dp are computed once
per frame (when the frame is described) and the update is W <- W o W(dp)^-1. The gain a and bias
b are re-fitted at each iteration (IR automatic gain), rho is Huber (iteratively reweighted, at
the weighted RMS scale of the residuals: occlusions, moving objects) or Tukey's biweight at c = 6
robust sigmas (sigma = 1.4826 x the median absolute residual), and pixels that warp outside the
image frame drop out. Tukey gives what disagrees by parallax (buildings standing on the ground
plane) no say where Huber gives it a say in proportion, so that the plane tilts toward the roofs
when they hold many of the strong gradients (bench/parallax.py); but it also stops short where
the feature estimate is a pixel or more off (its cut then drops the very edges that would move it):
on real turret video the frames agree less with their mosaic. Hence Huber by default, Tukey
on request (registration.photometric_loss). c = 6 rather than the textbook 4.685: under a zoom of
1.5 between frames their different blur leaves residuals on every strong edge. Accuracy is
limited by sensor noise; the registrar smooths the frames slightly
(TorchRegistrarOptions.pyramid_sigma) before building the templates.

Either frame of a pair can be the template (every frame's template is built when it is described);
the registrar picks the one with the finer ground sampling, so that the other is sampled densely
(sampling it sparser than its pixels would alias).

Convention: image_H_template maps template pixels to image pixels (full resolution, pixel centres
at integers). Each level works in normalised coordinates
x_n = (x_l - c_l) / s_l (c_l the level centre, s_l half its larger side) for conditioning.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..homography import h8_jacobian

__all__ = ['PhotometricOptions', 'PhotometricResult', 'PhotometricTemplate', 'make_template', 'refine_photometric']


_MAD_STRIDE = 8  # every 8th template pixel (~2,000 of 16,000) sets the robust scale


@dataclass(frozen=True)
class PhotometricOptions:
    """Settings of the photometric refinement.

    levels: pyramid levels used, coarse to fine (0 = full resolution).
    points: template pixels per level (in the order of levels): the level is cut into about this
        many blocks, each offering its strongest-gradient pixel.
    max_iterations: iterations per level.
    tol_px: a level stops when an update moves no frame corner by more than this (level pixels).
    loss: 'tukey' (biweight at ``tukey_c`` robust sigmas, the MAD of the residuals) or 'huber' (at
        ``huber_k`` times the weighted RMS of the residuals).
    """

    levels: tuple[int, ...] = (0,)
    points: tuple[int, ...] = (16000,)
    max_iterations: int = 12  # converged pairs stop at 3 to 8; scale changes near 1.5 need up to 8
    tol_px: float = 2e-3
    huber_k: float = 2.0
    loss: str = 'huber'
    tukey_c: float = 6.0

    def __post_init__(self) -> None:
        if len(self.levels) != len(self.points) or not self.levels or min(self.points) < 16:
            msg = 'photometric levels and points need one entry per level, and points >= 16.'
            raise ValueError(msg)
        if self.max_iterations < 1 or self.tol_px <= 0.0 or self.huber_k <= 0.0 or self.tukey_c <= 0.0:
            msg = 'photometric max_iterations >= 1, tol_px > 0, huber_k > 0 and tukey_c > 0 are required.'
            raise ValueError(msg)
        if self.loss not in ('tukey', 'huber'):
            msg = f"photometric loss {self.loss!r}: use 'tukey' or 'huber'."
            raise ValueError(msg)


@dataclass
class PhotometricTemplate:
    """Precomputed template of one pyramid level of a frame.

    level: pyramid level; size: (w, h) of the level; xn: (3, P) float32 homogeneous normalised
    coordinates of the template pixels (one column per pixel); values: (P,) intensities;
    sd: (8, P) steepest-descent images (feature-major, for fast weighted products); norm_from_full:
    (3, 3) float64 numpy, full-resolution pixels -> normalised level
    coordinates; grid_from_norm: (3, 3) normalised coordinates -> grid_sample coordinates.
    """

    level: int
    size: tuple[int, int]
    xn: torch.Tensor
    values: torch.Tensor
    sd: torch.Tensor
    norm_from_full: np.ndarray
    grid_from_norm: np.ndarray


@dataclass(frozen=True)
class PhotometricResult:
    """prev_H_cur: (3, 3) float64 refined; iterations: total over levels; rms: robust RMS intensity
    residual at the finest level; converged: the finest level met tol_px; valid_fraction: template
    pixels of the finest level that landed inside the image frame."""

    image_H_template: np.ndarray
    iterations: int
    rms: float
    converged: bool
    valid_fraction: float
    covariance: np.ndarray | None = None  # (8, 8) of image_H_template's h (h22 = 1), Gauss-Newton; see below


#: Variance inflation of the photometric Gauss-Newton covariance for correlated pixel residuals.
RESIDUAL_CORRELATION_VARIANCE_FACTOR = 2.0


def inverse_covariance(H: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(8, 8) covariance of h of H^-1, given that of h of H (h22 = 1): J C J^T with J the exact
    Jacobian of h(H^-1) (d H^-1 = -H^-1 dH H^-1)."""
    Hi = np.linalg.inv(H / H[2, 2])
    J = h8_jacobian(-Hi, Hi, Hi)
    return J @ covariance @ J.T


def _gauss_newton_covariance(hess: np.ndarray, scale2: float, Hn: np.ndarray, M: np.ndarray) -> np.ndarray | None:
    """(8, 8) covariance of h (h22 = 1) of H = M^-1 Hn M at the end of the inverse-compositional
    fit: cov(dp) = s^2 (J^T W J)^-1 (``hess`` (8, 8) float64, the Gauss-Newton normal matrix of the
    last step, s^2 the robust residual variance), carried to h through H(dp) = M^-1 Hn D(dp)^-1 M
    (d D^-1 = -dD at dp = 0). Pixel residuals are not independent (the optics blur neighbours
    together), so s^2 (J^T W J)^-1 is a lower bound: it is inflated by
    RESIDUAL_CORRELATION_VARIANCE_FACTOR (2: on simulated flights the refined corners' errors are
    about 1.5 times the uninflated sigma)."""
    try:
        cov_dp = RESIDUAL_CORRELATION_VARIANCE_FACTOR * scale2 * np.linalg.inv(hess)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(cov_dp)):
        return None
    A = np.linalg.inv(M) @ Hn
    J = h8_jacobian(-A, M, A @ M)
    return J @ cov_dp @ J.T


def _level_matrices(level: int, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    f = float(2**level)
    level_from_full = np.array([[1.0 / f, 0.0, -(f - 1.0) / (2.0 * f)], [0.0, 1.0 / f, -(f - 1.0) / (2.0 * f)],
                                [0.0, 0.0, 1.0]])
    s = max(w, h) / 2.0
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    norm_from_level = np.array([[1.0 / s, 0.0, -cx / s], [0.0, 1.0 / s, -cy / s], [0.0, 0.0, 1.0]])
    grid_from_level = np.array([[2.0 / (w - 1), 0.0, -1.0], [0.0, 2.0 / (h - 1), -1.0], [0.0, 0.0, 1.0]])
    return norm_from_level @ level_from_full, grid_from_level @ np.linalg.inv(norm_from_level)


def make_template(image: torch.Tensor, level: int, *, points: int, static: bool = False) -> PhotometricTemplate:
    """Template of a level image (1, 1, h, w): the image is cut into about `points` square blocks,
    each block offers its pixel of largest gradient, and the `points` strongest offers are kept
    (blocks on the border are left out), with intensities and steepest-descent images.

    static: exactly min(points, interior blocks) pixels, chosen by ``topk`` (fixed shapes, no host
    synchronisation: what a CUDA graph can capture); by default every block at or above the
    points-th strongest offer (``nonzero``: ties at the cut may add a few)."""
    _, _, h, w = image.shape
    b = max(1, round(math.sqrt(h * w / points)))
    hb, wb = h // b, w // b
    norm_from_full, grid_from_norm = _level_matrices(level, w, h)
    s = max(w, h) / 2.0
    if hb < 3 or wb < 3:  # no interior block
        empty = image.new_zeros(0)
        return PhotometricTemplate(level, (w, h), image.new_zeros(3, 0), empty, image.new_zeros(8, 0),
                                   norm_from_full, grid_from_norm)
    # Central differences over the interior blocks only (their neighbours are all inside the
    # image: no padding), at twice the gradient (the 1/2 is applied to the few pixels kept; the
    # block maxima and the cut are the same up to that exact factor 4).
    img = image[0, 0]
    r0, r1, c0, c1 = b, (hb - 1) * b, b, (wb - 1) * b
    wi = c1 - c0
    dx = torch.sub(img[r0:r1, c0 + 1:c1 + 1], img[r0:r1, c0 - 1:c1 - 1])
    dy = torch.sub(img[r0 + 1:r1 + 1, c0:c1], img[r0 - 1:r1 - 1, c0:c1])
    mag = torch.addcmul(dx * dx, dy, dy)
    # Block maxima and their first arg-max (row-major within the block) in one pass; flat
    # indices into the interior (width wi).
    bmax, arg = F.max_pool2d(mag[None, None], b, b, return_indices=True)
    flat, arg = bmax.view(-1), arg.view(-1)
    n_in = flat.numel()
    if static:
        top = flat.topk(min(points, n_in)).indices.sort().values   # in block order, as nonzero gives them
    else:
        cut = flat.kthvalue(n_in - points + 1).values if points < n_in else flat.new_tensor(0.0)
        top = (flat >= cut).nonzero()[:, 0]
    lin = arg.index_select(0, top)
    yi = lin // wi
    xi = lin - yi * wi
    xn = (xi.to(torch.float32) + (c0 - (w - 1) / 2.0)) / s
    yn = (yi.to(torch.float32) + (r0 - (h - 1) / 2.0)) / s
    tx = dx.view(-1).index_select(0, lin).mul_(0.5 * s)
    ty = dy.view(-1).index_select(0, lin).mul_(0.5 * s)
    proj = tx * xn + ty * yn
    sd = torch.stack([tx * xn, tx * yn, tx, ty * xn, ty * yn, ty, -proj * xn, -proj * yn], 0)
    values = img.reshape(-1).index_select(0, (yi + r0) * w + (xi + c0))
    return PhotometricTemplate(level, (w, h), torch.stack([xn, yn, torch.ones_like(xn)], 0), values, sd,
                               norm_from_full, grid_from_norm)


def _warp_from_params(dp: np.ndarray) -> np.ndarray:
    return np.array([[1.0 + dp[0], dp[1], dp[2]], [dp[3], 1.0 + dp[4], dp[5]], [dp[6], dp[7], 1.0]])


def _corner_motion(D: np.ndarray, half_w: float, half_h: float) -> float:
    """Largest displacement of the normalised frame corners under D, in normalised units."""
    c = np.array([[-half_w, -half_h, 1.0], [half_w, -half_h, 1.0], [half_w, half_h, 1.0], [-half_w, half_h, 1.0]])
    m = c @ D.T
    return float(np.abs(m[:, :2] / m[:, 2:3] - c[:, :2]).max())


def refine_photometric(
    image_pyramid: list[torch.Tensor],
    templates: list[PhotometricTemplate],
    image_H_template: np.ndarray,
    opts: PhotometricOptions,
) -> PhotometricResult:
    """Refine image_H_template (3, 3) float64 by inverse-compositional LK, coarse to fine.

    image_pyramid: levels of the image frame (1, 1, h_l, w_l); templates: of the template frame
    (same size), coarse to fine (as make_template built them for opts.levels).
    """
    H = np.asarray(image_H_template, dtype=np.float64)
    H = H / H[2, 2]
    total = 0
    rms = float('nan')
    converged = False
    valid_fraction = 0.0
    cov = None
    for tpl in templates:
        img = image_pyramid[tpl.level]
        dev = img.device
        M = tpl.norm_from_full
        Hn = M @ H @ np.linalg.inv(M)
        w, h = tpl.size
        s = max(w, h) / 2.0
        half_w, half_h = (w - 1) / (2.0 * s), (h - 1) / (2.0 * s)
        lim = 1.0 - 2.0 / max(w, h)
        sd, tv = tpl.sd, tpl.values
        xn_rows = tpl.xn.T                                                                # (P, 3) view
        weights = torch.ones_like(tv)
        converged = False
        for _ in range(opts.max_iterations):
            total += 1
            C = tpl.grid_from_norm @ Hn
            g = xn_rows @ torch.from_numpy(C.T.astype(np.float32)).to(dev)               # (P, 3)
            grid = g[:, :2] / g[:, 2:]                                                    # (P, 2), contiguous
            inside = grid.abs().amax(1) <= lim
            iw = F.grid_sample(img, grid.view(1, 1, -1, 2), mode='bilinear', padding_mode='border',
                               align_corners=True).view(-1)
            # Gain and bias of the warped image (least squares, current weights), then the residual.
            wv = weights * inside
            sw = wv.sum().clamp_min(1e-6)
            mi = torch.dot(wv, iw) / sw
            mt = torch.dot(wv, tv) / sw
            di = iw - mi
            wdi = wv * di
            gain = (torch.dot(wdi, tv) / torch.dot(wdi, di).clamp_min(1e-12)).clamp(0.2, 5.0)
            e = torch.addcmul(mt - tv, gain, di)
            e2 = e * e
            resid2 = torch.dot(wv, e2) / sw  # weighted residual variance: the covariance's and the reported RMS's
            if opts.loss == 'tukey':
                ae = e[::_MAD_STRIDE].abs()[inside[::_MAD_STRIDE]]  # a subsample: the median is the cost
                scale2 = (1.4826 * ae.median()) ** 2 if ae.numel() >= 16 else resid2
                u2 = e2 / (opts.tukey_c**2 * scale2.clamp_min(1e-12))
                weights = (1.0 - u2).clamp_min(0.0) ** 2
            else:
                # Huber IRLS weights at the weighted RMS scale of the residuals.
                scale2 = resid2
                weights = torch.rsqrt(e2 / (opts.huber_k**2 * scale2.clamp_min(1e-12))).clamp_max_(1.0)
            wv = weights * inside
            sdw = sd * wv
            # J^T W J and J^T W e in one transfer, solved on the host (8 x 8: a LAPACK call costs less
            # than a torch one here, and the step needs the host anyway)
            normal = torch.cat((sdw @ sd.T, (sdw @ e)[:, None]), 1).cpu().numpy().astype(np.float64)
            hess = normal[:, :8]
            try:
                dp = np.linalg.solve(hess, normal[:, 8])
            except np.linalg.LinAlgError:
                break
            if not np.all(np.isfinite(dp)):
                break
            D = _warp_from_params(dp)
            Hn = Hn @ np.linalg.inv(D)
            Hn = Hn / Hn[2, 2]
            if _corner_motion(D, half_w, half_h) * s < opts.tol_px:
                converged = True
                break
        rms = float(torch.sqrt(resid2))
        valid_fraction = float(inside.float().mean())
        H = np.linalg.inv(M) @ Hn @ M
        H = H / H[2, 2]
        cov = _gauss_newton_covariance(hess, float(resid2), Hn, M)
    return PhotometricResult(H, total, rms, converged, valid_fraction, cov)
