"""Which canvas tiles each still of a survey must be painted on.

A survey knows every still's place on the mosaic before it paints (the global solve), and its
compositor keeps, for each mosaic pixel, the still of largest feather weight (eq. 4.7; the weight is
geometry alone: closeness to the frame's centre), blended across seams. A still that ranks far
below the others over a whole tile changes nothing there but the feather average under the blend's
coarsest band; painting it costs as much as painting a winner. The plan: sample every tile on a
grid, rank the stills' weights at each sample, and paint a still on the tiles where it ranks among
the first ``rank`` at some sample of the tile or of its eight neighbours (the winner's region and its
seams, with a tile of margin for the blend), and on any tile where the stills so chosen would leave
some of its footprint uncovered (the mosaic's edges), so the mosaic's coverage is unchanged.

The plan assumes what the survey's canvas does: every still painted over its whole frame (no mask,
no far-field cut: max_stretch 0), with the canvas's feather profile as its weight (multiband).

Pixels: mosaic pixels (x right, y down, pixel centres at integers); frame pixels likewise, the
frame covering [-0.5, w - 0.5] x [-0.5, h - 0.5]; tile (tx, ty) covers x in [tx T, (tx + 1) T).
"""
from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

TileKey = tuple[int, int]


class PaintPlan(NamedTuple):
    """tiles: per still, the tile keys it is painted on; touched: the (still, tile) pairs its
    footprints touch, all told (what painting everything would cost)."""

    tiles: list[frozenset[TileKey]]
    touched: int

#: feather profiles the plan can rank by (the canvas's, blend._profile)
PROFILES = ('separable', 'distance')


def _weights(frame_H_mosaic: np.ndarray, xy: np.ndarray, w: int, h: int, profile: str) -> np.ndarray:
    """Feather weight (N,) of a (w, h) frame at mosaic points xy (N, 2), 0 outside the frame (the
    canvas's profile, blend._profile, evaluated at the point's frame coordinates)."""
    p = frame_H_mosaic @ np.c_[xy, np.ones(len(xy))].T
    with np.errstate(divide='ignore', invalid='ignore'):
        u, v = p[0] / p[2], p[1] / p[2]
    du = np.minimum(u + 1.0, w - u) / ((w + 1) // 2)
    dv = np.minimum(v + 1.0, h - v) / ((h + 1) // 2)
    inside = (p[2] > 0) & (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    out = np.minimum(du, dv) if profile == 'distance' else du * dv
    return np.where(inside, np.maximum(out, 1e-6), 0.0)


def _inside(frame_H_mosaic: np.ndarray, xy: np.ndarray, w: int, h: int, margin: float) -> np.ndarray:
    """bool (N,): mosaic points xy (N, 2) at least ``margin`` frame pixels inside the (w, h) frame."""
    p = frame_H_mosaic @ np.c_[xy, np.ones(len(xy))].T
    with np.errstate(divide='ignore', invalid='ignore'):
        u, v = p[0] / p[2], p[1] / p[2]
    lo = -0.5 + margin
    return (p[2] > 0) & (u >= lo) & (u <= w - 0.5 - margin) & (v >= lo) & (v <= h - 0.5 - margin)


def tiles_to_paint(mosaic_H_frames: list[np.ndarray], sizes: list[tuple[int, int]], tile_size: int, *,
                   rank: int = 2, samples_per_tile: int = 4, profile: str = 'separable',
                   margin_px: float = 2.0) -> PaintPlan:
    """The tiles each still is painted on (module docstring).

    Args:
        mosaic_H_frames: per still, (3, 3) frame pixel -> mosaic pixel (its footprint in front of the
            camera: every corner at positive depth).
        sizes: per still, (w, h) of the frame those homographies take.
        tile_size: the canvas's tile side T, mosaic pixels.
        rank: a still is kept where it is among the ``rank`` largest weights at a sample (>= 1).
        samples_per_tile: samples across and down each tile (>= 1).
        profile: the canvas's feather profile ('separable' or 'distance').
        margin_px: a tile counts as covered by a kept still only this far inside its frame (frame
            pixels), so interpolation at the footprint's edge leaves no pixel bare.

    Returns:
        PaintPlan: per still, a frozenset of tile keys (tx, ty) among those its footprint touches
        (empty for a footprint without area), and the number of (still, tile) pairs touched.
    """
    if rank < 1 or samples_per_tile < 1 or tile_size < 1:
        msg = f'rank, samples_per_tile and tile_size must be >= 1, got {rank}, {samples_per_tile}, {tile_size}.'
        raise ValueError(msg)
    if profile not in PROFILES:
        msg = f'profile must be one of {", ".join(PROFILES)}, got {profile!r}.'
        raise ValueError(msg)
    if len(mosaic_H_frames) != len(sizes):
        msg = f'{len(mosaic_H_frames)} homographies for {len(sizes)} sizes.'
        raise ValueError(msg)
    n = len(sizes)
    if n == 0:
        return PaintPlan([], 0)
    t, s = int(tile_size), int(samples_per_tile)
    inv = [np.linalg.inv(np.asarray(H, np.float64)) for H in mosaic_H_frames]
    quads = []
    for H, (w, h) in zip(mosaic_H_frames, sizes):
        # the canvas's support: bilinear sampling weighs mosaic pixels mapping inside (-1, w) x (-1, h)
        c = np.asarray(H, np.float64) @ np.array([[-1.0, w, w, -1.0], [-1.0, -1.0, h, h], [1.0] * 4])
        quads.append((c[:2] / c[2]).T)
    lo = np.floor(np.min([q.min(axis=0) for q in quads], axis=0) / t).astype(int)
    hi = np.floor(np.max([q.max(axis=0) for q in quads], axis=0) / t).astype(int)
    nx, ny = hi - lo + 1
    # sample grid: s x s points per tile, (ny s, nx s)
    offs = (np.arange(s) + 0.5) * t / s
    gx = (lo[0] + np.arange(nx))[:, None] * t + offs[None, :]
    gy = (lo[1] + np.arange(ny))[:, None] * t + offs[None, :]
    gx, gy = gx.ravel(), gy.ravel()
    top_w = np.zeros((rank, ny * s, nx * s))
    top_id = np.full((rank, ny * s, nx * s), -1, np.int64)
    boxes = []
    for k, (q, (w, h)) in enumerate(zip(quads, sizes)):
        bx0, by0 = np.clip(np.floor(q.min(axis=0) / t).astype(int) - lo, 0, [nx - 1, ny - 1])
        bx1, by1 = np.clip(np.floor(q.max(axis=0) / t).astype(int) - lo, 0, [nx - 1, ny - 1])
        boxes.append((bx0, by0, bx1, by1))
        ys, xs = slice(by0 * s, (by1 + 1) * s), slice(bx0 * s, (bx1 + 1) * s)
        X, Y = np.meshgrid(gx[xs], gy[ys])
        wk = _weights(inv[k], np.c_[X.ravel(), Y.ravel()], w, h, profile).reshape(X.shape)
        # insert into the sorted top-rank lists (largest first; ties keep the earlier still, as the canvas)
        cur_w, cur_id = wk, np.full(wk.shape, k, np.int64)
        for r in range(rank):
            tw, ti = top_w[r, ys, xs], top_id[r, ys, xs]
            swap = cur_w > tw
            new_w, new_id = np.where(swap, cur_w, tw), np.where(swap, cur_id, ti)
            cur_w, cur_id = np.where(swap, tw, cur_w), np.where(swap, ti, cur_id)
            top_w[r, ys, xs], top_id[r, ys, xs] = new_w, new_id
    # per tile, the stills ranked at one of its samples
    ranked = top_id.reshape(rank, ny, s, nx, s).transpose(1, 3, 0, 2, 4).reshape(ny, nx, -1)
    kept = np.zeros((n, ny, nx), bool)
    for k in range(n):
        hit = (ranked == k).any(axis=2)
        if hit.any():  # dilated by a tile: the seams' blend reaches past the sample grid
            kept[k] = cv2.dilate(hit.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    def tile_rect(tx: int, ty: int) -> np.ndarray:
        """float32 (4, 2) corners of grid tile (tx, ty) (pixel edges at half integers)."""
        x0, y0 = (lo[0] + tx) * t - 0.5, (lo[1] + ty) * t - 0.5
        return np.array([[x0, y0], [x0 + t, y0], [x0 + t, y0 + t], [x0, y0 + t]], np.float32)

    # tiles each footprint touches (a tile's corners, centre and the quad's vertices tested)
    touches = np.zeros((n, ny, nx), bool)
    for k, (bx0, by0, bx1, by1) in enumerate(boxes):
        poly = quads[k].astype(np.float32)
        for ty in range(by0, by1 + 1):
            for tx in range(bx0, bx1 + 1):
                area, _ = cv2.intersectConvexConvex(poly, tile_rect(tx, ty))
                touches[k, ty, tx] = area > 0
    kept &= touches
    # coverage: a touched tile where no kept still covers the footprint's part in it keeps that still
    for ty in range(ny):
        for tx in range(nx):
            users = np.flatnonzero(touches[:, ty, tx])
            if users.size == 0:
                continue
            chosen = [k for k in users if kept[k, ty, tx]]
            rect = tile_rect(tx, ty)
            if any(_inside(inv[k], rect.astype(np.float64), *sizes[k], margin_px).all() for k in chosen):
                continue  # the whole tile inside one kept still
            for k in users:
                if kept[k, ty, tx]:
                    continue
                _, part = cv2.intersectConvexConvex(quads[k].astype(np.float32), rect)
                if part is None:
                    continue
                pts = part.reshape(-1, 2).astype(np.float64)
                if not any(_inside(inv[j], pts, *sizes[j], margin_px).all() for j in chosen):
                    kept[k, ty, tx] = True
                    chosen.append(k)
    tiles = [frozenset((int(lo[0] + tx), int(lo[1] + ty)) for ty, tx in zip(*np.nonzero(kept[k]))) for k in range(n)]
    return PaintPlan(tiles, int(touches.sum()))
