"""The frames that cover a tile, as a batched observation operator A = M D B W (5.1).

Convention: ``tile_H_frame`` maps LR frame pixel coordinates to LR tile pixel coordinates (pixel
centres at integers). The HR tile of factor s has ``(H s, W s)`` pixels, HR pixel ``(u, v)`` at LR
tile point ``((u + 0.5) / s - 0.5, (v + 0.5) / s - 0.5)``.

Each frame contributes the window of its LR pixels whose footprint can reach the tile (R: a crop of
the frame), padded to a common size so that all frames run as one batch. The HR frame grid behind
that window carries the PSF margin (``s (h - 1) + k`` samples for ``h`` LR rows and a PSF of side
``k``), so D B is a ``valid`` strided convolution. An LR pixel is observed (mask 1) only when every
HR sample under its PSF has all four bilinear neighbours inside the HR tile: the data term never
compares a frame pixel with a prediction that reads outside the tile.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from .dense_flow import sample_field
from .operators import BlurDecimate, LinearOperator, Warp, hr_H_lr

__all__ = ['FrameStack', 'ObservationOperator', 'build_frame_stack', 'frame_window']


def frame_window(tile_H_frame: np.ndarray, frame_shape: tuple[int, int], tile_shape: tuple[int, int],
                 pad: int = 1) -> tuple[int, int, int, int] | None:
    """LR window ``(y0, x0, h, w)`` of a frame that holds every pixel whose centre maps into the tile.

    The tile rectangle ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` is mapped into the frame and its bounding
    box grown by ``pad`` pixels and clipped to the frame; None when they do not overlap or the
    tile's corners fall behind the frame's horizon.
    """
    h_t, w_t = tile_shape
    corners = np.array([[-0.5, -0.5, 1], [w_t - 0.5, -0.5, 1], [w_t - 0.5, h_t - 0.5, 1], [-0.5, h_t - 0.5, 1]]).T
    q = np.linalg.inv(tile_H_frame) @ corners
    if np.any(q[2] <= 1e-12):
        return None
    fx, fy = q[0] / q[2], q[1] / q[2]
    hf, wf = frame_shape
    x0 = max(0, math.floor(fx.min()) - pad)
    y0 = max(0, math.floor(fy.min()) - pad)
    x1 = min(wf - 1, math.ceil(fx.max()) + pad)
    y1 = min(hf - 1, math.ceil(fy.max()) + pad)
    if x1 < x0 or y1 < y0:
        return None
    return (y0, x0, y1 - y0 + 1, x1 - x0 + 1)


class ObservationOperator(LinearOperator):
    """A x = M D B W x for all K frames at once: ``(1, C, H s, W s)`` -> ``(K, C, h, w)``.

    The adjoint ``W^T B^T D^T M r`` sums over the frames: ``(K, C, h, w)`` -> ``(1, C, H s, W s)``.
    """

    def __init__(self, warp: Warp, blur_decimate: BlurDecimate, mask: torch.Tensor) -> None:
        self.warp = warp
        self.blur_decimate = blur_decimate
        self.mask = mask

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return self.blur_decimate.apply(self.warp.apply(x)) * self.mask

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return self.warp.adjoint(self.blur_decimate.adjoint(y * self.mask))


@dataclass
class FrameStack:
    """The K frames that overlap a tile, cropped and batched.

    ``y`` (K, C, h, w) the LR windows, zero where ``mask`` is 0; ``crops`` the same windows
    unmasked; ``in_frame`` (K, 1, h, w) 1 on real frame pixels (0 on the batch padding);
    ``mask`` (K, 1, h, w) the observed pixels; ``windows`` (y0, x0, h, w) of each window in its
    frame; ``index`` the position of each frame in the caller's list; ``tile_H_windows`` (K, 3, 3)
    LR window pixels -> LR tile pixels; ``operator`` A; ``counts`` (K,) observed values per frame.
    """

    y: torch.Tensor
    crops: torch.Tensor
    in_frame: torch.Tensor
    mask: torch.Tensor
    windows: list[tuple[int, int, int, int]]
    index: list[int]
    tile_H_windows: np.ndarray
    operator: ObservationOperator
    counts: torch.Tensor


def build_frame_stack(frames: Sequence[torch.Tensor], tile_H_frames: Sequence[np.ndarray],
                      tile_shape: tuple[int, int], factor: int, psf: torch.Tensor, *,
                      min_observed: int = 16, flows: dict[int, torch.Tensor] | None = None,
                      confidence: dict[int, torch.Tensor] | None = None,
                      interpolation: str = 'bilinear') -> FrameStack | None:
    """Crop, pad and batch the frames that observe the tile; None when none does.

    ``frames``: tensors (C, h_k, w_k) on one device; ``tile_shape`` (H, W) LR; ``psf`` (k, k) on the
    HR grid with k of the parity of ``factor``. Frames with fewer than ``min_observed`` observed LR
    pixels are left out. ``flows``: per frame (its index in ``frames``) a residual flow (2, H, W) in LR
    tile pixels (core/sr/dense_flow.py: the frame's content seen at tile point p belongs at p - f(p)),
    which moves the warp's sampling points; ``confidence``: per frame (1, H, W) in [0, 1] on the tile,
    which weights the frame's LR pixels in the mask (and so in the data term). ``interpolation``: W's
    (operators.WARP_MODES).
    """
    s = int(factor)
    kh, kw = (int(v) for v in psf.shape)
    h_t, w_t = (int(v) for v in tile_shape)
    hr_tile = (h_t * s, w_t * s)
    device, dtype = frames[0].device, frames[0].dtype
    cand = []
    for i, (frame, m) in enumerate(zip(frames, tile_H_frames, strict=True)):
        win = frame_window(np.asarray(m, dtype=np.float64), (frame.shape[-2], frame.shape[-1]), tile_shape)
        if win is not None:
            cand.append((i, win))
    if not cand:
        return None
    hc = max(w[2] for _, w in cand)
    wc = max(w[3] for _, w in cand)
    hg, wg = s * (hc - 1) + kh, s * (wc - 1) + kw
    mats = []
    win_mats = []
    for i, (y0, x0, _, _) in cand:
        tile_H_frame = np.asarray(tile_H_frames[i], dtype=np.float64)
        frame_H_window = np.array([[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1]])
        # HR grid index j -> LR window coordinate j / s + (1 - k) / (2 s): LR pixel i's PSF taps are
        # the HR samples s i .. s i + k - 1, centred on the LR pixel centre.
        window_H_grid = np.array([[1.0 / s, 0, (1.0 - kw) / (2 * s)],
                                  [0, 1.0 / s, (1.0 - kh) / (2 * s)], [0, 0, 1]])
        tile_H_window = tile_H_frame @ frame_H_window
        win_mats.append(tile_H_window)
        mats.append(hr_H_lr(s) @ tile_H_window @ window_H_grid)
    warp = _refined_warp(mats, [i for i, _ in cand], hr_tile, (hg, wg), s, flows, device, dtype, interpolation)
    # Observed LR pixels: every HR sample under the PSF reads inside the HR tile. The tile maps to a
    # convex quadrilateral of the HR grid and the PSF support of LR pixel (i, j) is the rectangle of
    # grid samples [s i, s i + kh - 1] x [s j, s j + kw - 1], so its four corner samples decide.
    inside = warp.inside(1e-6)[:, 0] > 0
    hs, ws = s * (hc - 1) + 1, s * (wc - 1) + 1
    mask = (inside[:, 0:hs:s, 0:ws:s] & inside[:, kh - 1:kh - 1 + hs:s, 0:ws:s]
            & inside[:, 0:hs:s, kw - 1:kw - 1 + ws:s] & inside[:, kh - 1:kh - 1 + hs:s, kw - 1:kw - 1 + ws:s])
    mask = mask[:, None].to(dtype)
    c = frames[0].shape[0]
    crops = torch.zeros((len(cand), c, hc, wc), dtype=dtype, device=device)
    in_frame = torch.zeros((len(cand), 1, hc, wc), dtype=dtype, device=device)
    for k, (i, (y0, x0, h, w)) in enumerate(cand):
        crops[k, :, :h, :w] = frames[i][:, y0:y0 + h, x0:x0 + w]
        in_frame[k, :, :h, :w] = 1.0
    mask = mask * in_frame
    if confidence:
        mask = mask * _window_confidence(confidence, cand, win_mats, (hc, wc), mask)
    counts = mask.reshape(len(cand), -1).sum(dim=1).double() * c
    keep = [k for k in range(len(cand)) if counts[k] >= min_observed * c]
    if not keep:
        return None
    if len(keep) < len(cand):
        sel = torch.as_tensor(keep, device=device)
        warp = _refined_warp([mats[k] for k in keep], [cand[k][0] for k in keep], hr_tile, (hg, wg), s, flows,
                             device, dtype, interpolation)
        crops, in_frame, mask, counts = crops[sel], in_frame[sel], mask[sel], counts[sel]
        cand = [cand[k] for k in keep]
        win_mats = [win_mats[k] for k in keep]
    op = ObservationOperator(warp, BlurDecimate(psf.to(device=device, dtype=dtype), s), mask)
    return FrameStack(y=crops * mask, crops=crops, in_frame=in_frame, mask=mask,
                      windows=[w for _, w in cand], index=[i for i, _ in cand],
                      tile_H_windows=np.stack(win_mats), operator=op, counts=counts)


def _refined_warp(mats: Sequence[np.ndarray], index: Sequence[int], hr_tile: tuple[int, int],
                  grid_shape: tuple[int, int], s: int, flows: dict[int, torch.Tensor] | None,
                  device: torch.device, dtype: torch.dtype, interpolation: str = 'bilinear') -> Warp:
    """The homographies' warp, its points moved by each frame's residual flow (when given): the HR tile
    point u read for a grid sample becomes u - s f(lr(u)), f sampled bilinearly at u's LR tile point."""
    warp = Warp(np.stack(mats), hr_tile, grid_shape, device=device, dtype=dtype, interpolation=interpolation)
    if not flows or not any(i in flows for i in index):
        return warp
    px, py = warp.points
    offset = torch.zeros((*px.shape, 2), dtype=px.dtype, device=px.device)
    for k, i in enumerate(index):
        if i not in flows:
            continue
        f = flows[i].to(device=px.device, dtype=px.dtype)[None]
        lx, ly = (px[k:k + 1] + 0.5) / s - 0.5, (py[k:k + 1] + 0.5) / s - 0.5
        offset[k] = -s * sample_field(f, lx, ly)[0].permute(1, 2, 0)
    return warp.displace(offset)


def _window_confidence(confidence: dict[int, torch.Tensor], cand: Sequence[tuple[int, tuple[int, int, int, int]]],
                       win_mats: Sequence[np.ndarray], window_shape: tuple[int, int], like: torch.Tensor) -> torch.Tensor:
    """(K, 1, h, w) each frame's confidence (given on the LR tile) read at its LR window pixels' tile points."""
    hc, wc = window_shape
    out = torch.ones_like(like)
    ys, xs = torch.meshgrid(torch.arange(hc, dtype=torch.float64), torch.arange(wc, dtype=torch.float64), indexing='ij')
    pts = torch.stack([xs.reshape(-1), ys.reshape(-1), torch.ones(hc * wc, dtype=torch.float64)])
    for k, (i, _) in enumerate(cand):
        if i not in confidence:
            continue
        q = torch.as_tensor(win_mats[k], dtype=torch.float64) @ pts
        qx, qy = (q[0] / q[2]).reshape(1, hc, wc), (q[1] / q[2]).reshape(1, hc, wc)
        c = confidence[i].to(device=like.device, dtype=like.dtype)[None]
        out[k] = sample_field(c, qx.to(like.device, like.dtype), qy.to(like.device, like.dtype))[0]
    return out
