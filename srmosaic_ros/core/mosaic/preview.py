"""Downscaled previews of the mosaic canvas (``TiledCanvas.render_preview``).

A preview reduces the canvas by a factor f that divides the tile size, so each tile's block sums
(``block_sums``) can be cached and recomputed only for tiles painted since the previous preview;
``assemble`` places the cached sums on the preview grid and divides them (the feather blend of each
block). The cache itself stays on the canvas (it is pickled with it).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from .blend import feather_divide

if TYPE_CHECKING:
    from .tile_store import Tile, TileKey

__all__ = ['assemble', 'block_sums', 'preview_factor']


def preview_factor(bounds: tuple[int, int, int, int], tile_size: int, max_side: int) -> int:
    """The smallest divisor f of ``tile_size`` with longer side of ``bounds`` / f <= ``max_side``
    (``tile_size`` when none is large enough)."""
    x0, y0, x1, y1 = bounds
    t = tile_size
    need = max(x1 - x0, y1 - y0) / int(max_side)
    return next((d for d in range(1, t + 1) if t % d == 0 and d >= need), t)


def block_sums(tile: Tile, f: int, tile_size: int, channels: int) -> tuple[np.ndarray, np.ndarray]:
    """Sums over f x f blocks of a tile's colour, (T/f, T/f, C), and weight, (T/f, T/f), float32.

    Feather and multiband tiles: ``acc`` and ``wsum``; best-view tiles: the winners' pixels
    (``best`` where ``best_id >= 0``) with weight 1, so the preview shows their block means.
    """
    c = channels
    n = tile_size // f
    if tile.best_view_tile:  # best view: the block means of the winners' pixels
        seen = (tile.best_id >= 0).astype(np.float32)
        acc, wts = tile.best * seen[..., None], seen
    else:
        acc, wts = tile.acc, tile.wsum
    return _sums(acc, f, n, c).reshape(n, n, c), _sums(wts, f, n, 1).reshape(n, n)


def _sums(a: np.ndarray, f: int, n: int, c: int) -> np.ndarray:
    """Sums over f x f blocks of ``a`` (T, T[, c]) float32, a new array: OpenCV's area average
    times f^2 (a twentieth of the time of numpy's strided reduction at f = 2, and outside the GIL: the live
    preview holds the pipeline while it runs), numpy's beyond OpenCV's 4 channels."""
    if f == 1:
        return np.array(a, np.float32)
    if c > 4:
        return a.reshape(n, f, n, f, c).sum(axis=(1, 3), dtype=np.float32)
    out = cv2.resize(np.ascontiguousarray(a, np.float32), (n, n), interpolation=cv2.INTER_AREA)
    return np.multiply(out, np.float32(f * f), out=out)


def assemble(sums: dict[TileKey, tuple[np.ndarray, np.ndarray]], bounds: tuple[int, int, int, int], f: int,
             tile_size: int, channels: int, background: np.float32,
             ) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int]]:
    """The preview of ``bounds`` from the tiles' block sums ``sums`` at factor ``f``.

    Returns ``(image, covered, region)``: image float32 (h, w, C) with ``background`` where no
    block is covered, covered bool (h, w), and region (x0, y0, width, height), the mosaic pixels
    the preview covers (f times its size from (bounds x0 // f * f, bounds y0 // f * f)).
    """
    x0, y0, x1, y1 = bounds
    c = channels
    n = tile_size // f
    gx0, gy0, gx1, gy1 = x0 // f, y0 // f, -(-x1 // f), -(-y1 // f)
    region = (gx0 * f, gy0 * f, (gx1 - gx0) * f, (gy1 - gy0) * f)
    acc = np.zeros((gy1 - gy0, gx1 - gx0, c), np.float32)
    wsum = np.zeros((gy1 - gy0, gx1 - gx0), np.float32)
    for (kx, ky), (a, w) in sums.items():
        ox, oy = kx * n - gx0, ky * n - gy0
        xs, ys = max(ox, 0), max(oy, 0)
        xe, ye = min(ox + n, gx1 - gx0), min(oy + n, gy1 - gy0)
        if xe > xs and ye > ys:
            acc[ys:ye, xs:xe] += a[ys - oy:ye - oy, xs - ox:xe - ox]
            wsum[ys:ye, xs:xe] += w[ys - oy:ye - oy, xs - ox:xe - ox]
    out = np.full(acc.shape, background, np.float32)
    covered = feather_divide(acc, wsum, out)
    return out, covered, region
