"""Keypoint description of the torch registrar: SIFT-like orientation and RootSIFT-like descriptors.

Computed on the Gaussian level of each keypoint's scale (the gradient buffer of
torch_detect.ScaleSpaceCandidates): a dominant gradient orientation from a 36-bin histogram, then
4 x 4 cells x 8 orientation bins of rotated gradients on a 12 x 12 grid spanning 12 sigma,
normalised, clipped at 0.2 and square-rooted (torch_features.py's module docstring).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch
import torch.nn.functional as F

from .torch_detect import ScaleSpaceCandidates
from .torch_scale_space import cached_constant, full_from_level

__all__ = ['DESCRIPTOR_SIZE', 'KeypointSet', 'concat_keypoints', 'describe_candidates']

DESCRIPTOR_SIZE = 128
_ORI_BINS = 36
_ORI_GRID = 9            # orientation window: 9 x 9 samples ...
_ORI_SPACING = 1.0       # ... spaced by 1 sigma, Gaussian weight of 1.5 sigma (SIFT)
_ORI_WEIGHT_SIGMA = 1.5
_DESC_GRID = 12          # descriptor window: 12 x 12 samples over 4 x 4 cells of 3 sigma (SIFT)
_DESC_CELLS = 4
_DESC_BINS = 8
_DESC_CELL_SIGMAS = 3.0
_DESC_CLIP = 0.2


@dataclass
class KeypointSet:
    """Keypoints of one frame, all tensors on one device.

    xy: (N, 2) float32 (x, y) in full-resolution pixels; scale: (N,) float32 sigma of the
    keypoint in full-resolution pixels; angle: (N,) float32 dominant orientation, radians,
    measured from +x toward +y; response: (N,) float32 DoH response; descriptors: (N, 128)
    float32 unit vectors.
    """

    xy: torch.Tensor
    scale: torch.Tensor
    angle: torch.Tensor
    response: torch.Tensor
    descriptors: torch.Tensor

    def __len__(self) -> int:
        return int(self.xy.shape[0])


def _sample_tall(tall: torch.Tensor, pts: torch.Tensor, row0: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of the gradient buffer at (P, K, 2) points -> (C, P, K).

    tall: (1, C, R, W), the Gaussian levels of all octaves stacked vertically (octave o, level l
    at rows row0_o + l * h_o); row0: (K,) first row of each keypoint's level; hi: (K, 2) its
    largest (x, y). Points are clamped to their level (border padding), then offset into it, so
    one 2-D grid_sample serves every octave and level.
    """
    _, _, ht, w = tall.shape
    dev, dt = pts.device, pts.dtype
    scale = cached_constant((2.0 / (w - 1), 2.0 / (ht - 1)), dev, dt)
    shift = torch.stack([torch.zeros_like(row0), row0], -1)                            # (K, 2)
    grid = torch.minimum(pts.clamp_min(0.0), hi).add_(shift).mul_(scale).sub_(1.0)
    out = F.grid_sample(tall, grid[None], mode='bilinear', padding_mode='border', align_corners=True)
    return out[0]


@lru_cache(maxsize=8)
def _orientation_offsets(device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    r = (_ORI_GRID - 1) / 2.0
    u = (torch.arange(_ORI_GRID, dtype=torch.float32) - r) * _ORI_SPACING
    yy, xx = torch.meshgrid(u, u, indexing='ij')
    off = torch.stack([xx.reshape(-1), yy.reshape(-1)], 1)
    keep = (off**2).sum(1) <= (r * _ORI_SPACING + 0.5) ** 2
    off = off[keep]
    wgt = torch.exp(-0.5 * (off**2).sum(1) / _ORI_WEIGHT_SIGMA**2)
    return off.to(device), wgt.to(device)


@lru_cache(maxsize=8)
def _descriptor_layout(device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sample offsets (P, 2) in units of sigma; pooling (16, P): bilinear cell assignment times the
    Gaussian window (sigma = half the window), as SIFT; bin directions (8,) radians."""
    n = _DESC_GRID
    width = _DESC_CELLS * _DESC_CELL_SIGMAS          # window side in sigmas
    step = width / n
    u = (torch.arange(n, dtype=torch.float32) + 0.5) * step - 0.5 * width
    yy, xx = torch.meshgrid(u, u, indexing='ij')
    off = torch.stack([xx.reshape(-1), yy.reshape(-1)], 1)          # (P, 2)
    cell = (off + 0.5 * width) / _DESC_CELL_SIGMAS - 0.5               # cell coordinates
    centers = torch.arange(_DESC_CELLS, dtype=torch.float32)
    wx = (1.0 - (cell[:, 0:1] - centers[None]).abs()).clamp_min(0.0)  # (P, 4)
    wy = (1.0 - (cell[:, 1:2] - centers[None]).abs()).clamp_min(0.0)
    spatial = (wy[:, :, None] * wx[:, None, :]).reshape(-1, _DESC_CELLS * _DESC_CELLS)  # (P, 16) row-major cells
    gauss = torch.exp(-0.5 * (off**2).sum(1) / (0.5 * width) ** 2)
    bins = torch.arange(_DESC_BINS, dtype=torch.float32) * (2.0 * math.pi / _DESC_BINS)
    return off.to(device), (spatial * gauss[:, None]).T.contiguous().to(device), bins.to(device)


def _rotated_points(xy: torch.Tensor, off: torch.Tensor, sigma: torch.Tensor,
                    angle: torch.Tensor | None) -> torch.Tensor:
    """xy (K, 2) + sigma (K,) * R(angle) @ off (P, 2) -> (P, K, 2) (sample-major, as grid_sample wants)."""
    ox, oy = off[:, 0, None, None], off[:, 1, None, None]                      # (P, 1, 1)
    if angle is None:
        return torch.addcmul(xy[None], off[:, None, :], sigma[None, :, None])
    c, s = torch.cos(angle) * sigma, torch.sin(angle) * sigma
    col0 = torch.stack([c, s], -1)[None]                                        # R[:, 0] * sigma, (1, K, 2)
    col1 = torch.stack([-s, c], -1)[None]
    return torch.addcmul(torch.addcmul(xy[None], ox, col0), oy, col1)


def _orientation(tall: torch.Tensor, xy: torch.Tensor, sigma: torch.Tensor, row0: torch.Tensor,
                 hi: torch.Tensor) -> torch.Tensor:
    """Dominant gradient orientation (K,) radians: peak of a 36-bin histogram of gradient angles in
    a Gaussian window of 1.5 sigma (weighted by magnitude, smoothed, parabolic peak), as SIFT."""
    off, wgt = _orientation_offsets(xy.device)
    g = _sample_tall(tall, _rotated_points(xy, off, sigma, None), row0, hi).transpose(1, 2)  # (2, K, P)
    mag = torch.sqrt(g[0] * g[0] + g[1] * g[1]) * wgt
    b = torch.atan2(g[1], g[0]) * (_ORI_BINS / (2.0 * math.pi)) + _ORI_BINS   # in (0.5 B, 1.5 B]
    lo = b.floor()
    frac = b - lo
    lo_i = lo.long() % _ORI_BINS
    hist = torch.zeros(xy.shape[0], _ORI_BINS + 1, device=xy.device)
    hist.scatter_add_(1, lo_i, mag * (1.0 - frac))
    hist.scatter_add_(1, lo_i + 1, mag * frac)
    hist = hist[:, :_ORI_BINS].index_add(1, torch.zeros(1, dtype=torch.long, device=xy.device), hist[:, _ORI_BINS:])
    # Circular smoothing [1 4 6 4 1] / 16 and parabolic interpolation of the peak.
    ext = torch.cat([hist[:, -3:], hist, hist[:, :3]], 1)
    sm = (6.0 * ext[:, 2:-2] + 4.0 * (ext[:, 1:-3] + ext[:, 3:-1]) + ext[:, :-4] + ext[:, 4:]) / 16.0   # (K, B + 2)
    core = sm[:, 1:-1]
    peak = core.argmax(1, keepdim=True)
    trio = sm.gather(1, torch.cat([peak, peak + 1, peak + 2], 1))
    hm, h0, hp = trio[:, 0], trio[:, 1], trio[:, 2]
    den = hm - 2.0 * h0 + hp
    shift = 0.5 * (hm - hp) / torch.where(den < 0, den, -torch.ones_like(den))
    return (peak[:, 0].to(torch.float32) + shift.clamp(-0.5, 0.5)) * (2.0 * math.pi / _ORI_BINS)


def _descriptor(tall: torch.Tensor, xy: torch.Tensor, sigma: torch.Tensor, row0: torch.Tensor, hi: torch.Tensor,
                angle: torch.Tensor) -> torch.Tensor:
    """(K, 128) RootSIFT-like unit descriptors.

    Gradients on a 12 x 12 grid (rotated by the keypoint angle, spanning 4 x 4 cells of 3 sigma)
    are projected on 8 directions relative to the keypoint angle and half-wave rectified (the
    orientation maps of DAISY: a cosine-shaped soft binning that needs no angle computation),
    pooled into the cells with bilinear and Gaussian weights, L2-normalised, clipped at 0.2, and
    square-rooted after L1 normalisation.
    """
    off, pool, bins = _descriptor_layout(xy.device)
    k = xy.shape[0]
    g = _sample_tall(tall, _rotated_points(xy, off, sigma, angle), row0, hi)          # (2, P, K)
    # Rectified projections of the gradients on 8 directions relative to the keypoint angle.
    dirs = angle[:, None] + bins[None]                                                 # (K, 8)
    proj = torch.addcmul(g[0][..., None] * torch.cos(dirs), g[1][..., None], torch.sin(dirs)).clamp_min_(0.0)
    d = torch.matmul(pool, proj.view(proj.shape[0], k * _DESC_BINS))                     # (16, K * 8)
    d = d.view(_DESC_CELLS * _DESC_CELLS, k, _DESC_BINS).transpose(0, 1).reshape(k, DESCRIPTOR_SIZE)
    d = F.normalize(d, dim=1).clamp_max_(_DESC_CLIP)
    return torch.sqrt(F.normalize(d, p=1.0, dim=1))


def _empty_keypoints(dev: torch.device) -> KeypointSet:
    e = torch.zeros(0, device=dev)
    return KeypointSet(torch.zeros(0, 2, device=dev), e, e, e, torch.zeros(0, DESCRIPTOR_SIZE, device=dev))


def describe_candidates(cands: ScaleSpaceCandidates, start: int, stop: int) -> KeypointSet:
    """Keypoints (orientation, descriptor, full-resolution position and scale) of the candidates
    ranked start .. stop - 1, all octaves at once."""
    dev = cands.response.device
    sl = slice(start, stop)
    if cands.response[sl].numel() == 0:
        return _empty_keypoints(dev)
    oct_ = cands.octave[sl]
    sub = cands.sub_level[sl]
    kxy = cands.xy[sl]
    n_lv = cands.scales_per_octave + 2
    lev = sub.round().clamp(0, n_lv - 1)
    sigma = cands.sigma0 * torch.pow(2.0, sub / cands.scales_per_octave)     # octave pixels
    size = cands.size[oct_]                                                   # (K, 2) (w, h)
    row0 = cands.row0[oct_] + lev * size[:, 1]
    hi = size - 1.0
    ang = _orientation(cands.tall, kxy, sigma, row0, hi)
    desc = _descriptor(cands.tall, kxy, sigma, row0, hi, ang)
    f = torch.pow(2.0, oct_.to(torch.float32))                                # octave -> level pixels
    xy = full_from_level(kxy * f[:, None] + (f[:, None] - 1.0) * 0.5, cands.level)
    return KeypointSet(xy, sigma * f * float(2**cands.level), ang, cands.response[sl], desc)


def concat_keypoints(a: KeypointSet, b: KeypointSet) -> KeypointSet:
    """Keypoints of a followed by those of b."""
    return KeypointSet(*(torch.cat([getattr(a, f), getattr(b, f)]) for f in
                         ('xy', 'scale', 'angle', 'response', 'descriptors')))


