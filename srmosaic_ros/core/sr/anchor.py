"""Anchoring an SR tile to the frame the mosaic shows there (one back-projection step).

The MAP estimate x fits all the tile's frames at once; where they differ from one another by more
than the model allows (parallax of 3-D ground, a car that moved, compression), it is a compromise
that matches none of them, while the best-view mosaic around the tile shows one frame, the
reference (the frame whose centre is nearest the tile's). Anchoring adds back what the reference
sees and x does not predict, upsampled onto the HR grid:

    x_a = x + U_ref (y_ref - M D B W_ref x),

U_ref the bicubic interpolation from the reference's LR window onto the HR tile (Irani and Peleg's
back-projection, one step, for one frame), the residual soft-thresholded at twice the frames' noise
std first: what the reference sees and the estimate misses is large and local (an object, an edge
seen from elsewhere); its noise is small everywhere, and adding it back would undo the averaging
that the fusion did. When the residual's RMS is several times the noise, it is mostly structure
(compression and chroma noise of real video, spatially correlated and below the threshold per
pixel), and the threshold is scaled by the share of its power the noise accounts for
(:func:`structure_threshold`). Optionally (``compression``) it is scaled down also by how much
neighbouring residual pixels correlate: white sensor noise does not, what compression leaves does,
so the reference's compression is taken back whole and the tile reproduces the reference frame as
it was recorded, artefacts included, rather than the ground (which is what a check against the
recorded originals rewards, and a check against the true ground charges: bench/sr_sim_video.py).
``D B W_ref x_a`` then reproduces the reference in the band its LR pixels carry, above the
threshold (up to the interpolation's own blur), and the tile keeps the detail above that band that
only the fusion of several frames recovers. The tile thereby agrees with the mosaic
around it: the same moving objects, the same side of a building, no seam at its border.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from .observation import FrameStack
from .operators import lr_H_hr

__all__ = ['RHO_STRUCTURE', 'anchor_to_frame', 'neighbour_correlation', 'reference_on_hr', 'structure_threshold']

#: Neighbour correlation of the reference's residual at which none of it is taken for noise
#: (:func:`structure_threshold`).
RHO_STRUCTURE = 0.15


def anchor_to_frame(x: torch.Tensor, y: torch.Tensor, stack: FrameStack, k: int, factor: int, *,
                    threshold: float = 0.0, noise: float = 0.0, compression: bool = False) -> tuple[torch.Tensor, float]:
    """Back-project frame ``k``'s residual onto the HR estimate.

    x: (1, C, H s, W s) HR estimate on the stack's tile grid; y: (K, C, h, w) the observations the
    estimate was solved against (masked; C as ``x``); stack: the tile's frames; k: position of the
    reference in the stack; factor: s; threshold: the residual is shrunk towards 0 by this much
    (intensity; sign(r) max(|r| - threshold, 0)), scaled by :func:`structure_threshold` when the
    frames' ``noise`` std is given, with the residual's neighbour correlation when ``compression``.

    Returns ``(x_a (1, C, H s, W s), rms)``: the anchored estimate and the RMS of the reference's
    residual before anchoring (intensity units, over its observed pixels). HR pixels whose bicubic
    support reaches an unobserved reference pixel are left as they are.
    """
    pred = stack.operator.apply(x)[k:k + 1]
    mask = stack.mask[k:k + 1]
    r = (y[k:k + 1] - pred) * mask
    observed = float(mask.sum()) * r.shape[1]
    rms = float(torch.sqrt((r.double() ** 2).sum() / max(observed, 1.0)))
    if threshold > 0:
        t = structure_threshold(threshold, noise, rms, neighbour_correlation(r, mask) if compression else 0.0)
        r = torch.sign(r) * (r.abs() - t).clamp_min(0.0)
    grid = _hr_grid(stack, k, factor, x.shape[-2:], x.dtype)
    up = F.grid_sample(r.to(x.dtype), grid, mode='bicubic', padding_mode='zeros', align_corners=True)
    return x + up * _valid_5x5(mask, grid), rms


def reference_on_hr(stack: FrameStack, k: int, factor: int, hr_shape: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Frame ``k``'s own LR pixels (all channels) sampled bicubically onto the HR tile grid.

    Returns ``(image (1, C, H s, W s), valid (1, 1, H s, W s) bool)``: valid where the 5x5 LR pixels
    around the nearest one are real frame pixels. The colour an anchored luminance tile takes
    (core/sr/reconstruct.py): the frame the tile is anchored to, not the frames' average.
    """
    crops = stack.crops[k:k + 1]
    grid = _hr_grid(stack, k, factor, hr_shape, crops.dtype)
    img = F.grid_sample(crops, grid, mode='bicubic', padding_mode='border', align_corners=True).clamp(0, 1)
    return img, _valid_5x5(stack.in_frame[k:k + 1], grid)


def _hr_grid(stack: FrameStack, k: int, factor: int, hr_shape: tuple[int, int], dtype: torch.dtype) -> torch.Tensor:
    """(1, H s, W s, 2) grid_sample grid (align_corners=True) of the HR tile pixels in frame ``k``'s LR window."""
    hc, wc = stack.crops.shape[-2:]
    hs, ws = (int(v) for v in hr_shape)
    # HR tile pixel -> LR tile point -> LR window point, normalised for grid_sample(align_corners=True)
    norm_H_window = np.array([[2.0 / max(wc - 1, 1), 0.0, -1.0], [0.0, 2.0 / max(hc - 1, 1), -1.0], [0.0, 0.0, 1.0]])
    m = norm_H_window @ np.linalg.inv(stack.tile_H_windows[k]) @ lr_H_hr(factor)
    vs, us = np.mgrid[0:hs, 0:ws].astype(np.float64)
    q = m @ np.stack([us.ravel(), vs.ravel(), np.ones(us.size)])
    return torch.as_tensor((q[:2] / q[2]).T.reshape(1, hs, ws, 2), dtype=dtype, device=stack.crops.device)


def _valid_5x5(mask: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Bicubic reads a 4x4 neighbourhood: HR pixels whose nearest LR pixel has its 5x5 in ``mask`` (1, 1, h, w)."""
    observed_5x5 = F.max_pool2d(1.0 - mask.to(grid.dtype), 5, stride=1, padding=2) < 0.5
    return F.grid_sample(observed_5x5.to(grid.dtype), grid, mode='nearest', padding_mode='zeros',
                         align_corners=True) > 0.5


def structure_threshold(threshold: float, noise: float, rms: float, rho: float = 0.0) -> float:
    """The shrinkage threshold for a residual of RMS ``rms`` and neighbour correlation ``rho`` when
    the frames' noise std is ``noise``: ``threshold * min(1, (noise / rms)^2) * max(0, 1 - rho / RHO_STRUCTURE)``.

    A residual at the noise level is noise, and the full threshold keeps it out; one several times
    the noise is structure the reference sees and the estimate does not (compression, colour,
    parallax on real footage), which a threshold of noise stds would cut, the more so the more of
    it is spread below the threshold. The first factor is the share of the residual's power the
    noise accounts for. The second (rho > 0 given by the ``compression`` option): sensor noise is
    white (neighbouring residual pixels uncorrelated), while what compression leaves in a frame is
    spatially correlated and belongs to the recorded frame as much as its detail does, so a
    correlated residual is taken back whole; it does not belong to the ground.
    """
    t = threshold
    if noise > 0 and rms > noise:
        t *= (noise / rms) ** 2
    return t * max(0.0, 1.0 - max(rho, 0.0) / RHO_STRUCTURE)


def neighbour_correlation(r: torch.Tensor, mask: torch.Tensor) -> float:
    """Correlation of horizontally neighbouring residual pixels, r (1, C, h, w), over pixel pairs
    that ``mask`` (1, 1 or C, h, w) observes both of; 0 with fewer than 16 pairs or no variance."""
    both = (mask[..., :, :-1] * mask[..., :, 1:]).double().expand(r[..., :, :-1].shape)
    n = float(both.sum())
    if n < 16:
        return 0.0
    a, b = r[..., :, :-1].double(), r[..., :, 1:].double()
    a = a - (a * both).sum() / n
    b = b - (b * both).sum() / n
    va, vb = float((a * a * both).sum()), float((b * b * both).sum())
    return float((a * b * both).sum()) / math.sqrt(va * vb) if va > 0 and vb > 0 else 0.0
