"""A mosaic canvas that grows without bound in every direction, stored as square tiles.

Convention: "mosaic pixels", x right, y down, pixel centres at integer coordinates; negative
coordinates are fine. Tile ``(tx, ty)`` holds the mosaic pixels
``x in [tx * T, (tx + 1) * T)``, ``y in [ty * T, (ty + 1) * T)`` (T = ``tile_size``), so tile keys
are ``floor(x / T), floor(y / T)``. Tiles are created only where a frame puts non-zero weight.

Each tile keeps, in float32:

- ``acc`` (T, T, C): the feather-weighted colour sum ``sum_i W_H^i I_H^i``;
- ``wsum`` (T, T): the weight sum ``sum_i W_H^i`` (``I_H^i``, ``W_H^i``: frame i and its feather
  weight warped into the mosaic);
- with ``blend='multiband'`` also the max-weight composite of eq. 4.7: ``best`` (T, T, C), the
  colour of the frame with the largest ``W_H^i`` so far, ``best_w`` (T, T) that weight and
  ``best_id`` (T, T) int32 the index of that frame (-1: none).

Painting (``paint``) warps the frame and its feather weight once onto the bounding box of the
frame's footprint (``cv2.warpPerspective``, whose convention is the one above: frame pixel (u, v)
lands at ``mosaic_H_frame @ (u, v, 1)``) and adds the result into the tiles that box overlaps,
skipping tiles where the warped weight is zero. The colour is sampled as ``interpolation`` says
(:mod:`.resample`: clamped bicubic by default, which keeps the detail a bilinear resample blurs
away), the weight bilinearly. The image is warped with replicated borders and the weight with a
zero border, and the two are multiplied after warping: inside the frame the colour is exactly
:func:`.resample.warp` of the frame, and at the frame edge the colour does not fade to black, only
its weight fades to zero.

Rendering (``render``) divides ``acc`` by ``wsum`` (feather blending) or, in multiband mode,
blends the max-weight composite over the feather composite band by band (see :mod:`.blend`).
``render_blocks`` yields the same pixels in strips of rows, for writers of mosaics too large to
hold whole.

This module keeps the storage and geometry: the tiles (:mod:`.tile_store`), where a frame lands
(:mod:`.placement`) and the tiles a paint writes (:mod:`.paint_jobs`). What a tile keeps of a frame
is the blend mode's compositor's: :mod:`.feather_compositor`, :mod:`.multiband_compositor`,
:mod:`.best_view_compositor` (the seams' cut of the last two in :mod:`.frame_cut`); the threads a
paint writes on are :mod:`.paint_pool`'s. Reading (render, previews, labels) is
:mod:`.canvas_reader`'s; the per-pixel arithmetic is in :mod:`.paint_ops` and :mod:`.blend`, the
argument checks in :mod:`.paint_args` and :mod:`.canvas_settings`.

Bounded memory: with ``max_tiles_in_memory`` > 0 the tiles live in a :class:`.tile_store.TileStore`
that keeps at most that many in memory and spills the least recently painted ones to disk
(``spill_dir``), loading them back when a frame paints them again or a render reads them. Each
paint fetches every tile it writes first, writes, then trims the store back to the bound (so the
bound may be exceeded by the tiles of one frame for the duration of the paint); rendering reads
spilled tiles one at a time without keeping them, so any region renders within the bound plus one
tile (plus its own output). Spilled tiles come back byte for byte: the results are identical with
and without the bound. ``close()`` (or ``with TiledCanvas(...) as canvas:``) releases the tiles and
removes the spill files; a canvas that is garbage-collected, or still alive at interpreter exit,
removes them too.
"""
from __future__ import annotations

import os
from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ..homography import project_points
from .best_view import clip_depth, depth_map
from .best_view_compositor import BestViewCompositor
from .blend import MULTIBAND_MARGIN as MULTIBAND_MARGIN  # importable from here as before it moved
from .canvas_reader import RENDER_BLOCK_PX as RENDER_BLOCK_PX  # importable from here as before
from .canvas_reader import CanvasReader
from .canvas_settings import (BestViewSettings, CanvasError, FeatherSettings, MultibandSettings, PlacementSettings, RenderSettings,
                              settings_problem)
from .feather_compositor import FeatherCompositor
from .frame_cut import PaintJob
from .minify import minify_level, reduce_frame
from .multiband_compositor import MultibandCompositor
from .paint_args import as_image, as_mask, as_rects, as_scale, as_tiles
from .paint_jobs import box_jobs, rect_weights, warp_colour
from .paint_ops import fill_invalid, scaled, to_float
from .paint_pool import PaintPool
from .placement import checked_homography, placement_box
from .resample import DEFAULT_INTERPOLATION, FILL_RINGS, FrameSampler
from .scratch import scratch
from .tile_store import TileKey, TileStore, TileStoreError

__all__ = ['CanvasError', 'PaintResult', 'TileKey', 'TileStoreError', 'TiledCanvas']


@dataclass(frozen=True, eq=False)
class PaintResult:
    """What one ``TiledCanvas.paint`` did.

    ``frame_index``: 0-based count of frames painted into this canvas before this one (the label
    used by the max-weight masks). ``touched_tiles``: keys (tx, ty) of the tiles the frame wrote,
    sorted. ``footprint_xy``: (4, 2) float64 mosaic-pixel corners of the frame's pixel area
    (frame points (-0.5, -0.5), (W - 0.5, -0.5), (W - 0.5, H - 0.5), (-0.5, H - 0.5), in that order).
    ``bbox``: (x0, y0, x1, y1) mosaic pixels that received non-zero weight, inclusive-exclusive
    ((0, 0, 0, 0) when none did).
    """

    frame_index: int
    touched_tiles: tuple[TileKey, ...]
    footprint_xy: np.ndarray = field(repr=False)
    bbox: tuple[int, int, int, int]


def _compositor(blend: str, feather: FeatherSettings, seams: str, best_view: BestViewSettings) -> FeatherCompositor:
    """The compositor of blend mode ``blend`` (feather, multiband or bestview)."""
    if blend == 'multiband':
        return MultibandCompositor(feather, MultibandSettings(seams))
    if blend == 'bestview':
        return BestViewCompositor(feather, best_view)
    return FeatherCompositor(feather)


class TiledCanvas:
    """Growing tiled canvas with feather or multi-band blending.

    Args:
        channels: C, colour channels of every painted image (1 mono, 3 RGB, any C >= 1).
        tile_size: tile side T in mosaic pixels (16 .. 4096).
        blend: ``'feather'`` (weighted average, eq. W(x, y) of section 4.2.5), ``'multiband'``
            (max-weight masks, eq. 4.7, and Laplacian-pyramid blending, Table 2 / eqs 4.8 to 4.10)
            or ``'bestview'`` (each pixel from the frame that sees it best, blended across seams
            only: :mod:`.best_view`).
        feather_profile: ``'separable'`` (w(x) w(y), the dissertation's form, the default) or
            ``'distance'`` (distance to the frame border); see :func:`.blend.feather_weight`.
            The separable form blends frames that share an edge without a jump along it (with
            the distance form both weigh the same next to the shared edge).
        feather_power: exponent applied to the normalised feather weight (> 0); larger values
            narrow the transitions.
        max_canvas_side_px: a frame whose footprint would make the painted area wider or taller
            than this is refused (CanvasError) instead of allocating memory for it.
        max_area_ratio: a frame whose footprint bounding box exceeds this many times the frame's
            own area is refused (an absurd homography, e.g. close to the horizon).
        bands: pyramid levels of multiband rendering; 0 chooses them from the region size
            (:func:`.blend.auto_bands`).
        background: value of uncovered pixels in ``render``.
        max_stretch: frame pixels more than this many times (linearly) coarser on the mosaic than
            the frame's finest pixel are not painted (far field and sky of oblique views, see
            :mod:`.best_view`); such frames may then cross the horizon. 0: no cut, and a frame
            crossing the horizon is refused.
        recency_frames: best view only: a frame this many frames newer wins over an e-fold better
            view (0: no preference for newer frames).
        agree: best view only: frames whose pixel is within this of the winner's (intensity, every
            channel) are averaged into it (0: one frame per pixel).
        moving: best view only: a frame's pixels that differ from the pixel's background by more
            than this (intensity; 0: off) saw something move and are kept out, see
            :func:`.best_view.update_best`.
        moving_history: best view with ``moving``: colour samples kept per mosaic pixel (odd); their
            median is the background (K C + 2 bytes per pixel more).
        seams: best view and multiband: 'score' (a frame wins where its score or weight is higher)
            or 'cut' (a graph cut moves the seams to where the frames agree, :mod:`.seam_cut`).
        max_tiles_in_memory: at most this many tiles are kept in memory, the least recently
            painted ones are spilled to disk (0: no bound, nothing is ever written). One tile
            holds ``4 T^2 (C + 1)`` bytes (feather), ``4 T^2 (2 C + 3)`` (multiband) or
            ``4 T^2 (3 C + 5)`` (best view): 1 MiB, 2.25 MiB and 3.5 MiB for T = 256, C = 3.
        interpolation: how the colour is sampled at the mosaic pixels' preimages
            (:mod:`.resample`): ``'cubic'`` (clamped bicubic, the default), ``'lanczos'`` (clamped
            Lanczos-4: a little sharper, and the costliest) or ``'linear'`` (bilinear: the
            fastest, and a low-pass filter at every sub-pixel offset).
        threads: tiles a paint writes on this many threads at once (1: on the caller's), each
            tile's colour warped on its own. For a caller with a core to spare (a survey's stills,
            one at a time); the mosaic is the same but for rounding (OpenCV rounds each tile's own
            coordinates: uint8 frames within one 8-bit step).
        spill_dir: directory under which the spill directory of this canvas is created ('':
            $TMPDIR, else /var/tmp, see :func:`.tile_store.default_spill_root`); created on the
            first spill, removed by ``close()``.

    Not thread-safe: paint and render from one thread (or hold a lock around both).
    """

    def __init__(
        self,
        channels: int,
        tile_size: int = 256,
        *,
        blend: str = 'feather',
        feather_profile: str = FeatherSettings.profile,
        feather_power: float = FeatherSettings.power,
        max_canvas_side_px: int = PlacementSettings.max_canvas_side_px,
        max_area_ratio: float = PlacementSettings.max_area_ratio,
        bands: int = RenderSettings.bands,
        background: float = RenderSettings.background,
        max_tiles_in_memory: int = 0,
        spill_dir: str | os.PathLike[str] = '',
        max_stretch: float = PlacementSettings.max_stretch,
        recency_frames: int = BestViewSettings.recency_frames,
        agree: float = BestViewSettings.agree,
        moving: float = BestViewSettings.moving,
        moving_history: int = BestViewSettings.moving_history,
        seams: str = BestViewSettings.seams,
        interpolation: str = DEFAULT_INTERPOLATION,
        threads: int = 1,
    ) -> None:
        msg = settings_problem(channels, tile_size, blend=blend, feather_profile=feather_profile, feather_power=feather_power,
                               max_canvas_side_px=max_canvas_side_px, max_area_ratio=max_area_ratio, bands=bands,
                               max_tiles_in_memory=max_tiles_in_memory, max_stretch=max_stretch,
                               recency_frames=recency_frames, agree=agree, moving=moving,
                               moving_history=moving_history, seams=seams, interpolation=interpolation)
        if msg is not None:
            raise CanvasError(msg)
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            msg = f'threads must be an integer >= 1, got {threads!r}.'
            raise CanvasError(msg)
        self._channels = int(channels)
        self._tile_size = int(tile_size)
        self._interpolation = interpolation
        self._limits = PlacementSettings(int(max_canvas_side_px), float(max_area_ratio), float(max_stretch))
        self._compositor = _compositor(blend, FeatherSettings(feather_profile, float(feather_power)), seams,
                                       BestViewSettings(int(recency_frames), float(agree), float(moving), int(moving_history), seams))
        self._pool = PaintPool(threads)  # the painting threads, started by the first paint that uses them
        self._store = TileStore(self._compositor.layout(self._tile_size, self._channels),
                                max_in_memory=int(max_tiles_in_memory), spill_dir=spill_dir)
        self._tile_frames: dict[TileKey, int] = {}  # every tile: how many frames wrote into it
        self._touched: set[TileKey] = set()
        # render, previews, labels: the reading half
        self._reader = CanvasReader(self, RenderSettings(int(bands), np.float32(background)))
        self._frames = 0
        self._bounds: tuple[int, int, int, int] | None = None

    # ------------------------------------------------------------------ properties
    @property
    def channels(self) -> int:
        return self._channels

    @property
    def tile_size(self) -> int:
        return self._tile_size

    @property
    def blend(self) -> str:
        return self._compositor.blend

    @property
    def interpolation(self) -> str:
        """How the colour of a frame is sampled (:mod:`.resample`)."""
        return self._interpolation

    @property
    def max_canvas_side_px(self) -> int:
        """The side beyond which the canvas refuses to grow (and to render a region)."""
        return self._limits.max_canvas_side_px

    @property
    def frames_painted(self) -> int:
        """Number of ``paint`` calls that succeeded."""
        return self._frames

    @property
    def is_empty(self) -> bool:
        return self._bounds is None

    @property
    def touched_tiles(self) -> frozenset[TileKey]:
        """Keys of tiles written since the canvas was created or ``pop_touched`` last ran."""
        return frozenset(self._touched)

    def pop_touched(self) -> frozenset[TileKey]:
        """Return ``touched_tiles`` and start a new record (for incremental previews)."""
        out = frozenset(self._touched)
        self._touched.clear()
        return out

    def tile_keys(self) -> list[TileKey]:
        """Keys (tx, ty) of all tiles, sorted by (ty, tx) (raster order)."""
        return sorted(self._tile_frames, key=lambda k: (k[1], k[0]))

    def tile_region(self, key: TileKey) -> tuple[int, int, int, int]:
        """Mosaic-pixel region (x0, y0, x1, y1) of tile ``key``, inclusive-exclusive."""
        t = self._tile_size
        return key[0] * t, key[1] * t, (key[0] + 1) * t, (key[1] + 1) * t

    def frames_per_tile(self) -> dict[TileKey, int]:
        """How many painted frames wrote into each tile."""
        return dict(self._tile_frames)

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the tile arrays in memory (spilled tiles not counted)."""
        return self._store.memory_bytes

    @property
    def disk_bytes(self) -> int:
        """Bytes of this canvas's spill files (0 while nothing was spilled)."""
        return self._store.disk_bytes

    @property
    def max_tiles_in_memory(self) -> int:
        """The bound on tiles in memory (0: none)."""
        return self._store.max_in_memory

    @property
    def tiles_in_memory(self) -> int:
        return self._store.in_memory

    @property
    def tiles_on_disk(self) -> int:
        """Tiles held only in spill files (not in memory now)."""
        return self._store.on_disk_only

    @property
    def spill_dir(self) -> str:
        """This canvas's spill directory ('' while nothing was spilled, and after close)."""
        d = self._store.directory
        return str(d) if d is not None else ''

    def tile_stats(self) -> dict[str, Any]:
        """Tiles in memory and on disk, their bytes, and the loads and writes of spill files so far."""
        return self._store.stats()

    # ------------------------------------------------------------------ memory, life cycle
    def spill(self, keep: int = 0) -> int:
        """Spill the least recently painted tiles until at most ``keep`` remain in memory.

        For a canvas that will not be painted for a while (e.g. a finished segment). Works with
        or without ``max_tiles_in_memory``. Returns the number of tiles evicted.
        """
        self._check_open()
        return self._store.trim(max(0, int(keep)))

    @property
    def closed(self) -> bool:
        return self._store.closed

    def close(self) -> None:
        """Release every tile and remove the spill files. The canvas cannot be used afterwards."""
        self._pool.close()
        self._store.close()

    def __enter__(self) -> TiledCanvas:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _check_open(self) -> None:
        if self._store.closed:
            msg = 'the canvas is closed (its tiles were released); paint and render before close().'
            raise CanvasError(msg)

    def bounds(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) mosaic pixels with non-zero weight, inclusive-exclusive.

        (0, 0, 0, 0) while nothing is painted.
        """
        return self._bounds if self._bounds is not None else (0, 0, 0, 0)

    # ------------------------------------------------------------------ paint
    def check_placement(self, mosaic_H_frame: np.ndarray, width: int, height: int) -> None:
        """Raise CanvasError where :meth:`paint` would refuse a width x height frame at mosaic_H_frame
        (an absurd homography, or a canvas beyond max_canvas_side_px), without painting it."""
        m = checked_homography(mosaic_H_frame, width, height, self._limits.max_stretch)
        placement_box(m, width, height, self._limits, self._bounds)

    def paint(
        self,
        image: np.ndarray,
        mosaic_H_frame: np.ndarray,  # frames in the name
        *,
        mask: np.ndarray | None = None,
        finite: bool = False,
        scale: np.ndarray | None = None,
        tiles: Collection[TileKey] | Mapping[TileKey, tuple[int, int, int, int]] | None = None,
    ) -> PaintResult:
        """Warp a frame into the canvas and accumulate it with its feather weight.

        Args:
            image: float32 (H, W, C) or, for C == 1, (H, W); values nominally in [0, 1].
                Non-finite pixels are treated as invalid. Or uint8 (values / 255): warped as
                integers (OpenCV's fixed-point bilinear, faster than on floats) and
                converted on the mosaic, so no float copy of the frame is made; the warped values
                are rounded to integers before the conversion (at most 0.5 / 255 apart from a float
                warp's).
            mosaic_H_frame: (3, 3) float64 homography from frame pixels to mosaic pixels (pixel
                centres at integers): frame pixel (u, v) lands at ``mosaic_H_frame @ (u, v, 1)``.
            mask: optional bool (H, W), True where the pixel is valid; invalid pixels weigh 0.
            finite: the caller guarantees that every pixel of ``image`` is finite (converted from
                integers): the check, a pass over the frame, is skipped.
            scale: optional (C,) multipliers of the image's values in [0, 1] (exposure gains);
                values they take above 1 are clipped to 1.
            tiles: optional tile keys (tx, ty): the frame is painted on these tiles only (a survey
                that knows where it cannot win, core/survey/paint_plan.py); or a mapping of tile key
                to the mosaic pixels (x0, y0, x1, y1) painted in it (a video frame painted where it
                sees what its neighbours do not, core/mosaic/thinning.py); None: wherever it falls.

        Returns:
            PaintResult: the frame index, the tiles written, the footprint and its bbox.

        Raises:
            CanvasError (a ValueError): bad image or mask, or an absurd homography (non-finite,
            singular, crossing the horizon, footprint bbox larger than ``max_area_ratio`` times
            the frame or making the canvas exceed ``max_canvas_side_px``).
        """
        self._check_open()
        gains = as_scale(scale, self._channels)
        img = as_image(image, self._channels)
        h, w = img.shape[:2]
        m = checked_homography(mosaic_H_frame, w, h, self._limits.max_stretch)
        if img.dtype != np.uint8 and gains is not None:
            img = scaled(img, gains)
        valid = as_mask(mask, img, finite or img.dtype == np.uint8)
        footprint, _ = project_points(m, np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]))
        placement = placement_box(m, w, h, self._limits, self._bounds)
        rects: dict[TileKey, tuple[int, int, int, int]] | None = None
        keys: frozenset[TileKey] | None = None
        if tiles is not None:
            rects = as_rects(tiles) if isinstance(tiles, Mapping) else None
            keys, placement = self._clip_to_tiles(placement, tiles, rects)
        index = self._frames
        if placement is None:
            return self._nothing_painted(footprint)
        img, valid, m, weight = self._prepare(img, valid, m, gains)
        x0, y0, x1, y1 = placement
        bw, bh = x1 - x0, y1 - y0
        box_h_frame = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ m
        src = FrameSampler(img[:, :, 0] if self._channels == 1 else img, self.interpolation)
        seam_cut = self._compositor.seam_cut
        if rects is not None and not seam_cut:  # painted in part: the weight over each asked-for box alone
            w_w, parts = None, rect_weights(weight, box_h_frame, rects, placement, self._tile_size)
            if not parts:
                return self._nothing_painted(footprint)
            jobs = [(key, box, loc) for key, box, loc, _, _ in parts]
            part_w = {key: sub for key, _, _, _, sub in parts}
            nz = np.array([b for _, _, _, b, _ in parts])
            tight = int(nz[:, 0].min()), int(nz[:, 1].min()), int(nz[:, 2].max()), int(nz[:, 3].max())
        else:
            # into this thread's scratch arrays: they live until paint returns (the tiles keep copies)
            w_w = cv2.warpPerspective(weight, box_h_frame, (bw, bh), dst=scratch('weight', (bh, bw)),
                                      flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
            # Tight box of non-zero weight, in box coordinates (one C pass over a mask, not two reductions).
            c0, r0, nc, nr = cv2.boundingRect((w_w != 0).view(np.uint8))
            if nc == 0:
                return self._nothing_painted(footprint)
            part_w = None
            tight = x0 + c0, y0 + r0, x0 + c0 + nc, y0 + r0 + nr
            jobs = box_jobs(w_w, (x0, y0), tight, self._tile_size, keys, rects)
        # Every tile first (loading spilled ones may fail: then nothing is written), then write.
        tile_list = [self._store.get(key, create=True) for key, _, _ in jobs]
        self._frames += 1
        # The colour over the whole box at once (what the seams' cut compares), or, painting on
        # threads, warped tile by tile: each in cache through its updates, no box-sized array
        img_w = None
        if (seam_cut or self._pool.threads == 1) and w_w is not None:
            img_w = warp_colour(src, box_h_frame, (slice(0, bh), slice(0, bw)), gains, 'colour', self._channels)
        cut = self._compositor.cut(jobs, tile_list, img_w, w_w, index, self._channels) \
            if seam_cut and img_w is not None and w_w is not None else None

        def offer(job: PaintJob, tile: Any) -> None:
            key, box, loc = job
            sub_w = w_w[box] if w_w is not None else part_w[key]  # type: ignore[index]
            # a tile's colour warped on its own stays in cache through the updates below
            colour = img_w[box] if img_w is not None else warp_colour(src, box_h_frame, box, gains, 'tile_colour', self._channels)
            self._compositor.offer(tile, loc, colour, sub_w, index, None if cut is None else (cut[0][box], cut[1][box]))

        self._pool.run(offer, jobs, tile_list)
        del tile_list
        return PaintResult(index, self._record([key for key, _, _ in jobs], tight), footprint, tight)

    def _clip_to_tiles(self, placement: tuple[int, int, int, int], tiles: Collection[TileKey] | Mapping[TileKey, Any],
                       rects: dict[TileKey, tuple[int, int, int, int]] | None,
                       ) -> tuple[frozenset[TileKey], tuple[int, int, int, int] | None]:
        """(the keys of ``tiles``, the paint's box ``placement`` (x0, y0, x1, y1) shrunk to those tiles and
        to the rectangles ``rects`` asked for in them, None where nothing is left): no weight is warped
        where none is painted."""
        keys, span = as_tiles(tiles)
        if span is None:
            return keys, None
        t = self._tile_size
        x0, y0, x1, y1 = placement
        x0, y0 = max(x0, span[0] * t), max(y0, span[1] * t)
        x1, y1 = min(x1, (span[2] + 1) * t), min(y1, (span[3] + 1) * t)
        if rects:
            r = np.array(list(rects.values()))
            x0, y0 = max(x0, int(r[:, 0].min())), max(y0, int(r[:, 1].min()))
            x1, y1 = min(x1, int(r[:, 2].max())), min(y1, int(r[:, 3].max()))
        return keys, ((x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None)

    def _nothing_painted(self, footprint: np.ndarray) -> PaintResult:
        """A paint that writes no tile: counted all the same (its index labels no pixel)."""
        self._frames += 1
        return PaintResult(self._frames - 1, (), footprint, (0, 0, 0, 0))

    def _prepare(self, img: np.ndarray, valid: np.ndarray | None, m: np.ndarray, gains: np.ndarray | None,
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
        """(image, valid mask, mosaic_H_frame, weight) of the frame as painted: reduced first where it
        shrinks on the mosaic (:mod:`.minify`, not point-sampled), cut where its view is too oblique
        (``max_stretch``, :func:`.best_view.clip_depth`), weighted by the compositor (float32 (h, w))
        and with its invalid pixels filled as far as the interpolation reads them."""
        h, w = img.shape[:2]
        max_stretch = self._limits.max_stretch
        level = minify_level(m, w, h, clip_depth(m, w, h, max_stretch))
        if level:  # a frame shrinking on the mosaic is reduced first, not point-sampled (minify.py)
            if img.dtype == np.uint8:  # reduced as floats
                img = to_float(img, gains)
            if valid is not None:
                img = fill_invalid(img, valid)
            img, valid, m = reduce_frame(img, valid, m, level)
            h, w = img.shape[:2]
        d_min = clip_depth(m, w, h, max_stretch)
        coarse = self._compositor.rates_resolution(m, w, h)
        depth = depth_map(m, h, w) if (coarse or d_min is not None) else None
        if d_min is not None and depth is not None:  # the far field and sky of an oblique view stay out
            kept = depth >= np.float32(d_min)
            valid = kept if valid is None else valid & kept
        weight = self._compositor.weight(h, w, valid, m, depth if coarse else None)
        if valid is not None:
            if img.dtype == np.uint8:  # filled as floats
                img = to_float(img, gains)
            img = fill_invalid(img, valid, FILL_RINGS[self.interpolation])
        return img, valid, m, weight

    def _record(self, touched: list[TileKey], bbox: tuple[int, int, int, int]) -> tuple[TileKey, ...]:
        """Count a paint that wrote the tiles ``touched`` over the mosaic box ``bbox``, grow the bounds,
        trim the store back to its bound; the tiles, sorted by (ty, tx)."""
        for key in touched:
            self._tile_frames[key] = self._tile_frames.get(key, 0) + 1
        self._touched.update(touched)
        self._reader.mark_painted(touched)
        gx0, gy0, gx1, gy1 = bbox
        self._bounds = bbox if self._bounds is None else (
            min(gx0, self._bounds[0]), min(gy0, self._bounds[1]),
            max(gx1, self._bounds[2]), max(gy1, self._bounds[3]))
        self._store.trim()  # back to the bound; may raise TileStoreError (the frame is painted)
        return tuple(sorted(touched, key=lambda k: (k[1], k[0])))

    # ------------------------------------------------------------------ render

    # ------------------------------------------------------------------ reading (CanvasReader)
    @property
    def tracks_moving(self) -> bool:
        """Whether the canvas votes on moving objects (best view with ``moving`` > 0): then
        :meth:`moving_counts` says where something moved."""
        return self._store.layout.history > 0

    @property
    def last_preview_region(self) -> tuple[int, int, int, int]:
        """The mosaic region (x0, y0, width, height) the last :meth:`render_preview` covers."""
        return self._reader.last_preview_region

    def moving_counts(self, region: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """uint8 (h, w): frames' pixels the vote on moving objects kept out (:meth:`CanvasReader.moving_counts`)."""
        return self._reader.moving_counts(region)

    def labels(self, region: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """int32 (h, w): the frame each mosaic pixel is taken from, -1 where none (:meth:`CanvasReader.labels`)."""
        return self._reader.labels(region)

    def weights(self, region: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Feather weight sum, float32 (h, w), over ``region`` (default: bounds)."""
        return self._reader.weights(region)

    def render(self, region: tuple[int, int, int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The blended mosaic over ``region`` (default: bounds): (image, covered) (:meth:`CanvasReader.render`)."""
        return self._reader.render(region)

    def render_reference(self, region: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The feather composite of ``region`` whatever the blend (:meth:`CanvasReader.render_reference`)."""
        return self._reader.render_reference(region)

    def render_preview(self, max_side: int) -> tuple[np.ndarray, np.ndarray]:
        """A small feather render of the whole canvas, incremental (:meth:`CanvasReader.render_preview`)."""
        return self._reader.render_preview(max_side)

    def render_blocks(self, block_rows: int = 256, region: tuple[int, int, int, int] | None = None, *,
                      threads: int = 1) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        """``render(region)`` in strips of ``block_rows`` rows, top to bottom (:meth:`CanvasReader.render_blocks`)."""
        return self._reader.render_blocks(block_rows, region, threads=threads)

    def tile_blocks(self, key: TileKey, f: int) -> tuple[np.ndarray, np.ndarray] | None:
        """One tile reduced by ``f`` as the preview reduces it, or None (:meth:`CanvasReader.tile_blocks`)."""
        return self._reader.tile_blocks(key, f)
