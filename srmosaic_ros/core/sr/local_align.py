"""Each frame brought onto the reference frame on the tile itself, before the solve.

Geometry: the mosaic's homographies are right on average over a frame; on a 64-px tile of real
footage they are off by a fraction of a pixel to a pixel (3-D ground, lens distortion, rolling
shutter, the chain's drift), and (5.1) reads such an error as detail: the fusion of frames that do
not superpose blurs or doubles edges, while the reference frame alone would not. Each frame warped
into the LR tile is aligned to the reference warped there by the ECC criterion (Evangelidis and
Psarakis 2008, OpenCV's ``findTransformECC``) with a translation or an affine motion, over the
pixels both cover, then again without the pixels where they still disagree (an object that moved).
A correction is kept only when it is small (``max_shift`` LR pixels at the tile's corners: a larger
one is a mismatch, not a refinement) and the aligned frame correlates with the reference;
otherwise the frame keeps its homography.

Exposure (:func:`photometric_to_reference`): a gain and an offset per frame and channel that give
it the reference's mean and std on the tile, again without the pixels that disagree.
"""
from __future__ import annotations

import cv2
import numpy as np
import torch

from .modes import ALIGN_MODES

__all__ = ['ALIGN_MODES', 'align_to_reference', 'photometric_to_reference']

_MOTION = {'translation': cv2.MOTION_TRANSLATION, 'affine': cv2.MOTION_AFFINE}


def align_to_reference(warped: torch.Tensor, covered: torch.Tensor, ref: int, *, mode: str = 'affine',
                       max_shift: float = 1.5, min_correlation: float = 0.6, iterations: int = 30) -> np.ndarray:
    """Corrections (K, 3, 3) that move each frame's LR tile coordinates onto the reference's.

    warped: (K, 1, H, W) the frames' luminance warped into the LR tile, [0, 1]; covered: (K, 1, H, W)
    1 where the frame covers; ref: the reference's position. Returns C_k such that
    ``C_k @ tile_H_frame_k`` places frame k where it superposes the reference (identity for the
    reference, for frames whose alignment fails and for rejected corrections: ECC's correlation
    below ``min_correlation`` or a corner moved by more than ``max_shift`` LR pixels).
    """
    if mode not in ALIGN_MODES:
        msg = f'local alignment mode must be one of {ALIGN_MODES}, got {mode!r}.'
        raise ValueError(msg)
    k_frames = warped.shape[0]
    out = np.tile(np.eye(3), (k_frames, 1, 1))
    if mode == 'off' or k_frames < 2:
        return out
    imgs = warped[:, 0].detach().float().cpu().numpy()
    cov = covered[:, 0].detach().cpu().numpy() > 0
    h, w = imgs.shape[-2:]
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [w - 1, h - 1, 1], [0, h - 1, 1]], dtype=np.float64).T
    template = imgs[ref]
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, iterations, 1e-4)
    for k in range(k_frames):
        if k == ref:
            continue
        both = cov[k] & cov[ref]
        if both.sum() < 0.25 * h * w:
            continue
        warp = np.eye(2, 3, dtype=np.float32)
        try:
            rho, warp = cv2.findTransformECC(template, imgs[k], warp, _MOTION[mode], criteria,
                                             both.astype(np.uint8), 3)
        except cv2.error:  # no convergence (flat tile, too little overlap): keep the homography
            continue
        inliers = _agreeing(template, imgs[k], warp, both)
        if inliers is not None:  # a car or a person moved: align on the rest (ECC is least squares)
            try:
                rho, warp = cv2.findTransformECC(template, imgs[k], warp, _MOTION[mode], criteria,
                                                 inliers.astype(np.uint8), 3)
            except cv2.error:
                continue
        fwd = np.vstack([warp.astype(np.float64), [0.0, 0.0, 1.0]])  # reference point -> frame's point
        moved = fwd @ corners
        if rho < min_correlation or np.abs(moved[:2] - corners[:2]).max() > max_shift:
            continue
        out[k] = np.linalg.inv(fwd)
    return out


def _agreeing(template: np.ndarray, img: np.ndarray, warp: np.ndarray, mask: np.ndarray,
              k: float = 4.0, floor: float = 1.0) -> np.ndarray | None:
    """Pixels of ``mask`` where the aligned frame agrees with the template: the residual of the two
    standardised images within ``k`` robust stds and within ``floor`` (a scene std: what an object
    that moved changes; interpolation and noise change far less), outliers grown by one pixel. None
    when all agree."""
    h, w = template.shape
    aligned = cv2.warpAffine(img, warp, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    a, t = aligned[mask], template[mask]
    r = (a - a.mean()) / max(float(a.std()), 1e-6) - (t - t.mean()) / max(float(t.std()), 1e-6)
    med = float(np.median(r))
    sigma = 1.4826 * float(np.median(np.abs(r - med)))
    bad = np.zeros_like(mask)
    bad[mask] = np.abs(r - med) > max(k * sigma, floor)
    if not bad.any():
        return None
    bad = cv2.dilate(bad.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    keep = mask & ~bad
    return keep if keep.sum() >= 0.25 * mask.sum() else None




def photometric_to_reference(warped: torch.Tensor, covered: torch.Tensor, ref: int, *, max_gain: float = 1.5,
                             min_change: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Per frame and channel gain and offset that map each frame's intensities onto the reference's.

    warped: (K, C, H, W) the frames warped into the LR tile; covered: (K, 1, H, W). ``ref = a y_k + b``
    matching the means and stds over the pixels both cover: exposure and white balance change between the
    stills of a survey, and (5.1) has no term for them, so the solve would average the exposures and
    the tile would not match the frame the mosaic shows. Returns ``(a, b)``, each (K, C, 1, 1); a
    frame sharing fewer than 16 pixels with the reference, or whose gain leaves
    [1 / max_gain, max_gain], keeps a = 1, b = 0, and so does a channel whose correction changes
    the frame by less than ``min_change`` RMS over the tile (intensity: the noise, where a frame
    exposed as the reference only shows a reference that is misregistered or sees other content).
    """
    k_frames, c = warped.shape[:2]
    both = ((covered * covered[ref:ref + 1]) > 0).to(warped.dtype)   # (K, 1, H, W)
    a, b, ok = _gain_offset(warped, both, ref, max_gain)
    # a car or a person that moved pulls the moments: refit without the pixels the first fit
    # leaves more than 3 robust stds and 5 grey levels off (luminance of the residual, per frame)
    res = (warped[ref:ref + 1] - (a * warped + b)).mean(dim=1, keepdim=True)     # (K, 1, H, W)
    keep = both.clone()
    for k in range(k_frames):
        m = both[k, 0] > 0
        if k == ref or not bool(ok[k].all()) or int(m.sum()) < 16:
            continue
        r = res[k, 0][m]
        med = r.median()
        sigma = 1.4826 * (r - med).abs().median()
        keep[k, 0][m] = ((r - med).abs() <= torch.maximum(3.0 * sigma, r.new_tensor(5.0 / 255))).to(warped.dtype)
    a, b, _ = _gain_offset(warped, keep, ref, max_gain)
    if min_change > 0:
        n = both.sum(dim=(1, 2, 3)).clamp_min(1)[:, None, None, None]
        change = torch.sqrt((((a - 1.0) * warped + b) ** 2 * both).sum(dim=(2, 3), keepdim=True) / n)
        small = change < min_change
        a = torch.where(small, torch.ones_like(a), a)
        b = torch.where(small, torch.zeros_like(b), b)
    return a, b


def _gain_offset(warped: torch.Tensor, weights: torch.Tensor, ref: int,
                 max_gain: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``ref = a y_k + b`` per frame and channel over ``weights`` (K, 1, H, W) in {0, 1}, by the means and stds:
    ``(a, b)`` (K, C, 1, 1) and ``ok`` (K, C), identity where not ``ok`` and for the reference."""
    n = weights.sum(dim=(1, 2, 3))                                     # (K,)
    t = warped[ref:ref + 1]
    mean_y = (warped * weights).sum(dim=(2, 3)) / n.clamp_min(1)[:, None]
    mean_t = (t * weights).sum(dim=(2, 3)) / n.clamp_min(1)[:, None]
    dy = (warped - mean_y[..., None, None]) * weights
    dt = (t - mean_t[..., None, None]) * weights
    var_y = (dy * dy).sum(dim=(2, 3))
    # the ratio of the stds, not least squares: a residual misregistration or parallax would bias
    # the least-squares gain towards 0 (regression dilution) and flatten the frames' contrast
    gain = torch.sqrt((dt * dt).sum(dim=(2, 3)) / var_y.clamp_min(1e-12))
    ok = (n[:, None] >= 16) & (var_y > 1e-8) & (gain >= 1.0 / max_gain) & (gain <= max_gain)
    a = torch.where(ok, gain, torch.ones_like(gain))[..., None, None].clone()
    b = torch.where(ok, mean_t - gain * mean_y, torch.zeros_like(gain))[..., None, None].clone()
    a[ref], b[ref] = 1.0, 0.0
    ok[ref] = True
    return a, b, ok
