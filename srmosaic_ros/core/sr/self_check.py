"""SR that never loses to the mosaic, checked without ground truth: leave a frame out, predict it.

A tile is super-resolved from its frames less one (the one whose centre is nearest the tile's after
the reference, which the run anchors to), and the frame left out is predicted twice: through its
own D B W (5.1) from the SR estimate, and by the LR mosaic of the same frames resampled at its
pixels (what the mosaic shows of that ground). The held-out frame sees the ground at sub-pixel
offsets no frame in the solve had, so an estimate whose detail is wrong (ringing, a trail, a
misfit) predicts it worse than the plain mosaic does; such a tile is refused
(:class:`SRNotBetterThanMosaic`: left to the mosaic, and counted), the others are reconstructed
from all their frames as usual. The same leave-one-out prediction chooses the flight's PSF
(psf_select.py).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..device import resolve_device
from .observation import build_frame_stack
from .operators import Warp, gaussian_psf
from .reconstruct import SRConfig, SRError, SRResult, _frames_to_tensors, reconstruct_tile
from .scheduler import frame_centres

__all__ = ['SRNotBetterThanMosaic', 'held_out_errors', 'reconstruct_checked_tile']


class SRNotBetterThanMosaic(SRError):
    """The tile's SR estimate predicts held-out frames no better than the mosaic: left to the mosaic."""


def _holdout_order(frames: Sequence[np.ndarray], tile_H_frames: Sequence[np.ndarray],
                   tile_shape: tuple[int, int]) -> np.ndarray:
    """Frame indices by the distance of their centre to the tile's centre (the first is the reference)."""
    h_t, w_t = tile_shape
    sizes = [(int(np.asarray(f).shape[1]), int(np.asarray(f).shape[0])) for f in frames]
    centres = frame_centres([np.asarray(h) for h in tile_H_frames], sizes)
    return np.argsort(np.hypot(*(centres - [(w_t - 1) / 2.0, (h_t - 1) / 2.0]).T), kind='stable')


def held_out_errors(frames: Sequence[np.ndarray], tile_H_frames: Sequence[np.ndarray], tile_shape: tuple[int, int],
                    factor: int, config: SRConfig, *, holdouts: int = 1) -> tuple[float, float, int]:
    """``(sse_sr, sse_mosaic, n)``: squared errors (intensity^2, summed over channels) of predicting
    up to ``holdouts`` held-out frames (module docstring) from the SR estimate of the others and from
    their LR mosaic, over the n frame values both predict. (0, 0, 0) when no frame could be held out
    (fewer than three frames, or the others cannot be solved)."""
    if len(frames) < 3:
        return 0.0, 0.0, 0
    order = _holdout_order(frames, tile_H_frames, tile_shape)
    device = resolve_device(config.device)
    s = int(factor)
    sse_sr = sse_mosaic = 0.0
    n = 0
    for j in (int(v) for v in order[1:1 + holdouts]):
        others = [k for k in range(len(frames)) if k != j]
        try:
            res = reconstruct_tile([frames[k] for k in others], [tile_H_frames[k] for k in others], tile_shape, s,
                                   config=config)
        except SRError:
            continue
        stack = build_frame_stack(_frames_to_tensors([frames[j]], device), [np.asarray(tile_H_frames[j])], tile_shape,
                                  s, gaussian_psf(config.psf_sigma * s, s, device=device), min_observed=1)
        if stack is None or stack.crops.shape[1] != res.image.shape[0]:
            continue
        by_sr = stack.operator.apply(res.image[None].to(stack.crops.dtype))
        # the mosaic's view: its LR tile resampled at the frame's pixels (bilinear), where it reaches
        to_window = Warp(np.asarray(stack.tile_H_windows, dtype=np.float64), tuple(res.lr_mosaic.shape[-2:]),
                         tuple(stack.crops.shape[-2:]), device=device, dtype=stack.crops.dtype, shared=False)
        by_mosaic = to_window.apply(res.lr_mosaic[None].to(stack.crops.dtype))
        mask = stack.mask * (to_window.inside(1e-5) > 0).to(stack.mask.dtype)
        sse_sr += float((((by_sr - stack.crops) ** 2) * mask).sum())
        sse_mosaic += float((((by_mosaic - stack.crops) ** 2) * mask).sum())
        n += int(mask.sum()) * stack.crops.shape[1]
    return sse_sr, sse_mosaic, n


def reconstruct_checked_tile(frames: Sequence[np.ndarray], tile_H_frames: Sequence[np.ndarray],
                             tile_shape: tuple[int, int], factor: int, config: SRConfig) -> SRResult:
    """:func:`.reconstruct.reconstruct_tile` of the tile after the leave-one-out check of
    ``config.self_check`` held-out frames (0: no check): raises :class:`SRNotBetterThanMosaic` (an
    SRError) when the SR estimate of the others predicts them no better than their mosaic."""
    rms = (float('nan'), float('nan'))
    if config.self_check > 0:
        check = replace(config, device=str(resolve_device(config.device)))
        sse_sr, sse_mosaic, n = held_out_errors(frames, tile_H_frames, tile_shape, factor, check,
                                                holdouts=config.self_check)
        if n > 0:
            rms = (255.0 * float(np.sqrt(sse_sr / n)), 255.0 * float(np.sqrt(sse_mosaic / n)))
            if not sse_sr < sse_mosaic:
                msg = (f'SR of this tile predicts a frame left out no better than the mosaic does (RMS {rms[0]:.2f} '
                       f'against {rms[1]:.2f} grey levels over {n} values): its detail is not the ground\'s '
                       '(ringing, motion, misfit); the tile is left to the mosaic (sr.self_check sets the held-out '
                       'frames, 0 turns the check off).')
                raise SRNotBetterThanMosaic(msg)
    res = reconstruct_tile(frames, tile_H_frames, tile_shape, factor, config=config)
    res.held_out_rms = rms
    return res
