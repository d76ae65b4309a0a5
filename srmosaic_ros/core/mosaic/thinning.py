"""Paint thinning: at video rates consecutive frames see nearly the same ground; painting each costs
the mosaic's largest share of the work and adds next to nothing to a best-view composite.

A placed frame is painted when its segment has none painted yet, when its footprint's corners moved
at least ``shift_px`` mosaic pixels from those of the last frame painted in its segment, or when
``stride - 1`` frames in a row were held back; otherwise it is held back. When the next frame of the
segment is painted, each frame held back is painted where its footprint reaches beyond the two
painted around it (a gust's sideways jitter at the swath's edge: per tile, the box of those pixels
and MARGIN_PX more), and nowhere else: its ground lies between theirs. The frames held back at the end of a segment are painted whole when
another segment paints, and at the end (:meth:`PaintThinning.release`). Every frame is still
registered, placed and fused; only its pixels are left to its neighbours'.

The caller decides which frames may be held back at all (Pipeline: near-nadir views only, whose
neighbours see the ground as they do; an oblique view's parallax and far field make each view count).

Footprints are convex polygons (N, 2) in mosaic pixels (x right, y down), as the canvas paints them
(its far-field cut included); tile (tx, ty) covers x in [tx T, (tx + 1) T).
"""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np

__all__ = ['MARGIN_PX', 'PaintThinning']

#: a frame painted where it reaches beyond its neighbours is painted this many pixels further
#: (mosaic pixels): its seam with them is blended, not cut at its own edge
MARGIN_PX = 4


def _inside(points: np.ndarray, polygon: np.ndarray) -> bool:
    """Whether every point (N, 2) lies inside the convex ``polygon`` (M, 2) or on its border."""
    poly = polygon.astype(np.float32).reshape(-1, 1, 2)
    return all(cv2.pointPolygonTest(poly, (float(x), float(y)), False) >= 0 for x, y in points)


class PaintThinning:
    """Which placed frames are painted, and where (module docstring). ``stride`` 1 paints every frame."""

    def __init__(self, stride: int, shift_px: float, tile_size: int = 256) -> None:
        if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1 or not shift_px >= 0.0 \
                or not tile_size >= 1:
            msg = (f'paint thinning needs an integer stride >= 1, shift_px >= 0 and tile_size >= 1, got {stride!r}, '
                   f'{shift_px!r}, {tile_size!r}.')
            raise ValueError(msg)
        self.stride = stride
        self.shift_px = float(shift_px)
        self.tile_size = int(tile_size)
        # segment -> (corners (4, 2), footprint (N, 2) of its last painted frame, frames held since)
        self._last: dict[int, tuple[np.ndarray, np.ndarray, int]] = {}
        self._held: dict[int, list[tuple[Any, np.ndarray]]] = {}  # segment -> [(frame, footprint)] held back
        self.thinned = 0  # frames left wholly unpainted so far (frames held back count until painted)
        self.in_part = 0  # frames held back, then painted on the tiles where they reach beyond their neighbours

    def offer(self, segment: int, item: Any, corners: np.ndarray, footprint: np.ndarray, *,
              force: bool = False) -> list[tuple[Any, Any]]:
        """What to paint now for a frame ``item`` of ``segment`` placed with frame ``corners`` (4, 2)
        and ``footprint`` (N, 2) in mosaic pixels: [(frame, tiles)] in order, tiles None for the
        whole frame or {tile key: (x0, y0, x1, y1) mosaic pixels to paint in it}
        (TiledCanvas.paint's ``tiles``): the frames held back by other segments, this
        segment's frames held back where they reach beyond their painted neighbours, then ``item``
        (unless it is held back; ``force``: never)."""
        out = [(frame, None) for key in [k for k in self._held if k != segment] for frame, _ in self._held.pop(key)]
        self.thinned -= len(out)
        if self.stride == 1:
            return [*out, (item, None)]
        corners = np.asarray(corners, np.float64)
        last = self._last.get(segment)
        if not force and last is not None and last[2] + 1 < self.stride \
                and float(np.abs(corners - last[0]).max()) < self.shift_px:
            self._held.setdefault(segment, []).append((item, footprint))
            self._last[segment] = (last[0], last[1], last[2] + 1)
            self.thinned += 1
            return out
        for frame, fp in self._held.pop(segment, []):
            tiles = self._beyond(fp, last[1], footprint) if last is not None else None
            if tiles is None or tiles:
                out.append((frame, tiles))
                self.thinned -= 1
                self.in_part += tiles is not None
        self._last[segment] = (corners, np.asarray(footprint, np.float64), 0)
        return [*out, (item, None)]

    def _beyond(self, footprint: np.ndarray, before: np.ndarray, after: np.ndarray) -> dict[tuple[int, int], tuple[int, int, int, int]]:
        """{tile: (x0, y0, x1, y1)}: where ``footprint`` reaches more than a pixel beyond both
        ``before`` and ``after``, per tile the box of those pixels widened by MARGIN_PX (the blend
        across the seam; clipped to the tile)."""
        fp = np.asarray(footprint, np.float64)
        if _inside(fp, before) or _inside(fp, after):
            return {}
        x0, y0 = np.floor(fp.min(axis=0)).astype(int) - 1
        x1, y1 = np.ceil(fp.max(axis=0)).astype(int) + 2
        shape = (y1 - y0, x1 - x0)

        def mask(poly: np.ndarray) -> np.ndarray:
            m = np.zeros(shape, np.uint8)
            pts = np.round((np.asarray(poly, np.float64) - (x0, y0)) * 16).astype(np.int32)  # 4 fractional bits
            cv2.fillConvexPoly(m, pts, 1, lineType=cv2.LINE_8, shift=4)
            return m

        covered = cv2.bitwise_or(mask(before), mask(after))
        inner = cv2.erode(mask(fp), np.ones((3, 3), np.uint8))  # its edge pixels: rounding, not ground
        beyond = cv2.subtract(inner, covered)  # 1 where it sees ground neither neighbour sees
        if not cv2.countNonZero(beyond):
            return {}
        # Per tile the box of those pixels: cv2.boundingRect of the tile's part of the mask (a C pass
        # over the few tiles the footprint spans, not a Python pass over its pixels).
        t, out = self.tile_size, {}
        for ty in range(y0 // t, (y1 - 1) // t + 1):
            for tx in range(x0 // t, (x1 - 1) // t + 1):
                ax, ay = max(tx * t, x0), max(ty * t, y0)
                part = beyond[ay - y0:min((ty + 1) * t, y1) - y0, ax - x0:min((tx + 1) * t, x1) - x0]
                bx, by, bw, bh = cv2.boundingRect(part)
                if bw == 0:
                    continue
                lo_x, lo_y = ax + bx, ay + by
                out[(tx, ty)] = (max(lo_x - MARGIN_PX, tx * t), max(lo_y - MARGIN_PX, ty * t),
                                 min(lo_x + bw + MARGIN_PX, (tx + 1) * t), min(lo_y + bh + MARGIN_PX, (ty + 1) * t))
        return out

    def release(self) -> list[tuple[Any, Any]]:
        """The frames held back, [(frame, None)] to paint whole now: the end of the input."""
        out = [(frame, None) for held in self._held.values() for frame, _ in held]
        self.thinned -= len(out)
        self._held.clear()
        return out
