"""SR that never loses to the best single frame: a tile SR cannot improve shows that frame upsampled.

The baseline that counts for an SR tile is its best single frame, upsampled: the reference (the
frame whose centre lands nearest the tile's, the one the best-view mosaic shows there and the SR
tile is anchored to), its LR pixels sampled bicubically at the HR tile's points
(:func:`frame_upsampled`). Whether SR improves on it is decided per tile without any truth, by
predicting frames SR did not see (the leave-one-out of self_check.py): the tile is solved from its
frames less the ``holdouts`` nearest the tile after the reference, and each frame j left out is
predicted by SR through its own observation model (5.1) and by the best frame alone, its LR pixels
on the tile resampled at frame j's pixels (as self_check.py resamples the mosaic):

    e_sr = || M_j (y_j - D B W_j x_sr) ||^2,    e_frame = || M_j (y_j - W_j^LR y_ref) ||^2.

The frame's prediction goes through no PSF, so a PSF chosen wrong charges SR alone. Frame j sees
the ground at sub-pixel offsets no frame of the solve had, so detail that is not the ground's
(ringing, a zipper, a ghost, a misfit) predicts it worse than the plain frame does, and real detail
predicts it better. In the frames' own band the plain frame is a strong predictor (a held-out frame
is mostly the reference resampled: same blur, its own noise), and SR made with the right PSF often
predicts it only about as well (bench: within 10 %), while a ringing or misfit estimate predicts it
far worse (1.3 to 3 times the RMS); so the tile keeps SR unless its RMS exceeds the frame's by more
than ``HELD_OUT_TOLERANCE``, and then falls back to the reference upsampled. What the frames cannot
see (detail in the PSF's null space) the check cannot either: the ringing clamp (ringing.py) guards
that band. A tile SR cannot serve at all (its frames disagree,
its reference is the odd one out, the solve fails) falls back too. Never to the mosaic's bicubic,
which is below a single frame wherever the canvas resampled the frame.

Convention: frames (h, w[, C]) as :func:`.reconstruct.reconstruct_tile` takes them; tile_H_frames
LR frame pixels -> LR tile pixels, pixel centres at integers; HR pixel (u, v) shows LR tile point
((u + 0.5) / s - 0.5, (v + 0.5) / s - 0.5) (operators.lr_H_hr).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import torch

from ..device import resolve_device
from .observation import build_frame_stack
from .operators import Warp, gaussian_psf, lr_H_hr
from .reconstruct import SRConfig, SRError, SRFramesDisagree, SRResult, _frames_to_tensors, reconstruct_tile
from .self_check import _holdout_order

__all__ = ['FALLBACK_REASONS', 'HELD_OUT_TOLERANCE', 'TileOutcome', 'frame_upsampled', 'held_out_against_frame', 'super_resolve_or_fallback']

#: SR is kept while its held-out RMS is at most this many times the best frame's (module docstring).
HELD_OUT_TOLERANCE = 1.2
#: Why a tile shows its best frame upsampled instead of SR (tiles.json "fallback").
FALLBACK_REASONS = ('held_out_worse_than_frame', 'frames_disagree', 'sr_failed')


@dataclass
class TileOutcome:
    """What one tile shows.

    image: (H s, W s, C) float32 in [0, 1]; result: the SR solve (None when it fell back before or
    instead of one); fallback: '' (SR kept) or one of FALLBACK_REASONS; detail: the sentence saying
    why; held_out_rms: grey levels (0..255) of predicting the held-out frames from SR, from the best
    frame's upsampling and from the LR mosaic ({} when none was held out); reference: the index of the
    best frame.
    """

    image: np.ndarray
    result: SRResult | None
    fallback: str = ''
    detail: str = ''
    held_out_rms: dict[str, float] = field(default_factory=dict)
    reference: int = 0


def frame_upsampled(frame: np.ndarray, tile_H_frame: np.ndarray, tile_shape: tuple[int, int], factor: int) -> np.ndarray:
    """The frame's LR pixels sampled bicubically at the HR tile's points: (H s, W s, C) float32 in [0, 1].

    frame: (h, w[, C]) uint8 or float in [0, 1]; tile_shape (H, W) LR tile pixels. Beyond the
    frame its edge pixels are repeated (a planned tile lies inside its frames).
    """
    img = np.asarray(frame)
    img = img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img.astype(np.float32)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    h, w = (int(v) * int(factor) for v in tile_shape)
    frame_H_hr = np.linalg.inv(np.asarray(tile_H_frame, dtype=np.float64)) @ lr_H_hr(factor)
    out = cv2.warpPerspective(img, frame_H_hr, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REPLICATE)
    return np.clip(out.reshape(h, w, -1), 0.0, 1.0)


def held_out_against_frame(frames: Sequence[np.ndarray], tile_H_frames: Sequence[np.ndarray], tile_shape: tuple[int, int],
                           factor: int, config: SRConfig, *, holdouts: int = 1,
                           reference: int | None = None) -> dict[str, float] | None:
    """Sums of squared errors (intensity^2 over channels) of predicting up to ``holdouts`` held-out
    frames (module docstring) from the SR estimate of the others (``sr``), from the reference's LR
    pixels resampled at theirs (``frame``) and from the others' LR mosaic resampled at their pixels (``mosaic``),
    over the ``n`` values all three predict. None when no frame could be held out (fewer than three
    frames, or the others cannot be solved). ``reference``: the best frame's index (default: the
    nearest, as :func:`super_resolve_or_fallback`)."""
    if len(frames) < 3 or holdouts < 1:
        return None
    order = [int(v) for v in _holdout_order(frames, tile_H_frames, tile_shape)]
    if reference is not None:
        order = [reference] + [k for k in order if k != reference]
    ref = order[0]
    device = resolve_device(config.device)
    s = int(factor)
    # the best frame on the LR tile grid (bicubic), resampled at the held-out frame's pixels as the mosaic is
    ref_lr = torch.as_tensor(frame_upsampled(frames[ref], tile_H_frames[ref], tile_shape, 1).transpose(2, 0, 1).copy(),
                             device=device)
    sums = {'sr': 0.0, 'frame': 0.0, 'mosaic': 0.0, 'n': 0.0}
    psf = gaussian_psf(config.psf_sigma * s, s, device=device)
    for j in (int(v) for v in order[1:1 + holdouts]):
        others = [k for k in range(len(frames)) if k != j]
        try:
            res = reconstruct_tile([frames[k] for k in others], [tile_H_frames[k] for k in others], tile_shape, s,
                                   config=config, reference=others.index(ref))
        except SRError:
            continue
        stack = build_frame_stack(_frames_to_tensors([frames[j]], device), [np.asarray(tile_H_frames[j])], tile_shape,
                                  s, psf, min_observed=1, interpolation=config.warp)
        if stack is None or stack.crops.shape[1] != res.image.shape[0] or ref_lr.shape[0] != res.image.shape[0]:
            continue
        dtype = stack.crops.dtype
        by_sr = stack.operator.apply(res.image[None].to(dtype))
        to_window = Warp(np.asarray(stack.tile_H_windows, dtype=np.float64), tuple(res.lr_mosaic.shape[-2:]),
                         tuple(stack.crops.shape[-2:]), device=device, dtype=dtype, shared=False)
        by_mosaic = to_window.apply(res.lr_mosaic[None].to(dtype))
        by_frame = to_window.apply(ref_lr[None].to(dtype))
        mask = stack.mask * (to_window.inside(1e-5) > 0).to(stack.mask.dtype)
        for key, pred in (('sr', by_sr), ('frame', by_frame), ('mosaic', by_mosaic)):
            sums[key] += float((((pred - stack.crops) ** 2) * mask).sum())
        sums['n'] += float(mask.sum()) * stack.crops.shape[1]
    return sums if sums['n'] > 0 else None


def super_resolve_or_fallback(frames: Sequence[np.ndarray], tile_H_frames: Sequence[np.ndarray],
                              tile_shape: tuple[int, int], factor: int, config: SRConfig, *,
                              holdouts: int = 1, reference: int | None = None) -> TileOutcome:
    """The tile as `process --sr` writes it: SR when it predicts held-out frames about as well as the
    best frame does or better, else that frame upsampled (module docstring); ``holdouts`` 0: only a
    tile SR cannot serve falls back. ``reference``: the best frame's index into ``frames`` (default:
    the one whose centre lands nearest the tile's). Never raises SRError for a tile its frames observe."""
    s = int(factor)
    if not frames:
        msg = 'no frame covers this tile.'
        raise SRError(msg)
    ref = int(_holdout_order(frames, tile_H_frames, tile_shape)[0]) if reference is None else int(reference)
    fallback_image = frame_upsampled(frames[ref], tile_H_frames[ref], tile_shape, s)

    def fall_back(reason: str, detail: str, rms: dict[str, float] | None = None) -> TileOutcome:
        return TileOutcome(fallback_image, None, reason, detail, rms or {}, ref)

    rms: dict[str, float] = {}
    if holdouts > 0:
        check = replace(config, device=str(resolve_device(config.device)))
        try:
            sums = held_out_against_frame(frames, tile_H_frames, tile_shape, s, check, holdouts=holdouts, reference=ref)
        except SRError:
            sums = None
        if sums is not None:
            rms = {k: round(255.0 * float(np.sqrt(sums[k] / sums['n'])), 3) for k in ('sr', 'frame', 'mosaic')}
            if sums['sr'] > HELD_OUT_TOLERANCE**2 * sums['frame']:
                return fall_back('held_out_worse_than_frame',
                                 f'SR of the other frames predicts a frame left out worse than the best frame '
                                 f'does (RMS {rms["sr"]:.2f} against {rms["frame"]:.2f} grey levels): its '
                                 'detail is not the ground\'s; the tile shows the best frame upsampled (bicubic).', rms)
    try:
        res = reconstruct_tile(frames, tile_H_frames, tile_shape, s, config=config, reference=ref)
    except SRFramesDisagree as exc:
        return fall_back('frames_disagree', f'{exc} The tile shows the best frame upsampled (bicubic).', rms)
    except SRError as exc:
        return fall_back('sr_failed', f'{exc} The tile shows the best frame upsampled (bicubic).', rms)
    res.held_out_rms = (rms.get('sr', float('nan')), rms.get('mosaic', float('nan')))
    image = np.clip(res.image.detach().cpu().numpy().transpose(1, 2, 0), 0.0, 1.0).astype(np.float32)
    return TileOutcome(image, res, '', '', rms, ref)
