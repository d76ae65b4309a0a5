"""Moving objects out of the SR data term: per-pixel weights of the frames that observe a tile.

A car that crosses the tile is in a few of the K frames; the data term (5.3) would fit the
estimate to all of them and leave a dark or bright trail along its path. Each frame's pixels are
compared, in the LR tile, with the per-pixel median of the frames that cover them (the background,
as in the mosaic's vote, core/mosaic/best_view.py): where at least MIN_FRAMES frames cover a pixel
and a frame differs from the median by more than ``threshold`` (the luminance difference averaged
over 3 x 3 LR pixels, after the frame's median difference over the tile is taken out: a change of
exposure is not motion), that frame saw something move there. Those pixels, grown by one LR
pixel and brought back to the frame's own LR grid, get weight 0 in the data term (the observation
mask M of A = M D B W): an iteratively reweighted least squares step with a 0 / 1 weight, taken
once before the solve.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from .observation import FrameStack
from .operators import Warp

__all__ = ['MIN_FRAMES', 'moving_mask']

#: Frames that must cover an LR tile pixel before their median is taken as its background.
MIN_FRAMES = 3


def moving_mask(stack: FrameStack, warped_luma: torch.Tensor, covered: torch.Tensor, kept: torch.Tensor,
                threshold: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``(in_tile (K, 1, H, W), in_window (K, 1, h, w))`` float 0 / 1: 1 where the frame saw something
    move (module docstring), in the LR tile and in each frame's LR window (``stack.crops``'s grid).
    ``warped_luma`` (K, 1, H, W) and ``covered`` (K, 1, H, W)
    the frames in the LR tile (reconstruct.warp_frames_to_tile); ``kept`` the indices of the frames
    that take part (the consistency test's); ``threshold`` intensity in [0, 1]."""
    k = warped_luma.shape[0]
    cov = covered > 0.5
    sel = torch.zeros(k, dtype=torch.bool, device=cov.device)
    sel[kept] = True
    cov = cov & sel.view(-1, 1, 1, 1)
    values = torch.where(cov, warped_luma, torch.full_like(warped_luma, float('nan')))
    background = torch.nanmedian(values, dim=0).values                      # (1, H, W)
    enough = cov.sum(dim=0) >= MIN_FRAMES                                    # (1, H, W)
    known = cov & enough[None]
    delta = torch.where(known, warped_luma - background[None], torch.zeros_like(warped_luma))
    for i in range(k):  # each frame's exposure offset: its median difference where known
        if bool(known[i].any()):
            delta[i] = torch.where(known[i], delta[i] - delta[i][known[i]].median(), delta[i])
    mean = F.avg_pool2d(delta, 3, stride=1, padding=1, count_include_pad=False).abs()
    moved = (known & (mean > threshold)).to(warped_luma.dtype)
    moved = F.max_pool2d(moved, 3, stride=1, padding=1)                      # grown by one LR pixel
    # back to each frame's window: window pixel -> tile pixel (tile_H_windows), any overlap counts
    hc, wc = stack.crops.shape[-2:]
    back = Warp(np.asarray(stack.tile_H_windows, dtype=np.float64), tuple(moved.shape[-2:]), (hc, wc),
                device=moved.device, dtype=moved.dtype, shared=False)
    return moved, (back.apply(moved) > 1e-3).to(warped_luma.dtype)
