"""Which frames of a tile see the same ground: the gate before super-resolution.

The observation model (5.1) holds only where the frames agree up to their sub-pixel offsets, blur
and noise. Where a homography cannot describe the scene (trees and roofs seen from stills tens of
metres apart, a local misregistration, moving water, cars), the warped frames disagree by much
more: on the brighton stills (7 s apart at 40 m) whole tiles of tree canopy correlate at 0.0
between frames, and the MAP solution there is an average of different pictures, blurrier than the
single frame the mosaic shows. The relative outlier weights (``robust_frame_weights``) cannot see
it when every frame disagrees with every other.

The test: every pair of frames warped into the LR tile (luminance) is compared by its normalised
cross-correlation (NCC) over the pixels both cover. Two noisy copies of one picture correlate at

    rho_ij = sqrt(s_i^2 s_j^2 / ((s_i^2 + n^2) (s_j^2 + n^2))),    s^2 = var - n^2,

n the noise std (Immerkaer's estimator on the frames' windows; texture inflates it, which only
lowers the bar). A pair is consistent when NCC_ij >= ``threshold`` * rho_ij. The frames kept are
a largest set of mutually consistent frames (greedy, frames with the most consistent partners
first), seeded by the tile's reference frame when that agrees with any other: the frame whose
centre is nearest the tile's, which the mosaic shows there, so that the SR tile agrees with the
mosaic around it. A reference that agrees with no other frame is itself the odd one out (a
misregistered frame): the others' set is used, and the figures say so. For scale, on the tiles
that `process --sr` plans aligned frames correlate at 0.95 to 1.00 (less on flat tiles, where the
noise bound is lower too); tree canopy on the brighton stills near 0, misregistered parts 0.3 to 0.7.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

__all__ = ['consistent_frames', 'noise_sigma']

# Immerkaer (1996): the 3x3 mask that cancels planes and quadrics; E|I * M| = sqrt(2/pi) * 6 sigma.
_IMMERKAER = torch.tensor([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])


def noise_sigma(images: torch.Tensor, valid: torch.Tensor | None = None) -> float:
    """Noise std (intensity units of ``images``) of (K, 1, H, W) images, Immerkaer's estimator.

    valid: optional (K, 1, H, W) mask of real pixels; the mask response is used where all nine
    pixels are valid. Returns the median over the K images (0 when none has 3x3 valid pixels).
    """
    mask = _IMMERKAER.to(images.device, images.dtype).view(1, 1, 3, 3)
    resp = F.conv2d(images, mask).abs()
    if valid is None:
        ok = torch.ones_like(resp)
    else:
        ok = (F.avg_pool2d(valid.to(images.dtype), 3, stride=1) > 0.999).to(images.dtype)
    n = ok.sum(dim=(1, 2, 3))
    sig = math.sqrt(math.pi / 2.0) / 6.0 * (resp * ok).sum(dim=(1, 2, 3)) / n.clamp_min(1)
    sig = sig[n > 0]
    return float(sig.median()) if sig.numel() else 0.0


def pairwise_ncc(images: torch.Tensor, covered: torch.Tensor, *, min_overlap: int = 64,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NCC of every pair of (K, 1, H, W) images over the pixels both cover.

    Returns ``(ncc (K, K), var (K, K), overlap (K, K))``: ``var[i, j]`` is the variance of image i
    on the pair's common pixels; pairs with fewer than ``min_overlap`` common pixels have NaN NCC.
    """
    k = images.shape[0]
    x = images.reshape(k, -1).double()
    c = (covered.reshape(k, -1) > 0).double()
    cc = c @ c.T  # common pixel counts
    sx = (x * c) @ c.T  # sum of x_i over the pixels common with j
    sxx = (x * x * c) @ c.T
    sxy = (x * c) @ (x * c).T
    n = cc.clamp_min(1)
    mean_i = sx / n
    mean_j = mean_i.T
    var_i = (sxx / n - mean_i**2).clamp_min(0)
    var_j = var_i.T
    cov = sxy / n - mean_i * mean_j
    ncc = cov / torch.sqrt(var_i * var_j).clamp_min(1e-20)
    ncc = torch.where(cc >= min_overlap, ncc, torch.full_like(ncc, math.nan))
    return ncc.cpu().numpy(), var_i.cpu().numpy(), cc.cpu().numpy()


def consistent_frames(images: torch.Tensor, covered: torch.Tensor, *, threshold: float = 0.8,
                      noise: float | None = None, min_overlap: int = 64,
                      reference: int | None = None) -> tuple[np.ndarray, dict[str, float]]:
    """The frames that see the same picture: ``(keep (K,) bool, figures)``.

    images: (K, 1, H, W) frames warped into the LR tile (luminance, [0, 1]); covered: (K, 1, H, W).
    threshold: fraction of the noise-limited NCC rho_ij (module docstring) a pair must reach.
    noise: the noise std, or None to estimate it from ``images``.
    Pairs without ``min_overlap`` common pixels count as consistent (nothing to compare).
    reference: a frame the set should contain (the one the mosaic shows on the tile, so that the SR
        tile agrees with its surroundings): it seeds the set when it agrees with at least one other
        frame; otherwise, and for None, the frame with the most consistent partners does
        (``figures['reference_kept']`` says which happened).
    figures: 'noise' (std), 'ncc_min' / 'ncc_median' (over compared pairs), 'kept', 'frames'.
    """
    k = images.shape[0]
    figures: dict[str, float] = {'frames': float(k), 'kept': float(k)}
    if k < 2:
        return np.ones(k, dtype=bool), figures
    sigma = noise_sigma(images, covered) if noise is None else float(noise)
    ncc, var, _ = pairwise_ncc(images, covered, min_overlap=min_overlap)
    n2 = sigma * sigma
    s_i = np.clip(var - n2, 0.0, None)
    s_j = s_i.T
    rho = np.sqrt(s_i * s_j / np.maximum((s_i + n2) * (s_j + n2), 1e-30))
    off = ~np.eye(k, dtype=bool)
    compared = off & np.isfinite(ncc)
    ok = np.where(compared, ncc >= threshold * rho, True)
    order = sorted(range(k), key=lambda i: (-int(ok[i].sum()), -float(np.nanmean(np.where(compared[i], ncc[i], np.nan)))
                                            if compared[i].any() else 0.0))
    if reference is not None and any(ok[reference, j] for j in np.flatnonzero(compared[reference])):
        order.remove(reference)
        order.insert(0, reference)
    keep = np.zeros(k, dtype=bool)
    for i in order:
        if all(ok[i, j] for j in np.flatnonzero(keep)):
            keep[i] = True
    vals = ncc[compared]
    figures.update({'noise': sigma, 'kept': float(keep.sum()),
                    'reference_kept': float(reference is None or keep[reference]),
                    'ncc_min': float(vals.min()) if vals.size else math.nan,
                    'ncc_median': float(np.median(vals)) if vals.size else math.nan})
    return keep, figures
