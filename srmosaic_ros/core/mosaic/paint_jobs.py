"""The tiles one paint writes and the frame's colour over them.

A paint warps the frame's weight over the box of mosaic pixels its footprint touches (or over the
rectangles asked for in each tile), keeps the tiles where that weight is non-zero (the jobs: tile
key, slices of the box, slices of the tile) and warps the colour over the box, or tile by tile.
"""
from __future__ import annotations

from collections.abc import Collection

import cv2
import numpy as np

from .frame_cut import PaintJob
from .paint_ops import to_float
from .resample import FrameSampler
from .scratch import scratch
from .tile_store import TileKey

__all__ = ['box_jobs', 'rect_weights', 'warp_colour']


def rect_weights(weight: np.ndarray, box_h_frame: np.ndarray, rects: dict[TileKey, tuple[int, int, int, int]],
                 placement: tuple[int, int, int, int], t: int,
                 ) -> list[tuple[TileKey, tuple[slice, slice], tuple[slice, slice], tuple[int, int, int, int], np.ndarray]]:
    """Jobs of a paint in part: (tile, box slices, tile slices, tight mosaic box (x0, y0, x1, y1) of
    non-zero weight, the warped weight over the box): the weight (frame-sized float32, warped
    through ``box_h_frame``, whose box starts at ``placement``'s corner) over each tile's
    asked-for box of ``rects`` within ``placement``, where it is non-zero somewhere (tiles of side ``t``).

    A frame painted in part (held back where it reaches beyond its neighbours) is asked for slivers at
    its footprint's edges, often at opposite corners, so the weight is warped over each box alone,
    not over the box around them all."""
    x0, y0, x1, y1 = placement
    out = []
    for (tx, ty), (rx0, ry0, rx1, ry1) in sorted(rects.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        xs, xe = max(x0, rx0, tx * t), min(x1, rx1, (tx + 1) * t)
        rs, re_ = max(y0, ry0, ty * t), min(y1, ry1, (ty + 1) * t)
        if xs >= xe or rs >= re_:
            continue
        m = np.array([[1.0, 0.0, x0 - xs], [0.0, 1.0, y0 - rs], [0.0, 0.0, 1.0]]) @ box_h_frame
        sub = cv2.warpPerspective(weight, m, (xe - xs, re_ - rs), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        c0, r0, nc, nr = cv2.boundingRect((sub != 0).view(np.uint8))
        if nc == 0:
            continue
        box = (slice(rs - y0, re_ - y0), slice(xs - x0, xe - x0))
        loc = (slice(rs - ty * t, re_ - ty * t), slice(xs - tx * t, xe - tx * t))
        out.append(((tx, ty), box, loc, (xs + c0, rs + r0, xs + c0 + nc, rs + r0 + nr), sub))
    return out


def warp_colour(src: FrameSampler, box_h_frame: np.ndarray, box: tuple[slice, slice], gains: np.ndarray | None,
                name: str, channels: int) -> np.ndarray:
    """float32 (h, w, C) colour of the frame ``src`` (float32, or uint8: warped as integers, then
    converted with ``gains``) over ``box`` (slices of the paint's box, whose homography from the
    frame is ``box_h_frame``), in this thread's scratch array ``name`` (C: ``channels``)."""
    ys, xs = box
    h, w, c = ys.stop - ys.start, xs.stop - xs.start, channels
    m = np.array([[1.0, 0.0, -xs.start], [0.0, 1.0, -ys.start], [0.0, 0.0, 1.0]]) @ box_h_frame
    if src.src.dtype == np.uint8:  # gains (if any) applied after the warp
        return to_float(src.warp(m, (w, h)), gains, scratch(name, (h, w, c)))
    return src.warp(m, (w, h), dst=scratch(name, (h, w, *src.src.shape[2:])))


def box_jobs(w_w: np.ndarray, origin: tuple[int, int], tight: tuple[int, int, int, int], t: int,
             tiles: Collection[TileKey] | None, rects: dict[TileKey, tuple[int, int, int, int]] | None) -> list[PaintJob]:
    """The tiles of side ``t`` a paint writes, with their slices of the paint's box (whose corner is at
    mosaic pixel ``origin``) and their own: those the tight box (x0, y0, x1, y1) of non-zero warped
    weight ``w_w`` (over the paint's box) overlaps, among ``tiles`` (None: any), within their
    rectangles of ``rects`` (None: whole), where ``w_w`` is non-zero."""
    x0, y0 = origin
    gx0, gy0, gx1, gy1 = tight
    jobs: list[PaintJob] = []
    for ty in range(gy0 // t, (gy1 - 1) // t + 1):
        ys, ye = max(gy0, ty * t), min(gy1, (ty + 1) * t)
        for tx in range(gx0 // t, (gx1 - 1) // t + 1):
            if tiles is not None and (tx, ty) not in tiles:
                continue
            xs, xe = max(gx0, tx * t), min(gx1, (tx + 1) * t)
            rs, re_ = ys, ye
            if rects is not None:
                rx0, ry0, rx1, ry1 = rects[(tx, ty)]
                xs, xe, rs, re_ = max(xs, rx0), min(xe, rx1), max(rs, ry0), min(re_, ry1)
                if xs >= xe or rs >= re_:
                    continue
            box = (slice(rs - y0, re_ - y0), slice(xs - x0, xe - x0))
            if not w_w[box].any():
                continue
            loc = (slice(rs - ty * t, re_ - ty * t), slice(xs - tx * t, xe - tx * t))
            jobs.append(((tx, ty), box, loc))
    return jobs
