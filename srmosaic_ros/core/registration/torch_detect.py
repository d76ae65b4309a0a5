"""Keypoint detection of the torch registrar: scale-normalised DoH maxima of a Gaussian scale space.

DoH = sigma**4 (Lxx Lyy - Lxy**2) on each level of each octave, its 3 x 3 x 3 maxima above the
response threshold, refined to sub-pixel and sub-level by a quadratic fit (torch_features.py's
module docstring). Positions in the detection level's octave pixels; torch_describe.py turns the
candidates into keypoints.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from .torch_feature_options import FeatureOptions
from .torch_scale_space import _gaussian_stack, _gradients_into, _on_cpu32, cached_constant, gaussian_blur, half_size

__all__ = ['ScaleSpaceCandidates', 'detect']

_SIGMA_IN = 0.5          # blur assumed in the detection-level image (pixel integration)
_RECT3 = np.ones((3, 3), np.uint8)


def _nms_max(resp: torch.Tensor) -> torch.Tensor:
    """Largest value of the 3 x 3 x 3 neighbourhood of each interior point of resp (S, H, W)
    -> (S - 2, H - 2, W - 2)."""
    scale = torch.maximum(torch.maximum(resp[:-2], resp[1:-1]), resp[2:])      # (S - 2, H, W), contiguous
    if _on_cpu32(resp):
        n, h, w = scale.shape
        # One 3 x 3 dilation of the levels stacked vertically: the rows where two levels meet
        # mix them, but those are border rows of a level, cropped below.
        d = cv2.dilate(scale.numpy().reshape(n * h, w), _RECT3)
        return torch.from_numpy(d).view(n, h, w)[:, 1:-1, 1:-1]
    return _max3(_max3(scale, 2), 1)


def _max3(a: torch.Tensor, dim: int) -> torch.Tensor:
    """Running max over 3 neighbours along dim (size shrinks by 2)."""
    n = a.shape[dim]
    return torch.maximum(torch.maximum(a.narrow(dim, 0, n - 2), a.narrow(dim, 1, n - 2)), a.narrow(dim, 2, n - 2))


def _is_max(resp: torch.Tensor, threshold: float, border: int) -> torch.Tensor:
    """(S, H - 4, W - 4) bool: resp (S + 2, H - 2, W - 2) at offset (1, 1, 1) is its 3 x 3 x 3
    neighbourhood's maximum and above threshold, and at least border from the edges of the mask."""
    centre = resp[1:-1, 1:-1, 1:-1]
    is_max = (centre >= _nms_max(resp)) & (centre > threshold)
    if border:
        is_max[:, :border, :] = False
        is_max[:, -border:, :] = False
        is_max[:, :, :border] = False
        is_max[:, :, -border:] = False
    return is_max


def _maxima_cpu(resp: torch.Tensor, threshold: float, border: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The points of _is_max (same order) by OpenCV: (s, y, x) long, coordinates in resp (S + 2, H, W),
    at least border (>= 1) from its spatial edges."""
    scale = torch.maximum(torch.maximum(resp[:-2], resp[1:-1]), resp[2:])       # (S, H, W), contiguous
    n, h, w = scale.shape
    a = scale.numpy().reshape(n * h, w)
    # centre > threshold  <=>  centre >= the next float32 above it: folded into the maximum.
    np.maximum(a, np.nextafter(np.float32(threshold), np.float32(np.inf)), out=a)
    # 3 x 3 dilation of the levels stacked vertically: rows where two levels meet mix them, but
    # they lie in the cleared border.
    mask = cv2.compare(resp[1:-1].numpy().reshape(n * h, w), cv2.dilate(a, _RECT3), cv2.CMP_GE)
    m = mask.reshape(n, h, w)
    m[:, :border] = 0
    m[:, h - border:] = 0
    m[:, :, :border] = 0
    m[:, :, w - border:] = 0
    pts = cv2.findNonZero(mask)                                   # (K, 1, 2) int32 (x, y), row-major
    if pts is None:
        e = torch.zeros(0, dtype=torch.long)
        return e, e, e
    pts = torch.from_numpy(pts.reshape(-1, 2)).long()
    row = pts[:, 1]
    return row // h + 1, row % h, pts[:, 0]


@dataclass
class _Octave:
    index: int                # octave number o (octave image = detection level / 2**o)
    xy: torch.Tensor          # (K, 2) refined (x, y), octave pixels
    sub_s: torch.Tensor       # (K,) refined level index (float)
    response: torch.Tensor    # (K,)


def _detect_octave(levels: torch.Tensor, sigmas: list[float], index: int, opts: FeatureOptions,
                   static_k: int | None = None) -> _Octave:
    """Scale-normalised DoH maxima of one octave; levels: (S + 2, H, W) Gaussian stack.

    static_k: None selects every maximum (``nonzero``: the count is data-dependent, a host
    synchronisation on a GPU); an int selects the static_k strongest positions of the masked
    response instead (``topk``: fixed shapes, no synchronisation, what a CUDA graph can capture),
    the positions that are no maximum carrying response -inf (they sort last).
    """
    dev = levels.device
    n_s, h, w = levels.shape
    sig = cached_constant(tuple(sigmas), dev)
    c = levels[:, 1:-1, 1:-1]
    lxx = torch.add(levels[:, 1:-1, 2:], levels[:, 1:-1, :-2]).sub_(c, alpha=2.0)
    lyy = torch.add(levels[:, 2:, 1:-1], levels[:, :-2, 1:-1]).sub_(c, alpha=2.0)
    lxy4 = torch.sub(levels[:, 2:, 2:], levels[:, 2:, :-2]).sub_(levels[:, :-2, 2:]).add_(levels[:, :-2, :-2])
    # (S+2, H-2, W-2), offset 1 from the level pixels.
    resp = lxx.mul_(lyy).addcmul_(lxy4, lxy4, value=-1.0 / 16.0).mul_((sig**4).view(-1, 1, 1))
    b = max(opts.border_px - 2, 0)
    hr, wr = h - 2, w - 2
    invalid = None
    if static_k is None and _on_cpu32(resp):
        s, y, x = _maxima_cpu(resp, opts.response_threshold, b + 1)
        if s.numel() == 0:
            z = torch.zeros(0, device=dev)
            return _Octave(index, torch.zeros(0, 2, device=dev), z, z)
    elif static_k is None:
        is_max = _is_max(resp, opts.response_threshold, b)
        idx = is_max.nonzero()  # (K, 3): s-1, y-2, x-2
        if idx.shape[0] == 0:
            z = torch.zeros(0, device=dev)
            return _Octave(index, torch.zeros(0, 2, device=dev), z, z)
        s = idx[:, 0] + 1
        y = idx[:, 1] + 1     # in resp coordinates (offset 1)
        x = idx[:, 2] + 1
    else:
        is_max = _is_max(resp, opts.response_threshold, b)
        centre = resp[1:-1, 1:-1, 1:-1]
        masked = torch.where(is_max, centre, torch.full_like(centre, -math.inf)).view(-1)
        top = masked.topk(min(static_k, masked.numel()))
        invalid = torch.isinf(top.values)
        hc, wc = h - 4, w - 4     # is_max is (S, h - 4, w - 4)
        s = top.indices // (hc * wc) + 1
        y = (top.indices // wc) % hc + 1
        x = top.indices % wc + 1
    flat = resp.reshape(-1)
    base = (s * hr + y) * wr + x
    offs = cached_constant((0, 1, -1, wr, -wr, wr + 1, wr - 1, -wr + 1, -wr - 1, hr * wr, -hr * wr), dev, torch.long)
    v = flat.index_select(0, (base[:, None] + offs[None, :]).view(-1)).view(-1, offs.numel())   # (K, 11)
    v0 = v[:, 0]
    dx = 0.5 * (v[:, 1] - v[:, 2])
    dy = 0.5 * (v[:, 3] - v[:, 4])
    dxx = v[:, 1] + v[:, 2] - 2.0 * v0
    dyy = v[:, 3] + v[:, 4] - 2.0 * v0
    dxy = 0.25 * (v[:, 5] - v[:, 6] - v[:, 7] + v[:, 8])
    ds = 0.5 * (v[:, 9] - v[:, 10])
    dss = v[:, 9] + v[:, 10] - 2.0 * v0
    det = dxx * dyy - dxy * dxy
    good = det > 1e-12 * v0.abs().clamp_min(1e-12) ** 2
    safe = torch.where(good, det, torch.ones_like(det))
    ox = torch.where(good, -(dyy * dx - dxy * dy) / safe, torch.zeros_like(det)).clamp(-0.5, 0.5)
    oy = torch.where(good, -(dxx * dy - dxy * dx) / safe, torch.zeros_like(det)).clamp(-0.5, 0.5)
    os_ = torch.where(dss < 0, -ds / torch.where(dss < 0, dss, -torch.ones_like(dss)),
                      torch.zeros_like(dss)).clamp(-0.5, 0.5)
    xy = torch.stack([x.float() + 1.0 + ox, y.float() + 1.0 + oy], dim=1)
    peak = v0 + 0.5 * (dx * ox + dy * oy)
    if invalid is not None:
        peak = peak.masked_fill(invalid, -math.inf)
    return _Octave(index, xy, s.float() + os_, peak)


@dataclass
class ScaleSpaceCandidates:
    """All DoH maxima of a frame, strongest first, kept with the gradient buffer so that more of
    them can be described later (describe_candidates) without recomputing the scale space.

    level: detection pyramid level; xy: (N, 2) positions in their octave's pixels; sub_level:
    (N,) refined level index within the octave; octave: (N,) long; response: (N,); tall:
    (1, 2, R, W) gradients (gx, gy) of every Gaussian level of every octave, stacked vertically;
    row0: (O,) first row of each octave in tall; size: (O, 2) (w, h) of each octave;
    sigma0, scales_per_octave: the scale space (sigma_i = sigma0 * 2**(i / S)); count: with fixed
    shapes (detect's static_k), a 0-d long tensor, the number of real candidates (the first count
    entries; the rest have response -inf), else None (every entry is real).
    """

    level: int
    xy: torch.Tensor
    sub_level: torch.Tensor
    octave: torch.Tensor
    response: torch.Tensor
    tall: torch.Tensor
    row0: torch.Tensor
    size: torch.Tensor
    sigma0: float
    scales_per_octave: int
    count: torch.Tensor | None = None

    def __len__(self) -> int:
        return int(self.response.numel()) if self.count is None else int(self.count)


def detect(level_image: torch.Tensor, level: int, opts: FeatureOptions, *,
           static_k: int | None = None) -> ScaleSpaceCandidates:
    """Scale-space maxima of a pyramid level image (1, 1, h, w), strongest first.

    Scale space (per octave o, S = scales_per_octave): sigma_i = sigma0 * 2**(i / S), i = 0..S+1,
    on the detection level downscaled by 2**o; DoH = sigma**4 (Lxx Lyy - Lxy**2); candidates are its
    3 x 3 x 3 maxima above response_threshold. static_k: fixed shapes (see _detect_octave): at most
    static_k candidates per octave, ``count`` of them real; the first ``count`` are those of the
    data-dependent path when no octave has more than static_k.
    """
    dev = level_image.device
    s_per = opts.scales_per_octave
    n_lv = s_per + 2
    sig = [opts.sigma0 * 2.0 ** (i / s_per) for i in range(n_lv)]
    _, _, h0, w0 = level_image.shape
    sizes = []
    h, w = h0, w0
    for _ in range(opts.octaves):
        if min(h, w) < 4 * opts.border_px + 8:
            break
        sizes.append((w, h))
        h, w = h // 2, w // 2
    rows = [0]
    for _, h_o in sizes:
        rows.append(rows[-1] + n_lv * h_o)
    tall = level_image.new_empty(1, 2, max(rows[-1], 1), w0)
    if not sizes:
        tall.zero_()
    octs: list[_Octave] = []
    base = gaussian_blur(level_image, math.sqrt(max(sig[0] ** 2 - _SIGMA_IN**2, 1e-6)))
    steps = [math.sqrt(sig[i] ** 2 - sig[i - 1] ** 2) for i in range(1, n_lv)]
    for o, (w_o, h_o) in enumerate(sizes):
        stack = _gaussian_stack(base, steps)
        octs.append(_detect_octave(stack, sig, o, opts, static_k))
        _gradients_into(stack, tall[0, :, rows[o]:rows[o + 1], :w_o].view(2, n_lv, h_o, w_o))
        if w_o < w0:  # bilinear samples at a level's right edge read (with weight 0) the column beyond
            tall[0, :, rows[o]:rows[o + 1], w_o:] = 0.0
        if o + 1 < len(sizes):
            # Next octave from the level at 2 sigma0 (index S), 2 x 2 averaged: sigma ~ sigma0 again.
            base = half_size(stack[s_per][None, None])
    z = torch.zeros(0, device=dev)
    if not octs:
        return ScaleSpaceCandidates(level, torch.zeros(0, 2, device=dev), z, z.long(), z, tall,
                                    z.long(), torch.zeros(0, 2, device=dev), opts.sigma0, s_per)
    resp = torch.cat([o.response for o in octs])
    order = resp.argsort(descending=True, stable=True)
    octave = torch.cat([torch.full((o.response.numel(),), o.index, device=dev, dtype=torch.long) for o in octs])
    count = None if static_k is None else torch.isfinite(resp).sum()
    return ScaleSpaceCandidates(
        level, torch.cat([o.xy for o in octs]).index_select(0, order),
        torch.cat([o.sub_s for o in octs]).index_select(0, order), octave.index_select(0, order),
        resp.index_select(0, order), tall, cached_constant(tuple(rows[:-1]), dev), cached_constant(tuple(sizes), dev),
        opts.sigma0, s_per, count)

