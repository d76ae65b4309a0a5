"""Super-resolution of one mosaic tile from the registered frames that cover it (chapter 5).

:func:`reconstruct_tile` is the entry point: it batches the frames that observe the tile
(:mod:`.observation`), builds the initial estimate the reference uses (the interpolated LR mosaic:
the frames warped into the tile, averaged, bicubically upsampled), then minimises (5.3) with one of
the solvers of :mod:`.solvers`.

Colour: by default (``color='luma'``) the MAP problem is solved on the luminance Y (Rec. 601) and
the chroma is taken from the interpolated mosaic: the eye resolves luminance detail far better than
chroma, natural aerial scenes carry little high-frequency chroma, and one channel costs a third of
three (the speed target). The result is ``rgb0 + (Y_sr - Y0)`` on every channel, which changes Y
by exactly ``Y_sr - Y0`` and leaves the colour differences B - Y and R - Y of ``rgb0`` untouched.
``rgb0`` is the interpolated mosaic, and when the tile is anchored (``anchor``) its colour
differences are anchored too: where the reference frame's (sampled bicubically onto the HR tile)
depart from the average's by more than twice the noise, the excess is added back, as anchor.py does
for the luminance. Interlaced and compressed video carries a different chroma error in each frame,
so the average's colour fringes on edges and small objects where the frame the mosaic shows has
none; on simulated frames the difference is noise and stays out. ``color='rgb'`` solves the three
channels jointly (same operators; three times the cost) for when colour detail matters; it is not
the default because its PSNR over RGB is lower (bench/sr.py): the per-channel problems are noisier
than the luminance one.

Local alignment (``local_align``, :mod:`.local_align`): before anything else each frame warped into
the tile is aligned to the reference by ECC (affine), so that (5.1) does not read the homographies'
local error on real footage (parallax, lens, the chain) as detail; a correction larger than
``local_align_max_px`` at the tile's corners is not applied. Then (``photometric``) each frame's
gain and offset per channel give it the reference's mean and std on the tile, where that changes it
by more than twice the noise (survey stills differ in exposure and white balance).

Robust frame weights: frames whose residual on the tile is an outlier (misregistration, moving
objects) must not smear the result. Before iterating, every frame warped into the LR tile is
compared with the per-pixel median of all of them (three frames or more); after the iterations in
``reweight_at`` it is compared with its prediction from the current HR estimate. From the RMS
residuals ``e_k``: ``tau = median(e) + outlier_threshold * max(1.4826 MAD(e), 0.1 median(e))``;
``w_k = 1`` when ``e_k <= tau``, else ``(tau / e_k)^outlier_power``.

Within each frame, the robust data term (``robust_pixels``, :mod:`.robust_pixels`) weights every LR
pixel by its residual at the same iterations (IRLS), so a person walking or a patch misregistered
does not pull the estimate while the rest of its frame still counts. Optionally (``dense_flow``,
:mod:`.dense_flow`) a dense residual flow of each frame to the reference moves the warp's sampling
points per pixel after the ECC alignment.

Those weights are relative: they cannot see a tile where every frame disagrees with every other
(3-D ground seen from stills far apart). Before them, the consistency test of
:mod:`.consistency` keeps the largest set of frames that correlate as well as their noise allows
(weight 0 for the others) and refuses the tile (SRError) when fewer than two agree: such a tile is
left to the mosaic instead of being averaged into blur.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace

import numpy as np
import torch
import torch.nn.functional as F

from ..device import resolve_device
from .anchor import anchor_to_frame, neighbour_correlation, reference_on_hr, structure_threshold
from .consistency import consistent_frames, noise_sigma
from .dense_flow import dense_flow_to_reference, remap_tile
from .local_align import align_to_reference, photometric_to_reference
from .moving import MIN_FRAMES as MOVING_MIN_FRAMES, moving_mask
from .observation import FrameStack, build_frame_stack
from .operators import Warp, gaussian_psf
from .prior import HuberPrior, clique_differences, huber_sum
from .robust_pixels import pixel_weights
from .ringing import clamp_to_lr_range, resolve_clamp
from .scheduler import frame_centres
from .sr_config import SRConfig, SRError, SRFramesDisagree  # re-exported: checkpoints and callers name them here
from .solvers import IterationRecord, LambdaRule, Problem, solve

__all__ = [
    'SRConfig',
    'SRResult',
    'SRError',
    'SRFramesDisagree',
    'reconstruct_tile',
    'robust_frame_weights',
    'luma',
    'lr_mosaic',
    'warp_frames_to_tile',
    'average_frames',
]

LUMA = (0.299, 0.587, 0.114)
#: std of the colour difference R - Y, G - Y, B - Y over the std of Y, for noise i.i.d. per channel:
#: sqrt(sum_j (delta_cj - w_j)^2 / sum_j w_j^2), w = LUMA.
CHROMA_NOISE = tuple(math.sqrt(sum(((c == j) - w) ** 2 for j, w in enumerate(LUMA)) / sum(w * w for w in LUMA))
                     for c in range(3))
#: Exposure matching leaves a frame as it is when it would change it by less than this many noise
#: stds (core/sr/local_align.py).
PHOTOMETRIC_NOISE = 2.0
@dataclass
class SRResult:
    """Output of :func:`reconstruct_tile`.

    image: (C, H s, W s) float32 in [0, 1] on the device: the SR tile; HR pixel (u, v) shows LR tile
        point ((u + 0.5) / s - 0.5, (v + 0.5) / s - 0.5).
    initial: (C, H s, W s) the initial estimate = bicubic upsampling of the LR mosaic (the baseline).
    lr_mosaic: (C, H, W) the frames averaged in the tile; coverage: (H, W) frames covering each pixel.
    history: per-iteration records (objective, lambda, relative change, time).
    frame_weights, frame_rms: (N,) per input frame (0 / NaN for frames that do not observe the tile).
    frame_consistent: (N,) False for frames left out by the consistency test (or not observing);
    consistency: its figures (noise, ncc_min, ncc_median, kept, frames; empty when off).
    reference: index (into the caller's frames) of the reference frame, the one whose centre is
    nearest the tile's; anchor_rms: RMS of its residual before anchoring (intensity), NaN when the
    tile was not anchored.
    timings: seconds for 'setup', 'initial', 'solve', 'total'.
    moving_pixels: frames' LR pixels left out of the data term as moving (``moving``).
    held_out_rms: the leave-one-out check's RMS prediction errors (grey levels) of the held-out
    frames from SR and from the mosaic (core/sr/self_check.py), NaN when not checked.
    """

    image: torch.Tensor
    initial: torch.Tensor
    lr_mosaic: torch.Tensor
    coverage: torch.Tensor
    factor: int
    history: list[IterationRecord] = field(default_factory=list)
    frame_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_rms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_consistent: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    consistency: dict[str, float] = field(default_factory=dict)
    reference: int = -1
    anchor_rms: float = math.nan
    timings: dict[str, float] = field(default_factory=dict)
    converged: bool = False
    moving_pixels: int = 0
    held_out_rms: tuple[float, float] = (math.nan, math.nan)
    stop_reason: str = ''
    config: SRConfig | None = None

    def to_numpy(self, *, initial: bool = False) -> np.ndarray:
        """(H s, W s, C) uint8 of the SR tile (or of the bicubic initial estimate)."""
        img = (self.initial if initial else self.image).detach().float().cpu().clamp(0, 1)
        return (img.permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.uint8)


def luma(x: torch.Tensor) -> torch.Tensor:
    """Rec. 601 luminance of (..., 3, H, W) -> (..., 1, H, W); (..., 1, H, W) is returned as is."""
    if x.shape[-3] == 1:
        return x
    w = torch.tensor(LUMA, dtype=x.dtype, device=x.device).view(3, 1, 1)
    return (x * w).sum(dim=-3, keepdim=True)


def robust_frame_weights(rms: torch.Tensor, *, threshold: float = 3.0, power: float = 2.0) -> torch.Tensor:
    """Per-frame weights (K,) from per-frame RMS residuals (K,): 1 for inliers, (tau / e)^power above tau.

    tau = median + threshold * max(1.4826 MAD, 0.1 median); fewer than 3 frames: all 1.
    """
    rms = rms.double()
    if rms.numel() < 3:
        return torch.ones_like(rms)
    med = rms.median()
    mad = 1.4826 * (rms - med).abs().median()
    tau = med + threshold * torch.maximum(mad, 0.1 * med).clamp_min(1e-9)
    return torch.where(rms <= tau, torch.ones_like(rms), (tau / rms.clamp_min(1e-12)) ** power)


def _frames_to_tensors(frames: Sequence[np.ndarray | torch.Tensor], device: torch.device) -> list[torch.Tensor]:
    """All frames of a tile as (C, H, W) float32 tensors in [0, 1] on ``device``.

    uint16 frames (radiometric IR) are stretched by the 0.5 and 99.5 percentiles of all the tile's
    frames together: one mapping for every frame keeps them photometrically consistent, which the
    data term needs (a per-frame stretch would make the same ground differ between frames).
    """
    u16 = [np.asarray(f) for f in frames if not isinstance(f, torch.Tensor) and np.asarray(f).dtype == np.uint16]
    stretch = None
    if u16:
        sample = np.concatenate([f.reshape(-1)[:: max(1, f.size // 200000)] for f in u16])
        lo, hi = (float(v) for v in np.percentile(sample, (0.5, 99.5)))
        stretch = (lo, max(hi, lo + 1.0))
    return [_to_tensor(f, device, stretch) for f in frames]


def _to_tensor(frame: np.ndarray | torch.Tensor, device: torch.device,
               stretch: tuple[float, float] | None = None) -> torch.Tensor:
    """Edge image (H, W) / (H, W, C) uint8|uint16|float, or tensor (C, H, W) / (1, C, H, W) -> (C, H, W)."""
    if isinstance(frame, torch.Tensor):
        t = frame
        if t.ndim == 4 and t.shape[0] == 1:
            t = t[0]
        if t.ndim == 2:
            t = t[None]
        if t.ndim != 3:
            msg = f'a frame tensor is (C, H, W) or (1, C, H, W), got shape {tuple(frame.shape)}.'
            raise SRError(msg)
        t = t.to(device=device, dtype=torch.float32)
    else:
        a = np.asarray(frame)
        if a.dtype == np.uint8:
            f = a.astype(np.float32) / 255.0
        elif a.dtype == np.uint16:
            lo, hi = stretch if stretch is not None else (0.0, 65535.0)
            f = np.clip((a.astype(np.float32) - lo) / (hi - lo), 0.0, 1.0)
        elif np.issubdtype(a.dtype, np.floating):
            f = a.astype(np.float32)
        else:
            msg = f'frame dtype {a.dtype} is not supported; give uint8, uint16 or float in [0, 1].'
            raise SRError(msg)
        if f.ndim == 2:
            f = f[:, :, None]
        if f.ndim != 3:
            msg = f'a frame array is (H, W) or (H, W, C), got shape {a.shape}.'
            raise SRError(msg)
        t = torch.from_numpy(np.ascontiguousarray(f.transpose(2, 0, 1))).to(device)
    if t.shape[0] == 4:
        t = t[:3]
    if t.shape[0] not in (1, 3):
        msg = f'frames have 1 (mono, IR) or 3 (RGB) channels, got {t.shape[0]}.'
        raise SRError(msg)
    return t


def _fill_uncovered(img: torch.Tensor, covered: torch.Tensor, max_rounds: int = 64) -> torch.Tensor:
    """Fill pixels with ``covered == 0`` by repeated 3x3 normalised averaging from covered ones."""
    if bool(covered.all()):
        return img
    val = img * covered
    cov = covered.clone()
    for _ in range(max_rounds):
        if bool((cov > 0).all()):
            break
        s_val = F.avg_pool2d(val[None], 3, stride=1, padding=1, count_include_pad=False)[0]
        s_cov = F.avg_pool2d(cov[None], 3, stride=1, padding=1, count_include_pad=False)[0]
        grow = (cov == 0) & (s_cov > 0)
        val = torch.where(grow, s_val / s_cov.clamp_min(1e-12), val)
        cov = torch.where(grow, torch.ones_like(cov), cov)
    return torch.where(cov > 0, val, img.new_tensor(0.5))


def warp_frames_to_tile(stack: FrameStack, tile_shape: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """The frames' windows warped into the LR tile (bilinear): ``(warped (K, C, H, W), covered (K, 1, H, W))``.

    ``covered`` is 1 where the frame has all four bilinear neighbours on real frame pixels.
    """
    windows_H_tile = np.linalg.inv(stack.tile_H_windows)
    hc, wc = stack.crops.shape[-2:]
    warp = Warp(windows_H_tile, (hc, wc), tile_shape, device=stack.crops.device, dtype=stack.crops.dtype,
                shared=False)
    both = warp.apply(torch.cat([stack.crops, stack.in_frame], dim=1))
    warped = both[:, :-1]
    covered = ((both[:, -1:] > 0.999) & (warp.inside(1e-5) > 0)).to(warped.dtype)
    return warped, covered


def average_frames(warped: torch.Tensor, covered: torch.Tensor,
                   weights: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The interpolated LR mosaic: weighted mean of the warped frames where they cover.

    Returns ``(mosaic (C, H, W), coverage (H, W))``; pixels no frame covers are filled from their
    neighbours (coverage 0 there).
    """
    w = covered if weights is None else covered * weights.to(warped.dtype).view(-1, 1, 1, 1)
    wsum = w.sum(dim=0)
    mosaic = (warped * w).sum(dim=0) / wsum.clamp_min(1e-12)
    mosaic = _fill_uncovered(mosaic, (wsum > 0).to(mosaic.dtype))
    return mosaic, covered.sum(dim=(0, 1))


def lr_mosaic(stack: FrameStack, tile_shape: tuple[int, int],
              weights: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`warp_frames_to_tile` then :func:`average_frames`: ``(mosaic (C, H, W), coverage (H, W))``."""
    return average_frames(*warp_frames_to_tile(stack, tile_shape), weights)


def _median_rms(warped: torch.Tensor, covered: torch.Tensor) -> torch.Tensor:
    """(K,) RMS of each warped frame against the per-pixel median of all (where >= 3 frames cover)."""
    nan = torch.full_like(warped, math.nan)
    vals = torch.where(covered > 0, warped, nan)
    med = torch.nanmedian(vals, dim=0).values
    enough = (covered.sum(dim=0) >= 3) & torch.isfinite(med)
    d = torch.where(enough & (covered > 0), warped - torch.nan_to_num(med), torch.zeros_like(warped))
    n = (enough & (covered > 0)).expand_as(d).reshape(d.shape[0], -1).sum(dim=1).clamp_min(1)
    return torch.sqrt((d.double() ** 2).reshape(d.shape[0], -1).sum(dim=1) / n)


def _nearest_frame(index: Sequence[int], tile_H_frames: Sequence[np.ndarray], frames: Sequence[torch.Tensor],
                   tile_shape: tuple[int, int]) -> int:
    """Position in ``index`` of the frame whose centre lands nearest the tile's centre (the frame the
    mosaic shows there, as the SR scheduler ranks frames)."""
    h_t, w_t = tile_shape
    centres = frame_centres([np.asarray(tile_H_frames[i]) for i in index],
                            [(int(frames[i].shape[-1]), int(frames[i].shape[-2])) for i in index])
    return int(np.argmin(np.hypot(*(centres - [(w_t - 1) / 2.0, (h_t - 1) / 2.0]).T)))


TileCallback = Callable[[int, torch.Tensor], None]


def reconstruct_tile(frames: Sequence[np.ndarray | torch.Tensor], tile_H_frames: Sequence[np.ndarray],
                     tile_shape: tuple[int, int], factor: int, *, psf: torch.Tensor | None = None,
                     config: SRConfig | None = None, callback: TileCallback | None = None, reference: int | None = None,
                     **settings: object) -> SRResult:
    """Super-resolve the LR tile ``tile_shape = (H, W)`` by ``factor`` from ``frames``.

    frames: N images, each (h, w) / (h, w, C) numpy (uint8, float in [0, 1], or uint16 stretched by
        the percentiles of all N together) or a tensor (C, h, w) in [0, 1]; all with the same channel
        count (1 or 3; alpha is dropped).
    tile_H_frames: N (3, 3) homographies, frame LR pixels -> LR tile pixels (pixel centres at
        integers); for a mosaic tile at (x0, y0): ``translation(-x0, -y0) @ mosaic_H_frame``.
    factor: 2, 3 or 4 (any integer >= 2 works).
    psf: optional (k, k) PSF on the HR grid (k of the parity of ``factor``) replacing the Gaussian.
    config / settings: an :class:`SRConfig` and/or any of its fields as keywords (keywords win);
        unknown keys are refused.
    reference: index into ``frames`` of the frame the tile is anchored to and aligned on (default: the
        frame whose centre lands nearest the tile's, the one the mosaic shows there); ignored when
        that frame does not observe the tile.
    callback(iteration, image (C, H s, W s)): called with the current tile estimate (iteration 0 is
        the initial estimate); for studies, it costs a colour composition per iteration.

    Returns an :class:`SRResult`; raises :class:`SRError` when no frame observes the tile, or when
    fewer than two of the frames agree on it (``consistency``; the message gives the figures).
    """
    t0 = time.perf_counter()
    known = {f.name for f in fields(SRConfig)}
    unknown = sorted(set(settings) - known)
    if unknown:
        msg = f'unknown SR settings {unknown}; known: {sorted(known)}.'
        raise SRError(msg)
    if 'reweight_at' in settings:
        settings['reweight_at'] = tuple(settings['reweight_at'])  # type: ignore[arg-type]
    cfg = replace(config or SRConfig(), **settings)  # type: ignore[arg-type]
    s = int(factor)
    if s < 2:
        msg = f'the SR factor must be an integer >= 2, got {factor}.'
        raise SRError(msg)
    if len(frames) != len(tile_H_frames) or not frames:
        msg = f'need the same, non-zero number of frames and homographies, got {len(frames)} and {len(tile_H_frames)}.'
        raise SRError(msg)
    h_t, w_t = (int(v) for v in tile_shape)
    if h_t < 2 or w_t < 2:
        msg = f'the tile must be at least 2x2 LR pixels, got {tile_shape}.'
        raise SRError(msg)
    device = resolve_device(cfg.device)
    ts = _frames_to_tensors(frames, device)
    if len({t.shape[0] for t in ts}) != 1:
        msg = 'frames of one tile must all be mono or all be RGB.'
        raise SRError(msg)
    channels = ts[0].shape[0]
    m = cfg.margin
    hm, wm = h_t + 2 * m, w_t + 2 * m
    shift = np.array([[1.0, 0.0, m], [0.0, 1.0, m], [0.0, 0.0, 1.0]])
    tilem_H_frames = [shift @ np.asarray(h, dtype=np.float64) for h in tile_H_frames]
    if psf is None:
        kernel = gaussian_psf(cfg.psf_sigma * s, s, device=device)
    else:
        kernel = torch.as_tensor(psf, dtype=torch.float32, device=device)
        kernel = kernel / kernel.sum()
        if kernel.ndim != 2 or (kernel.shape[0] - s) % 2 or (kernel.shape[1] - s) % 2:
            msg = (f'a PSF for factor {s} is a 2-D kernel whose sides have the parity of {s} (it is centred '
                   f'on an LR pixel centre), got shape {tuple(kernel.shape)}.')
            raise SRError(msg)
    stack = build_frame_stack(ts, tilem_H_frames, (hm, wm), s, kernel, min_observed=cfg.min_observed, interpolation=cfg.warp)
    if stack is None:
        msg = 'no frame observes this tile; pick tiles inside the frames\' footprints.'
        raise SRError(msg)
    n_frames = len(frames)
    k_frames = len(stack.index)
    t1 = time.perf_counter()

    # Initial estimate: the robustly weighted LR mosaic, bicubically upsampled.
    warped, covered = warp_frames_to_tile(stack, (hm, wm))
    # noise of the frames themselves (luminance): the bilinear warp smooths it, which a high-pass
    # estimate on the warped frames would take for less noise
    noise = noise_sigma(luma(stack.crops), stack.in_frame)
    ref = (stack.index.index(reference) if reference is not None and reference in stack.index
           else _nearest_frame(stack.index, tilem_H_frames, ts, (hm, wm)))
    if cfg.local_align != 'off' and k_frames >= 2:  # each frame superposed on the reference here (local_align.py)
        corr = align_to_reference(luma(warped), covered, ref, mode=cfg.local_align, max_shift=cfg.local_align_max_px)
        ref_frame = stack.index[ref]
        if not np.allclose(corr, np.eye(3)):
            for k, i in enumerate(stack.index):
                tilem_H_frames[i] = corr[k] @ tilem_H_frames[i]
            stack = build_frame_stack(ts, tilem_H_frames, (hm, wm), s, kernel, min_observed=cfg.min_observed, interpolation=cfg.warp)
            if stack is None:
                msg = 'no frame observes this tile; pick tiles inside the frames\' footprints.'
                raise SRError(msg)
            k_frames = len(stack.index)
            warped, covered = warp_frames_to_tile(stack, (hm, wm))
            # the reference stays the frame the mosaic shows (centres often tie within a pixel)
            ref = stack.index.index(ref_frame) if ref_frame in stack.index else \
                _nearest_frame(stack.index, tilem_H_frames, ts, (hm, wm))
    if cfg.dense_flow != 'off' and k_frames >= 2:  # per-pixel residual registration (dense_flow.py)
        flow, conf = dense_flow_to_reference(luma(warped), covered, ref, preset=cfg.dense_flow,
                                             max_px=cfg.dense_flow_max_px, smooth=cfg.dense_flow_smooth,
                                             fb_px=cfg.dense_flow_fb_px)
        ref_frame = stack.index[ref]
        flows = {i: flow[k] for k, i in enumerate(stack.index)}
        confs = {i: conf[k] for k, i in enumerate(stack.index)}
        refined = build_frame_stack(ts, tilem_H_frames, (hm, wm), s, kernel, min_observed=cfg.min_observed, interpolation=cfg.warp,
                                    flows=flows, confidence=confs)
        if refined is not None and ref_frame in refined.index:
            stack = refined
            k_frames = len(stack.index)
            ref = stack.index.index(ref_frame)
            warped, covered = warp_frames_to_tile(stack, (hm, wm))
            sel = torch.stack([flows[i] for i in stack.index])
            both = remap_tile(torch.cat([warped, covered], dim=1), sel)
            warped, covered = both[:, :-1], (both[:, -1:] > 0.999).to(warped.dtype)
    if cfg.photometric and k_frames >= 2:  # exposure and white balance onto the reference's (local_align.py)
        gain, offset = photometric_to_reference(warped, covered, ref, min_change=PHOTOMETRIC_NOISE * noise)
        stack.crops.copy_((stack.crops * gain + offset).clamp(0, 1) * stack.in_frame)
        stack.y.copy_(stack.crops * stack.mask)
        warped = (warped * gain + offset).clamp(0, 1) * covered
    keep, consistency = np.ones(k_frames, dtype=bool), {}
    if cfg.consistency > 0 and k_frames >= 2:
        keep, consistency = consistent_frames(luma(warped), covered, threshold=cfg.consistency, noise=noise,
                                              reference=ref)
        if keep.sum() < 2:
            msg = (f'the {k_frames} frames on this tile disagree with each other (pairwise NCC median '
                   f'{consistency["ncc_median"]:.2f}, min {consistency["ncc_min"]:.2f}, against a noise of '
                   f'{255 * consistency["noise"]:.1f} grey levels): parallax, misregistration or motion, which '
                   'SR would average into blur; the tile is left to the mosaic (sr.consistency sets the test, 0 '
                   'turns it off).')
            raise SRFramesDisagree(msg)
    kept = torch.as_tensor(np.flatnonzero(keep), device=device)
    robust = cfg.robust and len(kept) >= 3

    def gated(rms: torch.Tensor) -> torch.Tensor:
        """Weights: 0 for inconsistent frames, the relative outlier rule among the others."""
        w = torch.zeros(k_frames, dtype=torch.float64, device=device)
        w[kept] = robust_frame_weights(rms[kept], threshold=cfg.outlier_threshold,
                                       power=cfg.outlier_power) if robust else 1.0
        return w

    moving_px = 0
    if cfg.moving > 0 and len(kept) >= MOVING_MIN_FRAMES:  # moving objects out of the data term (moving.py)
        moved, drop = moving_mask(stack, luma(warped), covered, kept, cfg.moving)
        covered = covered * (1.0 - moved)
        stack.mask.mul_(1.0 - drop)  # the operator's M: these pixels weigh 0 in (5.3)
        stack.y.mul_(1.0 - drop)
        moving_px = int(drop.sum())
    w0 = torch.zeros(k_frames, dtype=torch.float64, device=device)
    w0[kept] = 1.0
    if robust:
        rms0 = torch.zeros(k_frames, dtype=torch.float64, device=device)
        rms0[kept] = _median_rms(luma(warped[kept]), covered[kept])
        w0 = gated(rms0)
    mosaic, coverage = average_frames(warped, covered, w0)
    x0_rgb = F.interpolate(mosaic[None], scale_factor=s, mode='bicubic', align_corners=False).clamp(0, 1)
    t2 = time.perf_counter()

    if cfg.color == 'luma' and channels == 3:
        y_obs = luma(stack.crops) * stack.mask
        x0 = luma(x0_rgb)
        solve_c = 1
    else:
        y_obs = stack.y
        x0 = x0_rgb
        solve_c = channels
    counts = stack.mask.reshape(k_frames, -1).sum(dim=1).double() * solve_c
    if solve_c != 1:  # per channel: the residual is over the channels, so is the noise
        noise = noise_sigma(stack.crops.reshape(-1, 1, *stack.crops.shape[-2:]),
                            stack.in_frame.repeat_interleave(solve_c, dim=0))
    noise_cap = cfg.lambda_noise_cap * noise if cfg.lambda_noise_cap > 0 and noise > 0 else None
    noise_floor = cfg.lambda_noise_floor * noise if cfg.lambda_noise_floor > 0 and noise > 0 else None
    if cfg.lambda_reference == 'initial':
        g0 = clique_differences(x0)
        rule = LambdaRule(cfg.lambda_mode, value=cfg.lam, gamma=cfg.lambda_gamma / (s * s),
                          reference=huber_sum(g0, cfg.huber_alpha) / g0.numel(), noise_cap=noise_cap,
                          noise_floor=noise_floor)
    else:
        rule = LambdaRule(cfg.lambda_mode, value=cfg.lam, gamma=cfg.lambda_gamma / s, noise_cap=noise_cap,
                          noise_floor=noise_floor)
    problem = Problem(stack.operator, y_obs, prior=HuberPrior(cfg.huber_alpha), lam=rule,
                      frame_weights=w0.to(y_obs.dtype), counts=counts)

    base = x0_rgb  # the colour of a luminance solve: the frames' average, anchored to the reference's
    if cfg.anchor and solve_c != channels:
        # the reference's colour where it departs from the average by more than the noise, as
        # anchor.py does for the luminance (interlaced and compressed video: chroma differs per frame)
        ref_rgb, ref_valid = reference_on_hr(stack, ref, s, x0_rgb.shape[-2:])
        d = (ref_rgb - x0_rgb) * ref_valid
        d = d - luma(d)
        n_valid = max(float(ref_valid.sum()), 1.0)
        thr = torch.zeros((1, channels, 1, 1), dtype=d.dtype, device=d.device)
        # anchor_compression: the reference's colour-difference residual on its own LR pixels, whose
        # neighbours correlate where compression made it (structure_threshold); d above lives on the
        # HR grid, correlated by the upsampling
        ref_mask = stack.mask[ref:ref + 1]
        r_ref = (stack.y[ref:ref + 1] - stack.operator.apply(x0_rgb)[ref:ref + 1]) * ref_mask
        r_ref = r_ref - luma(r_ref)
        for c in range(channels):
            # noise i.i.d. per channel: a colour difference c - Y is noisier than Y by CHROMA_NOISE[c]
            noise_c = CHROMA_NOISE[c] * noise
            d_rms = float(torch.sqrt((d[:, c].double() ** 2).sum() / n_valid))
            rho = neighbour_correlation(r_ref[:, c:c + 1], ref_mask) if cfg.anchor_compression else 0.0
            thr[0, c] = structure_threshold(cfg.anchor_noise * noise_c, noise_c, d_rms, rho)
        base = x0_rgb + torch.sign(d) * (d.abs() - thr).clamp_min(0.0) * ref_valid
    base_y = luma(base)

    def compose(x: torch.Tensor) -> torch.Tensor:
        full = (base + (x - base_y)) if solve_c != channels else x
        return full[0, :, m * s:(m + h_t) * s, m * s:(m + w_t) * s].clamp(0, 1)

    pixel_robust = cfg.robust_pixels != 'off'
    reweight_at = set(cfg.reweight_at) if robust or pixel_robust else set()
    base_mask, y_raw = stack.mask.clone(), y_obs / stack.mask.clamp_min(1e-12) * (stack.mask > 0)

    def reweight(n: int, _x: torch.Tensor, r: torch.Tensor) -> torch.Tensor | None:
        if n not in reweight_at:
            return None
        w = gated(problem.frame_rms(r).double()).to(r.dtype) if robust else problem.frame_weights
        if pixel_robust:  # the robust data term (robust_pixels.py): the operator's mask and y reweighted
            wp = pixel_weights(r, stack.mask, norm=cfg.robust_pixels, scale=cfg.robust_pixels_scale, noise=noise)
            stack.mask.copy_(base_mask * torch.sqrt(wp))
            problem.y.copy_(y_raw * stack.mask)
        return w

    x0_tile = x0_rgb[0, :, m * s:(m + h_t) * s, m * s:(m + w_t) * s].clamp(0, 1)
    cb = None if callback is None else (lambda n, x: callback(n, x0_tile if n == 0 else compose(x)))
    lm_opts = {'inner_iterations': cfg.lm_inner} if cfg.solver == 'lm' else {}
    res = solve(problem, x0, method=cfg.solver, iterations=cfg.iterations, tol=cfg.tol, callback=cb,
                reweight=reweight, **lm_opts)
    x_final, anchor_rms = res.x, math.nan
    if pixel_robust:  # anchoring and the figures below read the frames as observed
        stack.mask.copy_(base_mask)
        problem.y.copy_(y_raw * stack.mask)
    if cfg.anchor:
        if not (keep[ref] and float(problem.frame_weights[ref]) >= 0.5):
            # the frame the mosaic shows here is the odd one out (parallax, a passing car): a tile
            # fused from the others would disagree with the mosaic around it
            msg = (f'the frame the mosaic shows on this tile disagrees with the other {k_frames - 1} (left out by '
                   f"{'the consistency test' if not keep[ref] else 'the robust weights'}): parallax, motion or "
                   'misregistration; the tile is left to the mosaic (sr.anchor: false super-resolves it from the '
                   'others).')
            raise SRFramesDisagree(msg)
        x_final, anchor_rms = anchor_to_frame(res.x, y_obs, stack, ref, s, threshold=cfg.anchor_noise * noise,
                                              noise=noise, compression=cfg.anchor_compression)
    if resolve_clamp(cfg.clamp, psf_chosen=False) != 'off':  # no ringing beyond the range the frames show (ringing.py)
        bounds = [mosaic, torch.where(covered[ref] > 0, warped[ref], mosaic)]
        if solve_c != channels:
            bounds = [luma(b[None])[0] for b in bounds]
        x_final = clamp_to_lr_range(x_final, bounds, s, cfg.clamp)
    if device.type == 'cuda':
        torch.cuda.synchronize(device)
    t3 = time.perf_counter()

    final_r = problem.y - problem.operator.apply(x_final)
    rms = problem.frame_rms(final_r).cpu().numpy()
    weights_all = np.zeros(n_frames)
    rms_all = np.full(n_frames, math.nan)
    consistent_all = np.zeros(n_frames, dtype=bool)
    for k, i in enumerate(stack.index):
        weights_all[i] = float(problem.frame_weights[k])
        rms_all[i] = float(rms[k])
        consistent_all[i] = bool(keep[k])
    crop = (slice(None), slice(m * s, (m + h_t) * s), slice(m * s, (m + w_t) * s))
    image = compose(x_final)
    t4 = time.perf_counter()
    return SRResult(
        image=image, initial=x0_rgb[0][crop], lr_mosaic=mosaic[:, m:m + h_t, m:m + w_t],
        coverage=coverage[m:m + h_t, m:m + w_t], factor=s, history=res.history,
        frame_weights=weights_all, frame_rms=rms_all, frame_consistent=consistent_all, consistency=consistency,
        reference=stack.index[ref], anchor_rms=anchor_rms,
        timings={'setup': t1 - t0, 'initial': t2 - t1, 'solve': t3 - t2, 'total': t4 - t0},
        converged=res.converged, stop_reason=res.stop_reason, config=cfg, moving_pixels=moving_px)
