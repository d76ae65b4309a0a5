"""Choosing the PSF of a flight without ground truth: leave one frame out, predict it.

For each sigma of a small ladder, a tile is reconstructed from its frames less one, and the frame
left out is predicted through its own D B W (5.1) with that sigma; the sigma whose predictions of
the held-out frames have the least squared error, summed over a few tiles and held-out frames, is
the flight's. The held-out frame sees the ground at sub-pixel offsets that no frame in the solve
had, so an estimate whose detail is wrong (a PSF too wide rings, one too narrow leaves the aliasing
unresolved) predicts it worse. The curve is shallow (the noise is in every prediction), which is
why several tiles and frames are pooled; a choice one rung too low costs some sharpness, one too
high rings, so ties go to the lower sigma.

The tiles are solved with the regularisation the ladder was calibrated with (PSF_LAMBDA_GAMMA): a
stronger prior smooths the estimate and a narrower PSF makes up for it in the predictions, which
moved the choice a rung below the true blur on simulated tiles.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from ..device import resolve_device
from .observation import build_frame_stack
from .operators import gaussian_psf
from .reconstruct import SRConfig, SRError, _frames_to_tensors, reconstruct_tile
from .scheduler import frame_centres

__all__ = ['PSF_LAMBDA_GAMMA', 'PsfChoice', 'TileFrames', 'choose_psf_sigma', 'held_out_residual']

#: sr.lambda_gamma of the solves that judge the PSF (at most this; module docstring).
PSF_LAMBDA_GAMMA = 0.1


@dataclass(frozen=True)
class TileFrames:
    """One tile's inputs: frames (as :func:`reconstruct_tile` takes them), their (3, 3) homographies
    frame LR pixels -> LR tile pixels, and the tile's (H, W) in LR pixels."""

    frames: Sequence[np.ndarray]
    tile_H_frames: Sequence[np.ndarray]
    tile_shape: tuple[int, int]


@dataclass(frozen=True)
class PsfChoice:
    """The chosen sigma (LR pixels) and, per rung of the ladder, the RMS prediction error of the
    held-out frames (intensity in [0, 1]; NaN where no prediction could be made)."""

    sigma: float
    ladder: tuple[float, ...]
    rms: tuple[float, ...]
    predictions: int


def held_out_residual(tile: TileFrames, j: int, factor: int, config: SRConfig) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Frame ``j`` predicted from the tile's other frames through D B W_j with ``config.psf_sigma``:
    ``(squared residual (C, h, w), observed mask (1, h, w))`` on frame j's window of the tile, or None
    when the others cannot be solved or j does not observe the tile. The solve is not clamped
    (sr.clamp, ringing.py): the ringing of a PSF too wide is what tells it apart."""
    others = [k for k in range(len(tile.frames)) if k != j]
    try:
        res = reconstruct_tile([tile.frames[k] for k in others], [tile.tile_H_frames[k] for k in others],
                               tile.tile_shape, factor, config=config, anchor=False, clamp='off')
    except SRError:
        return None
    device = res.image.device
    s = int(factor)
    stack = build_frame_stack(_frames_to_tensors([tile.frames[j]], device), [tile.tile_H_frames[j]], tile.tile_shape,
                              s, gaussian_psf(config.psf_sigma * s, s, device=device), min_observed=1,
                              interpolation=config.warp)
    if stack is None or stack.y.shape[1] != res.image.shape[0]:
        return None
    r = stack.operator.apply(res.image[None]) - stack.crops
    return (r[0].double() ** 2), stack.mask[0]


def choose_psf_sigma(tiles: Sequence[TileFrames], factor: int, config: SRConfig, ladder: Sequence[float], *,
                     holdouts: int = 3) -> PsfChoice:
    """The sigma of ``ladder`` that predicts held-out frames best over ``tiles``.

    In each tile the frames nearest its centre after the first (the reference, which the others
    are anchored to in the run itself) are left out in turn, at most ``holdouts`` of them; tiles of
    fewer than three frames are skipped. Raises SRError when no prediction can be made (then the
    caller keeps ``config.psf_sigma``).
    """
    rungs = tuple(float(v) for v in ladder)
    cfg = replace(config, device=str(resolve_device(config.device)),
                  lambda_gamma=min(config.lambda_gamma, PSF_LAMBDA_GAMMA))
    sse = np.zeros(len(rungs))
    count = np.zeros(len(rungs))
    predictions = 0
    for tile in tiles:
        if len(tile.frames) < 3:
            continue
        h_t, w_t = tile.tile_shape
        sizes = [(int(np.asarray(f).shape[1]), int(np.asarray(f).shape[0])) if not isinstance(f, torch.Tensor)
                 else (int(f.shape[-1]), int(f.shape[-2])) for f in tile.frames]
        centres = frame_centres([np.asarray(h) for h in tile.tile_H_frames], sizes)
        order = np.argsort(np.hypot(*(centres - [(w_t - 1) / 2.0, (h_t - 1) / 2.0]).T))
        for j in order[1:1 + holdouts]:
            found = [held_out_residual(tile, int(j), factor, replace(cfg, psf_sigma=sigma)) for sigma in rungs]
            if any(f is None for f in found):
                continue
            # the same pixels for every rung: a wider PSF observes fewer of them near the tile's border
            common = torch.stack([f[1] for f in found]).amin(dim=0)
            n = float(common.sum()) * found[0][0].shape[0]
            if n == 0:
                continue
            for i, (sq, _) in enumerate(found):  # type: ignore[misc]
                sse[i] += float((sq * common).sum())
                count[i] += n
            predictions += 1
    if not predictions or not np.all(count > 0):
        msg = 'no tile has three frames or more to leave one out of; the PSF cannot be chosen from the frames.'
        raise SRError(msg)
    rms = np.sqrt(sse / count)
    best = int(np.argmin(rms))  # argmin takes the first (lowest sigma) of equal values
    return PsfChoice(sigma=rungs[best], ladder=rungs, rms=tuple(float(v) for v in rms), predictions=predictions)
