"""The SR tile kept within the range of the LR pixels around each HR pixel (``sr.clamp``): no ringing.

Where the PSF the solver assumes is wider than the frames' own (a flight's PSF chosen too wide, a
sharper lens or compression that ate the blur), (5.3) deconvolves more than the frames were blurred:
the LR-Nyquist band is boosted and every edge rings, a dark and a bright line beside it whose phase
follows the edge across the LR grid (the checkerboard or zipper along road edges and lane markings).
With too few frames or too little sub-pixel diversity the same band is left to the prior. Either
way the overshoot lies outside the intensities the frames show there.

The rule (as the mosaic's clamped bicubic, core/mosaic/resample.py): each HR pixel of the tile lies
between the least and the largest of the LR pixels around its LR point ``p = (u + 1/2) / s - 1/2``:
the 2 x 2 cell ``floor(p) .. floor(p) + 1`` (``'cell'``), or that cell grown by one LR pixel each
way, the 4 x 4 a bicubic reads (``'wide'``: leaves more of a thin line's peak, clamps less of the
ringing). The LR values are those of the frames' weighted average on the tile and of the reference
frame (the anchored tile follows the reference where it departs from the average: a car the mosaic
shows must not be clamped away). Edges stay sharp: a step between two LR pixels is a full-range
cell; only what lies beyond both sides is cut.

``'auto'`` (the default): ``'cell'`` where the PSF is given (``sr.psf_sigma``, the live node), ``'off'``
where the flight's PSF was chosen from its own frames by predicting held-out ones (core/sr/psf_select.py,
`process --sr`): that choice already rules out the PSF too wide whose ringing the clamp is for (a
ringing estimate predicts a frame it did not see worse, which is how the ladder tells the widths
apart), and the clamp then only cuts real detail: the peak of a thin line or of a leaf lies beyond
the LR pixels around it, which average it with its surroundings (bench/sr_video.py,
bench/sr_oracle.py, docs/results.md).

Convention: tensors (1, C, H, W) on the HR grid, (C, h, w) on the LR grid, H = s h; pixel centres
at integers (operators.lr_H_hr).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from .modes import CLAMP_MODES

__all__ = ['CLAMP_MODES', 'clamp_to_lr_range', 'lr_range_on_hr', 'resolve_clamp']


def resolve_clamp(mode: str, *, psf_chosen: bool) -> str:
    """The clamp applied: ``mode`` itself, or for 'auto' 'off' when the PSF was chosen from the frames
    and 'cell' when it is given (module docstring)."""
    if mode != 'auto':
        return mode
    return 'off' if psf_chosen else 'cell'


def _cell_index(n_hr: int, factor: int, device: torch.device) -> torch.Tensor:
    """(n_hr,) index into the LR axis padded by one pixel at its start: floor(p) + 1 of each HR pixel."""
    u = torch.arange(n_hr, dtype=torch.float64, device=device)
    return torch.floor((u + 0.5) / factor - 0.5).long() + 1


def lr_range_on_hr(lo: torch.Tensor, hi: torch.Tensor, factor: int, mode: str = 'cell',
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """(least, largest) (1, C, s h, s w) of the LR pixels ``lo``, ``hi`` (C, h, w) around each HR pixel.

    ``lo`` and ``hi`` are per-pixel bounds (the same image twice, or the least and largest of
    several); 'cell' takes them over the 2 x 2 cell of each HR pixel's LR point, 'wide' over that
    cell grown by one LR pixel each way. Beyond the LR grid its edge pixels are repeated.
    """
    if mode not in ('cell', 'wide'):
        msg = f"mode must be 'cell' or 'wide', got {mode!r}."
        raise ValueError(msg)
    c, h, w = lo.shape
    grow = 1 if mode == 'wide' else 0
    # pad so that padded index j + 1 + grow holds LR pixel j; windows of 2 + 2 grow, anchored at the top-left
    pad = (1 + grow, 1 + grow, 1 + grow, 1 + grow)
    k = 2 + 2 * grow
    lo_p = F.pad(lo[None], pad, mode='replicate')
    hi_p = F.pad(hi[None], pad, mode='replicate')
    cell_lo = -F.max_pool2d(-lo_p, k, stride=1)  # index j: the window starting at padded j
    cell_hi = F.max_pool2d(hi_p, k, stride=1)
    rows = _cell_index(h * factor, factor, lo.device)
    cols = _cell_index(w * factor, factor, lo.device)
    # the window starting at padded floor(p) + 1 covers LR floor(p) - grow .. floor(p) + 1 + grow
    out_lo = cell_lo[:, :, rows][:, :, :, cols]
    out_hi = cell_hi[:, :, rows][:, :, :, cols]
    return out_lo, out_hi


def clamp_to_lr_range(x: torch.Tensor, lr_images: list[torch.Tensor], factor: int, mode: str = 'cell') -> torch.Tensor:
    """``x`` (1, C, s h, s w) clamped to the range of the LR images (each (C, h, w)) around each HR
    pixel (:func:`lr_range_on_hr`); ``x`` itself for mode 'off'; 'auto' is 'cell' here (a PSF chosen
    from the frames is resolved by :func:`resolve_clamp` before)."""
    mode = resolve_clamp(mode, psf_chosen=False)
    if mode == 'off':
        return x
    stacked = torch.stack([im.to(x.dtype) for im in lr_images])
    lo, hi = lr_range_on_hr(stacked.amin(dim=0), stacked.amax(dim=0), factor, mode)
    return torch.maximum(torch.minimum(x, hi), lo)
