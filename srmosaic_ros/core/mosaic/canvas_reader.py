"""The reading half of a TiledCanvas: its tiles back as images (``render``, strips, the incremental
preview, labels, weights and the moving-object counts), never writing a tile.

Conventions as in :mod:`.canvas`: mosaic pixels, x right, y down, pixel centres at integers; a region is
(x0, y0, x1, y1), inclusive-exclusive. Feather: ``sum_i W_H^i I_H^i / sum_i W_H^i``; multiband and best
view: :mod:`.blend` (Table 2, eqs 4.8 to 4.10). A canvas makes one reader and hands its methods on.
"""
from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from typing import TYPE_CHECKING, Any

import numpy as np

from .best_view import transition_image
from .blend import auto_bands, feather_divide, multiband_blend, pyramid_region
from .canvas_settings import CanvasError, RenderSettings
from .preview import assemble, block_sums, preview_factor

if TYPE_CHECKING:
    from .tile_store import TileKey

__all__ = ['RENDER_BLOCK_PX', 'CanvasReader']

#: Largest side (px) rendered in one piece in multiband mode; larger regions go in blocks. Each block
#: holds a dozen float arrays over itself and its pyramid margin, so this side bounds a render's memory
#: (the memory of each choice: docs/results.md).
RENDER_BLOCK_PX = 1024


class CanvasReader:
    """Reads ``canvas``'s tiles (its store, tile counts and bounds) into images; keeps the incremental
    preview's block sums (recomputed only for the tiles painted since the last preview)."""

    def __init__(self, canvas: Any, settings: RenderSettings) -> None:  # the TiledCanvas it reads (canvas.py imports this module)
        self.canvas = canvas
        self.settings = settings
        self._preview_dirty: set[TileKey] = set()
        self._preview_sums: dict[TileKey, tuple[np.ndarray, np.ndarray]] = {}
        self._preview_factor = 0
        self.last_preview_region = (0, 0, 0, 0)

    def mark_painted(self, keys: list[TileKey]) -> None:
        """Tiles a paint wrote: their preview block sums are recomputed by the next preview."""
        self._preview_dirty.update(keys)

    def _region(self, region: tuple[int, int, int, int] | None) -> tuple[int, int, int, int]:
        if region is None:
            return self.canvas.bounds()
        if len(region) != 4 or any(int(v) != v for v in region):
            msg = f'region must be four integers (x0, y0, x1, y1), got {region!r}.'
            raise CanvasError(msg)
        x0, y0, x1, y1 = (int(v) for v in region)
        if x1 < x0 or y1 < y0:
            msg = f'region {region!r} is inverted: need x0 <= x1 and y0 <= y1 (inclusive-exclusive).'
            raise CanvasError(msg)
        if max(x1 - x0, y1 - y0) > self.canvas.max_canvas_side_px:
            msg = f'region {region!r} is larger than max_canvas_side_px={self.canvas.max_canvas_side_px}; render it in pieces.'
            raise CanvasError(msg)
        return x0, y0, x1, y1

    def _keys_in(self, x0: int, y0: int, x1: int, y1: int) -> list[TileKey]:
        t = self.canvas._tile_size
        if x1 <= x0 or y1 <= y0:
            return []
        kx0, ky0, kx1, ky1 = x0 // t, y0 // t, (x1 - 1) // t, (y1 - 1) // t
        tiles = self.canvas._tile_frames
        if (kx1 - kx0 + 1) * (ky1 - ky0 + 1) <= len(tiles):
            return [(kx, ky) for ky in range(ky0, ky1 + 1) for kx in range(kx0, kx1 + 1) if (kx, ky) in tiles]
        return sorted((k for k in tiles if kx0 <= k[0] <= kx1 and ky0 <= k[1] <= ky1), key=lambda k: (k[1], k[0]))

    def _overlap(self, key: TileKey, region: tuple[int, int, int, int],
                 ) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
        """(slices in the region's array, slices in the tile) of the overlap of tile ``key`` and ``region``."""
        x0, y0, x1, y1 = region
        kx, ky = key
        t = self.canvas._tile_size
        xs, xe = max(x0, kx * t), min(x1, (kx + 1) * t)
        ys, ye = max(y0, ky * t), min(y1, (ky + 1) * t)
        return ((slice(ys - y0, ye - y0), slice(xs - x0, xe - x0)),
                (slice(ys - ky * t, ye - ky * t), slice(xs - kx * t, xe - kx * t)))

    def _gather(self, region: tuple[int, int, int, int], names: tuple[str, ...]) -> list[np.ndarray]:
        """Tile arrays ``names`` assembled over ``region``; zeros (best_id: -1) where no tile."""
        x0, y0, x1, y1 = region
        h, w = y1 - y0, x1 - x0
        c = self.canvas._channels
        shapes = {'acc': (h, w, c), 'best': (h, w, c), 'second': (h, w, c),
                  'wsum': (h, w), 'best_w': (h, w), 'best_id': (h, w), 'second_w': (h, w), 'moved': (h, w)}
        dtypes = {'best_id': np.int32, 'moved': np.uint8}
        fill = {'best_id': -1, 'best_w': -np.inf, 'second_w': -np.inf} if self.canvas.blend == 'bestview' else {'best_id': -1}
        outs = [np.full(shapes[n], fill[n], dtypes.get(n, np.float32)) if n in fill
                else np.zeros(shapes[n], dtypes.get(n, np.float32)) for n in names]
        for key in self._keys_in(x0, y0, x1, y1):
            tile = self.canvas._store.peek(key)
            if tile is None:  # only after a failed paint created no tile for its key
                continue
            dst, src = self._overlap(key, region)
            for out, n in zip(outs, names):
                out[dst] = getattr(tile, n)[src]
        return outs

    def moving_counts(self, region: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """uint8 (h, w) over ``region`` (default: bounds): how many frames' pixels the vote on moving
        objects kept out of each mosaic pixel (saturating at 255; :func:`.best_view.update_best`): where
        something moved. Zeros when the canvas does not vote (:attr:`tracks_moving`)."""
        self.canvas._check_open()
        region = self._region(region)
        if not self.canvas.tracks_moving:
            return np.zeros((region[3] - region[1], region[2] - region[0]), np.uint8)
        return self._gather(region, ('moved',))[0]

    def labels(self, region: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """int32 (h, w) over ``region`` (default: bounds): the index (:attr:`PaintResult.frame_index`)
        of the frame each mosaic pixel is taken from (eq. 4.7: the max-weight, or with the vote on
        moving objects the consensus, frame), -1 where none; around seams multiband also blends in
        its neighbours. CanvasError for a feather canvas (every frame is averaged: no such frame)."""
        self.canvas._check_open()
        if self.canvas.blend == 'feather':
            msg = 'a feather canvas averages every frame over a pixel: it has no labels (blend bestview or multiband).'
            raise CanvasError(msg)
        return self._gather(self._region(region), ('best_id',))[0]

    def weights(self, region: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Feather weight sum ``sum_i W_H^i``, float32 (h, w), over ``region`` (default: bounds)."""
        self.canvas._check_open()
        return self._gather(self._region(region), ('wsum',))[0]

    def render(self, region: tuple[int, int, int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The blended mosaic over ``region`` = (x0, y0, x1, y1) mosaic pixels (default: ``bounds()``).

        Returns ``(image, covered)``: image float32 (h, w, C), or (h, w) when C == 1, with
        ``background`` where nothing is painted; covered bool (h, w), True where some frame put
        non-zero weight. Image pixel (i, j) is mosaic pixel (x0 + j, y0 + i).

        Feather: ``sum_i W_H^i I_H^i / sum_i W_H^i``. Multiband: see :mod:`.blend`; the result may
        overshoot the input range slightly at strong edges near seams. Its pyramids run on a grid
        fixed in mosaic coordinates over the region plus a margin, in blocks of RENDER_BLOCK_PX, so
        a pixel renders nearly the same (~1e-4) whatever region it is rendered in, as long as the
        band count is the same (fix ``bands`` for that; automatic bands follow the region size).
        """
        self.canvas._check_open()
        x0, y0, x1, y1 = self._region(region)
        h, w = y1 - y0, x1 - x0
        if self.canvas.blend == 'feather' or h == 0 or w == 0:
            out, covered = self._render_feather((x0, y0, x1, y1))
        else:
            out = np.empty((h, w, self.canvas._channels), np.float32)
            covered = np.empty((h, w), bool)
            for _ in self._multiband_rows((x0, y0, x1, y1), self.settings.bands or auto_bands(h, w), out, covered):
                pass
        if self.canvas._channels == 1:
            out = out[:, :, 0]
        return out, covered

    def render_reference(self, region: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The feather composite of ``region`` whatever the blend (``render``'s return convention):
        what keyframes register to. Under a revisit it still holds the first pass, which best view
        hands to the newest frames."""
        self.canvas._check_open()
        out, covered = self._render_feather(self._region(region))
        return (out[:, :, 0] if self.canvas._channels == 1 else out), covered

    def render_preview(self, max_side: int) -> tuple[np.ndarray, np.ndarray]:
        """A small feather render of the whole canvas for live previews, in time independent of the
        canvas's size: only tiles painted since the previous call are read.

        The canvas is reduced by the smallest divisor f of the tile size with longer side / f <=
        ``max_side`` (f = the tile size when none is large enough: the result is then larger than
        max_side, resize it); preview pixel (i, j) covers mosaic pixels [x0 + f j, x0 + f (j + 1))
        x [y0 + f i, ...) with (x0, y0) = (bounds x0 // f * f, bounds y0 // f * f), and is the
        feather blend of that block, ``sum acc / sum W`` over it (the weighted mean: a block half
        covered shows its covered half, not half its brightness). Returns ``(image, covered)`` as
        :meth:`render` does (float32 (h, w, C) or (h, w); bool (h, w)); empty arrays for an empty
        canvas. Multiband canvases preview their feather blend. ``last_preview_region`` is then the
        mosaic region (x0, y0, width, height) the result covers: f times its size, from (x0, y0).
        """
        self.canvas._check_open()
        if int(max_side) < 1:
            msg = f'max_side must be a positive integer, got {max_side!r}.'
            raise CanvasError(msg)
        c = self.canvas._channels
        if self.canvas._bounds is None:
            empty = np.zeros((0, 0, c) if c > 1 else (0, 0), np.float32)
            return empty, np.zeros((0, 0), bool)
        f = preview_factor(self.canvas._bounds, self.canvas._tile_size, max_side)
        if f != self._preview_factor:
            self._preview_factor = f
            self._preview_sums.clear()
            dirty = set(self.canvas._tile_frames)
        else:
            dirty = self._preview_dirty
        for key in dirty:
            tile = self.canvas._store.peek(key)
            if tile is None:
                continue
            self._preview_sums[key] = block_sums(tile, f, self.canvas._tile_size, c)
        self._preview_dirty = set()
        out, covered, self.last_preview_region = assemble(self._preview_sums, self.canvas._bounds, f, self.canvas._tile_size, c,
                                                          self.settings.background)
        return (out[:, :, 0] if c == 1 else out), covered

    def render_blocks(self, block_rows: int = 256, region: tuple[int, int, int, int] | None = None, *,
                      threads: int = 1) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        """The mosaic of ``render(region)`` in strips of ``block_rows`` rows, top to bottom.

        Yields ``(row, image, covered)``: ``row`` the strip's first row in the region (image row 0
        is mosaic row y0 of the region), ``image`` and ``covered`` as ``render`` returns them for
        rows ``row .. row + len(image)`` (the last strip may be shorter). Stacked, the strips are
        ``render(region)`` exactly (same band count in multiband mode: automatic bands follow the
        whole region). For writers of mosaics too large to hold whole: feather strips cost their
        own size; multiband strips are cut from rows of RENDER_BLOCK_PX-high blocks, one such row
        (RENDER_BLOCK_PX x region width) is held at a time, its blocks rendered on ``threads``
        threads (the same pixels; each thread holds one block's pyramids, ~10 block-sized float
        arrays). The canvas must not be painted while the generator runs.
        """
        if isinstance(block_rows, bool) or int(block_rows) != block_rows or block_rows < 1:
            msg = f'block_rows must be a positive integer, got {block_rows!r}.'
            raise CanvasError(msg)
        self.canvas._check_open()
        block_rows = int(block_rows)
        x0, y0, x1, y1 = self._region(region)
        h, w = y1 - y0, x1 - x0
        squeeze = self.canvas._channels == 1
        if self.canvas.blend == 'feather' or w == 0:
            for r in range(0, h, block_rows):
                o, c = self._render_feather((x0, y0 + r, x1, min(y0 + r + block_rows, y1)))
                yield r, (o[:, :, 0] if squeeze else o), c
            return
        pending: list[tuple[np.ndarray, np.ndarray]] = []
        have = start = 0
        for _, o, c in self._multiband_rows((x0, y0, x1, y1), self.settings.bands or auto_bands(h, w), threads=threads):
            pos = 0
            while pos < o.shape[0]:
                take = min(block_rows - have, o.shape[0] - pos)
                pending.append((o[pos:pos + take], c[pos:pos + take]))
                have += take
                pos += take
                if have == block_rows:
                    img = np.concatenate([p[0] for p in pending])
                    yield start, (img[:, :, 0] if squeeze else img), np.concatenate([p[1] for p in pending])
                    start += have
                    pending, have = [], 0
        if pending:
            img = np.concatenate([p[0] for p in pending])
            yield start, (img[:, :, 0] if squeeze else img), np.concatenate([p[1] for p in pending])

    def _render_feather(self, region: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Feather render (h, w, C), covered (h, w) of ``region``, tile by tile (no full-size sums)."""
        x0, y0, x1, y1 = region
        h, w = y1 - y0, x1 - x0
        out = np.full((h, w, self.canvas._channels), self.settings.background, np.float32)
        covered = np.zeros((h, w), bool)
        for key in self._keys_in(x0, y0, x1, y1):
            tile = self.canvas._store.peek(key)
            if tile is None:
                continue
            dst, src = self._overlap(key, region)
            covered[dst] = feather_divide(tile.acc[src], tile.wsum[src], out[dst])
        return out, covered

    def _multiband_rows(self, region: tuple[int, int, int, int], bands: int, dst_image: np.ndarray | None = None,
                        dst_covered: np.ndarray | None = None, *, threads: int = 1,
                        ) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        """Multiband render of ``region`` in rows of RENDER_BLOCK_PX-square blocks anchored at its origin.

        Yields (first row in the region, image (rows, w, C) with the background where uncovered,
        covered (rows, w)); written into ``dst_image`` (h, w, C) and ``dst_covered`` (h, w) when
        given (the yielded arrays are then views of them), else into new arrays per row. A row's
        blocks are rendered on ``threads`` threads (OpenCV's pyramids release the GIL), each
        writing its own columns of the row.
        """
        x0, y0, x1, y1 = region
        block = RENDER_BLOCK_PX
        columns = [(bx, min(bx + block, x1)) for bx in range(x0, x1, block)]
        workers = max(1, min(int(threads), len(columns)))
        with ThreadPoolExecutor(workers, thread_name_prefix='render') if workers > 1 else nullcontext() as pool:
            for by in range(y0, y1, block):
                by1 = min(by + block, y1)
                if dst_image is not None and dst_covered is not None:
                    out, covered = dst_image[by - y0:by1 - y0], dst_covered[by - y0:by1 - y0]
                else:
                    out = np.empty((by1 - by, x1 - x0, self.canvas._channels), np.float32)
                    covered = np.empty((by1 - by, x1 - x0), bool)

                def put(cols: tuple[int, int], by: int = by, by1: int = by1, out: np.ndarray = out,
                        covered: np.ndarray = covered) -> None:
                    bx, bx1 = cols
                    o, c = self._render_multiband((bx, by, bx1, by1), bands)
                    out[:, bx - x0:bx1 - x0] = o
                    covered[:, bx - x0:bx1 - x0] = c

                for _ in (pool.map(put, columns) if pool is not None else map(put, columns)):
                    pass
                out[~covered] = self.settings.background
                yield by - y0, out, covered

    def _render_multiband(self, region: tuple[int, int, int, int], bands: int) -> tuple[np.ndarray, np.ndarray]:
        """Multiband render of ``region`` with ``bands`` levels, its pyramids run over
        :func:`.blend.pyramid_region` (the same grid whatever the region)."""
        x0, y0, x1, y1 = region
        ex0, ey0, ex1, ey1 = pyramid_region(region, bands)
        if self.canvas.blend == 'bestview':
            best, best_id, second, second_w = self._gather((ex0, ey0, ex1, ey1), ('best', 'best_id', 'second', 'second_w'))
            covered = best_id >= 0
            out = multiband_blend(transition_image(best, second, second_w), best, best_id, bands, coarsest_by_seams=True)
        else:
            acc, wsum, best, best_id = self._gather((ex0, ey0, ex1, ey1), ('acc', 'wsum', 'best', 'best_id'))
            feather = np.zeros(acc.shape, np.float32)
            covered = feather_divide(acc, wsum, feather)
            out = multiband_blend(feather, best, best_id, bands)
        crop = (slice(y0 - ey0, y1 - ey0), slice(x0 - ex0, x1 - ex0))
        return out[crop], covered[crop]

    def tile_blocks(self, key: TileKey, f: int) -> tuple[np.ndarray, np.ndarray] | None:
        """One tile reduced by ``f`` (a divisor of the tile size) as the preview reduces it: the
        feather blend of each f x f block (best view: the block mean of the winners' pixels).

        Returns ``(image, covered)``: image float32 (T/f, T/f, C) with ``background`` where nothing is
        painted, covered bool (T/f, T/f); image pixel (i, j) covers mosaic pixels
        [tx T + f j, tx T + f (j + 1)) x [ty T + f i, ...). None when the tile does not exist.
        For the live map's changed tiles (with :meth:`pop_touched`); reads the tile only.
        """
        self.canvas._check_open()
        if int(f) < 1 or self.canvas._tile_size % int(f):
            msg = f'the reduction must divide the tile size {self.canvas._tile_size}, got {f!r}.'
            raise CanvasError(msg)
        tile = self.canvas._store.peek(key)
        if tile is None:
            return None
        acc, wsum = block_sums(tile, int(f), self.canvas._tile_size, self.canvas._channels)
        out = np.full(acc.shape, self.settings.background, np.float32)
        return out, feather_divide(acc, wsum, out)
