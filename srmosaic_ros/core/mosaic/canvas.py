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
hold whole. The per-pixel arithmetic of painting and rendering the composites is in :mod:`.blend`,
the downscaling of ``render_preview`` in :mod:`.preview`, the argument checks in :mod:`.canvas_settings`.

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

import math
import os
from collections.abc import Collection, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np


from ..homography import project_points
from .best_view import (clip_depth, clipped_polygon, depth_map, magnified_somewhere, resolution_factor, update_best)
from .minify import minify_level, reduce_frame
from .blend import MULTIBAND_MARGIN as MULTIBAND_MARGIN  # importable from here as before it moved
from .blend import feather_weight, update_max_weight
from .canvas_reader import RENDER_BLOCK_PX as RENDER_BLOCK_PX  # importable from here as before
from .canvas_reader import CanvasReader
from .canvas_settings import CanvasError, settings_problem
from .resample import DEFAULT_INTERPOLATION, FILL_RINGS, FrameSampler
from .scratch import scratch
from .seam_cut import block_means, block_size, cut_nodes, expand
from .tile_store import TileKey, TileLayout, TileStore, TileStoreError

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


def _fill_invalid(img: np.ndarray, valid: np.ndarray, rings: int = 1) -> np.ndarray:
    """Replace invalid pixels by the mean of their valid 8-neighbours, ``rings`` times over (each
    ring filled from the last; 0 beyond).

    Where the warped weight is non-zero, bilinear interpolation reads invalid pixels one pixel from
    a valid one, bicubic two, Lanczos-4 four (:data:`.resample.FILL_RINGS`), so this is all the fill
    that the colour needs (garbage or NaN never leaks in).
    """
    clean = np.where(valid[..., None], img, np.float32(0.0)).astype(np.float32, copy=False)
    known = valid
    for _ in range(rings):
        m = known.astype(np.float32)
        num = cv2.boxFilter(clean, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT).reshape(img.shape)
        den = cv2.boxFilter(m, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        fill = num / np.maximum(den, np.float32(1.0))[..., None]
        clean = np.where(known[..., None], clean, fill).astype(np.float32, copy=False)
        known = den > 0
    return clean


def _to_float(image: np.ndarray, gains: np.ndarray | None, out: np.ndarray | None = None) -> np.ndarray:
    """float32 (h, w, C) of uint8 (h, w, C): values / 255, times ``gains`` (C,) per channel and
    clipped to 1 where a gain exceeds 1 (None: no gains); into ``out`` when given."""
    h, w, c = image.shape
    if out is None:
        out = np.empty(image.shape, np.float32)
    if gains is None:  # one factor: numpy's scalar product, about twice OpenCV's (same values, all 256 checked)
        return np.multiply(image, np.float32(1.0 / 255.0), out=out, dtype=np.float32)
    factor = gains / np.float32(255.0)
    saturates = float(gains.max()) > 1.0  # only a gain above 1 can saturate
    if c <= 4:  # OpenCV's per-channel scalar product, about three times numpy's broadcast (same values)
        shape = (h, w, c) if c > 1 else (h, w)  # OpenCV takes (h, w, 1) as (h, w)
        scalar = tuple(float(f) for f in factor) + (0.0,) * (4 - c)
        res = cv2.multiply(image.reshape(shape), scalar, dst=out.reshape(shape), dtype=cv2.CV_32F)
        if saturates:
            res = cv2.min(res, (1.0, 1.0, 1.0, 1.0), dst=res)  # a 4-tuple: every channel (a bare 1.0 is channel 0's)
        if not np.shares_memory(res, out):  # a layout OpenCV could not write in place
            out[...] = res.reshape(out.shape)
        return out
    np.multiply(image, factor, out=out, dtype=np.float32)  # one rounding: as astype, then the product
    if saturates:
        np.minimum(out, np.float32(1.0), out=out)
    return out


def _scaled(image: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """float32 (H, W, C) image times ``gains`` (C,), clipped to 1 where a gain exceeds 1 (a new array)."""
    out = np.multiply(image, gains, dtype=np.float32)
    if float(gains.max()) > 1.0:
        np.minimum(out, np.float32(1.0), out=out)
    return out


def _times_weight(colour: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """float32 (h, w, C) ``colour * weight[..., None]`` of colour (h, w, C) and weight (h, w), in this
    thread's scratch array 'weighted' (:mod:`.scratch`).

    The same products (one float32 rounding each) as numpy's broadcast, which runs element by element
    over the channel axis; OpenCV multiplies whole rows of a weight expanded to C channels instead.
    """
    h, w, c = colour.shape
    if c == 1:
        return np.multiply(colour[:, :, 0], weight, out=scratch('weighted', (h, w)))[:, :, None]
    expanded = scratch('expanded', colour.shape)
    if c == 3:
        expanded = cv2.cvtColor(weight, cv2.COLOR_GRAY2RGB, dst=expanded)
    else:
        expanded = cv2.merge([weight] * c, dst=expanded)
    return cv2.multiply(colour, expanded, dst=scratch('weighted', colour.shape)).reshape(colour.shape)


def _add_into(dst: np.ndarray, src: np.ndarray) -> None:
    """dst += src in place (float32 views of one shape); OpenCV's add runs about twice as fast as
    numpy's on these tile views, with the same sums."""
    if cv2.add(dst, src, dst=dst) is not dst:  # a layout OpenCV could not write in place: numpy's way
        np.add(dst, src, out=dst)


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
            Lanczos-4: a little sharper, about five times the cost) or ``'linear'`` (bilinear: the
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

    _threads = 1  # canvases pickled before the setting existed
    _pool = None

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without its painting threads (started again by the next paint)."""
        state = dict(self.__dict__)
        state['_pool'] = None
        return state

    def __init__(
        self,
        channels: int,
        tile_size: int = 256,
        *,
        blend: str = 'feather',
        feather_profile: str = 'separable',
        feather_power: float = 1.0,
        max_canvas_side_px: int = 100000,
        max_area_ratio: float = 50.0,
        bands: int = 0,
        background: float = 0.0,
        max_tiles_in_memory: int = 0,
        spill_dir: str | os.PathLike[str] = '',
        max_stretch: float = 0.0,
        recency_frames: int = 90,
        agree: float = 0.0,
        moving: float = 0.0,
        moving_history: int = 5,
        seams: str = 'score',
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
        self._threads = threads
        self._pool: ThreadPoolExecutor | None = None  # the painting threads, started by the first paint that uses them
        self._max_stretch = float(max_stretch)
        self._interpolation = interpolation
        self._recency_frames = int(recency_frames)
        self._agree = float(agree)
        self._moving = float(moving)
        self._seam_cut = blend in ('bestview', 'multiband') and seams == 'cut'
        self._channels = int(channels)
        self._tile_size = int(tile_size)
        self._blend = blend
        self._profile = feather_profile
        self._power = float(feather_power)
        self._max_side = int(max_canvas_side_px)
        self._max_area_ratio = float(max_area_ratio)
        self._bands = int(bands)
        self._background = np.float32(background)
        history = int(moving_history) if (blend == 'bestview' and self._moving > 0) else 0
        self._store = TileStore(TileLayout(self._tile_size, self._channels, blend == 'multiband', blend == 'bestview', history),
                                max_in_memory=int(max_tiles_in_memory), spill_dir=spill_dir)
        self._tile_frames: dict[TileKey, int] = {}  # every tile: how many frames wrote into it
        self._touched: set[TileKey] = set()
        self._reader = CanvasReader(self)  # render, previews, labels: the reading half
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
        return self._blend

    @property
    def interpolation(self) -> str:
        """How the colour of a frame is sampled (:mod:`.resample`)."""
        return getattr(self, '_interpolation', 'linear')  # canvases pickled before the setting: bilinear

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
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
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
    def _as_image(self, image: np.ndarray) -> np.ndarray:
        """(H, W, C) C-contiguous float32, or uint8 as given."""
        if not isinstance(image, np.ndarray):
            msg = f'image must be a numpy array, got {type(image).__name__}.'
            raise CanvasError(msg)
        if not (np.issubdtype(image.dtype, np.floating) or image.dtype == np.uint8):
            msg = (f'image dtype {image.dtype} is neither floating point nor uint8; convert it to float32 in [0, 1] '
                   '(e.g. core.image_ops.to_float01).')
            raise CanvasError(msg)
        if image.ndim == 2 and self._channels == 1:
            image = image[:, :, None]
        if image.ndim != 3 or image.shape[2] != self._channels:
            msg = (f'image shape {image.shape} does not match the canvas: expected (H, W, {self._channels})'
                   + (' or (H, W)' if self._channels == 1 else '') + '.')
            raise CanvasError(msg)
        if image.shape[0] < 1 or image.shape[1] < 1:
            msg = f'image shape {image.shape} is empty.'
            raise CanvasError(msg)
        return np.ascontiguousarray(image, dtype=np.uint8 if image.dtype == np.uint8 else np.float32)

    def _as_scale(self, scale: np.ndarray | None) -> np.ndarray | None:
        """(C,) float32 positive finite multipliers, or None."""
        if scale is None:
            return None
        g = np.asarray(scale, dtype=np.float64).reshape(-1)
        if g.shape != (self._channels,) or not np.all(np.isfinite(g)) or not np.all(g > 0):
            msg = f'scale must be {self._channels} positive finite multipliers (one per channel), got {scale!r}.'
            raise CanvasError(msg)
        return g.astype(np.float32)

    def _as_mask(self, mask: np.ndarray | None, img: np.ndarray, finite: bool = False) -> np.ndarray | None:
        """Valid-pixel mask (bool (H, W)) or None when every pixel is valid and finite (``finite``: the
        caller knows it is, the image is not read)."""
        valid = None
        if mask is not None:
            mask = np.asarray(mask)
            if mask.shape != img.shape[:2]:
                msg = f'mask shape {mask.shape} differs from the image shape {img.shape[:2]}.'
                raise CanvasError(msg)
            valid = mask.astype(bool)
        # fast path: the extremes (NaN propagates through both), the full check only if needed
        if not finite and not (np.isfinite(img.max()) and np.isfinite(img.min())):
            finite = np.isfinite(img).all(axis=2)
            if not finite.all():
                valid = finite if valid is None else valid & finite
        return valid

    @staticmethod
    def _as_tiles(tiles: Collection[TileKey]) -> tuple[frozenset[TileKey], tuple[int, int, int, int] | None]:
        """(``tiles`` as a frozenset, their (min tx, min ty, max tx, max ty) or None when empty);
        CanvasError when a key is not a pair of integers."""
        try:
            keys = frozenset((int(tx), int(ty)) for tx, ty in tiles)
        except (TypeError, ValueError) as exc:
            msg = f'tiles must be (tx, ty) pairs of integers: {exc}'
            raise CanvasError(msg) from exc
        if not keys:
            return keys, None
        a = np.array(list(keys), np.int64)
        lo, hi = a.min(axis=0), a.max(axis=0)
        return keys, (int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1]))

    @staticmethod
    def _as_rects(tiles: Mapping[TileKey, tuple[int, int, int, int]]) -> dict[TileKey, tuple[int, int, int, int]]:
        """{(tx, ty): (x0, y0, x1, y1)} as integers; CanvasError when a rectangle is not 4 integers."""
        try:
            out = {(int(k[0]), int(k[1])): tuple(int(v) for v in r) for k, r in tiles.items()}
            if any(len(r) != 4 for r in out.values()):
                raise ValueError('a rectangle of other than 4 numbers')
            return out  # type: ignore[return-value]
        except (TypeError, ValueError) as exc:
            msg = f'tiles must map (tx, ty) to (x0, y0, x1, y1) integers: {exc}'
            raise CanvasError(msg) from exc

    def _as_homography(self, mosaic_h_frame: np.ndarray, w: int, h: int) -> np.ndarray:
        """Checked float64 homography with positive projective depth over the frame."""
        m = np.asarray(mosaic_h_frame, dtype=np.float64)
        if m.shape != (3, 3):
            msg = f'mosaic_H_frame must be a 3x3 matrix, got shape {m.shape}.'
            raise CanvasError(msg)
        if not np.isfinite(m).all():
            msg = f'mosaic_H_frame has non-finite entries:\n{m}\nthe registration or chain diverged; skip this frame.'
            raise CanvasError(msg)
        if not np.abs(m).max() > 0:
            msg = 'mosaic_H_frame is the zero matrix; skip this frame.'
            raise CanvasError(msg)
        corners = np.array([[-1.0, -1.0], [w, -1.0], [w, h], [-1.0, h]])
        _, depth = project_points(m, corners)
        if (depth <= 0).all():
            m = -m
            depth = -depth
        tol = 1e-9 * np.abs(depth).max()
        if not (depth > tol).all() and not self._max_stretch > 0:
            msg = ('mosaic_H_frame maps part of the frame beyond the horizon (the projective depth '
                   f'changes sign over the frame: {depth.tolist()}); the homography is absurd, skip this frame '
                   '(or set mosaic.max_stretch to paint the part of the frame below the horizon).')
            raise CanvasError(msg)
        corners = clipped_polygon(m, corners, clip_depth(m, w, h, self._max_stretch))
        if len(corners) < 3:
            msg = 'mosaic_H_frame maps the whole frame beyond the horizon; the homography is absurd, skip this frame.'
            raise CanvasError(msg)
        pts, _ = project_points(m, corners)
        x, y = pts[:, 0], pts[:, 1]
        area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
        if not area > 1e-6 * (w + 1) * (h + 1):
            msg = f'mosaic_H_frame is (nearly) singular, it collapses the frame to area {area:.3g} px^2:\n{m}\nskip this frame.'
            raise CanvasError(msg)
        return m

    def check_placement(self, mosaic_H_frame: np.ndarray, width: int, height: int) -> None:
        """Raise CanvasError where :meth:`paint` would refuse a width x height frame at mosaic_H_frame
        (an absurd homography, or a canvas beyond max_canvas_side_px), without painting it."""
        self._placement(self._as_homography(mosaic_H_frame, width, height), width, height)

    def _placement(self, m: np.ndarray, w: int, h: int) -> tuple[int, int, int, int]:
        """Bounding box (x0, y0, x1, y1) of the mosaic pixels a w x h frame at m touches; CanvasError
        when it is absurd or would make the canvas exceed max_canvas_side_px."""
        # Bilinear sampling gives non-zero weight to mosaic pixels mapping inside (-1, W) x (-1, H)
        # (one pixel beyond the cut of max_stretch: the depth changes by |m20| + |m21| per pixel).
        d_min = clip_depth(m, w, h, self._max_stretch)
        if d_min is not None:
            d_min = max(d_min - abs(m[2, 0]) - abs(m[2, 1]), 0.5 * d_min)
        support, _ = project_points(m, clipped_polygon(m, np.array([[-1.0, -1.0], [w, -1.0], [w, h], [-1.0, h]]), d_min))
        lo = support.min(axis=0)
        hi = support.max(axis=0)
        bw_f, bh_f = hi[0] - lo[0], hi[1] - lo[1]
        if bw_f * bh_f > self._max_area_ratio * max(w * h, 64):
            msg = (f'the footprint of a {w}x{h} frame spans {bw_f:.0f}x{bh_f:.0f} mosaic pixels, more than '
                   f'{self._max_area_ratio:g} times the frame area; mosaic_H_frame is absurd:\n{m}\n'
                   'skip this frame (or raise max_area_ratio if such a zoom is intended).')
            raise CanvasError(msg)
        x0, y0 = math.floor(lo[0]), math.floor(lo[1])
        x1, y1 = math.floor(hi[0]) + 1, math.floor(hi[1]) + 1
        ux0, uy0, ux1, uy1 = (x0, y0, x1, y1) if self._bounds is None else (
            min(x0, self._bounds[0]), min(y0, self._bounds[1]), max(x1, self._bounds[2]), max(y1, self._bounds[3]))
        if max(ux1 - ux0, uy1 - uy0) > self._max_side:
            msg = (f'painting this frame would make the canvas {ux1 - ux0}x{uy1 - uy0} px, beyond '
                   f'max_canvas_side_px={self._max_side} (footprint bbox x [{x0}, {x1}), y [{y0}, {y1})); '
                   'the chain has drifted or the homography is absurd: skip the frame or start a new segment.')
            raise CanvasError(msg)
        return x0, y0, x1, y1

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
                integers (OpenCV's fixed-point bilinear, about twice as fast as on floats) and
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
        gains = self._as_scale(scale)
        img = self._as_image(image)
        h, w = img.shape[:2]
        m = self._as_homography(mosaic_H_frame, w, h)
        if img.dtype != np.uint8 and gains is not None:
            img = _scaled(img, gains)
        valid = self._as_mask(mask, img, finite or img.dtype == np.uint8)
        footprint, _ = project_points(m, np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]))
        x0, y0, x1, y1 = self._placement(m, w, h)
        t = self._tile_size
        rects: dict[TileKey, tuple[int, int, int, int]] | None = None
        if tiles is not None:
            rects = self._as_rects(tiles) if isinstance(tiles, Mapping) else None
            tiles, keys = self._as_tiles(tiles)
            if keys is not None:  # the box shrinks to those tiles: no weight warped where none is painted
                x0, y0 = max(x0, keys[0] * t), max(y0, keys[1] * t)
                x1, y1 = min(x1, (keys[2] + 1) * t), min(y1, (keys[3] + 1) * t)
            if rects:  # ... and to the pixels asked for in them
                r = np.array(list(rects.values()))
                x0, y0 = max(x0, int(r[:, 0].min())), max(y0, int(r[:, 1].min()))
                x1, y1 = min(x1, int(r[:, 2].max())), min(y1, int(r[:, 3].max()))
            if keys is None or x1 <= x0 or y1 <= y0:
                self._frames += 1
                return PaintResult(self._frames - 1, (), footprint, (0, 0, 0, 0))
        level = minify_level(m, w, h, clip_depth(m, w, h, self._max_stretch))
        if level:  # a frame shrinking on the mosaic is reduced first, not point-sampled (minify.py)
            if img.dtype == np.uint8:  # reduced as floats
                img = _to_float(img, gains)
            if valid is not None:
                img = _fill_invalid(img, valid)
            img, valid, m = reduce_frame(img, valid, m, level)
            h, w = img.shape[:2]
        best_view = self._blend == 'bestview'
        d_min = clip_depth(m, w, h, self._max_stretch)
        # view quality's resolution factor: 1 everywhere (not computed) unless a frame pixel lands
        # larger than a mosaic pixel somewhere
        coarse = best_view and magnified_somewhere(m, w, h)
        depth = depth_map(m, h, w) if (coarse or d_min is not None) else None
        if d_min is not None and depth is not None:  # the far field and sky of an oblique view stay out
            kept = depth >= np.float32(d_min)
            valid = kept if valid is None else valid & kept

        weight = feather_weight(h, w, profile=self._profile, power=self._power, mask=valid)
        if coarse and depth is not None:  # view quality: closeness to the centre x resolution
            r = resolution_factor(m, depth)
            weight = cv2.multiply(weight, r, dst=r)
        if valid is not None:
            if img.dtype == np.uint8:  # filled as floats
                img = _to_float(img, gains)
            img = _fill_invalid(img, valid, FILL_RINGS[self.interpolation])
        bw, bh = x1 - x0, y1 - y0
        box_h_frame = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ m
        src = FrameSampler(img[:, :, 0] if self._channels == 1 else img, self.interpolation)
        index = self._frames
        multiband = self._blend == 'multiband'
        jobs: list[tuple[TileKey, tuple[slice, slice], tuple[slice, slice]]] = []
        if rects is not None and not self._seam_cut:
            # Painted in part (a frame held back, where it reaches beyond its neighbours): the
            # boxes asked for are slivers at the footprint's edges, often at opposite corners, so
            # the weight is warped over each box alone, not over the box around them all.
            w_w, parts = None, self._rect_weights(weight, box_h_frame, rects, (x0, y0, x1, y1))
            if not parts:
                self._frames += 1
                return PaintResult(index, (), footprint, (0, 0, 0, 0))
            jobs = [(key, box, loc) for key, box, loc, _, _ in parts]
            part_w = {key: sub for key, _, _, _, sub in parts}
            nz = np.array([b for _, _, _, b, _ in parts])
            gx0, gy0, gx1, gy1 = int(nz[:, 0].min()), int(nz[:, 1].min()), int(nz[:, 2].max()), int(nz[:, 3].max())
        else:
            # into this thread's scratch arrays: they live until paint returns (the tiles keep copies)
            w_w = cv2.warpPerspective(weight, box_h_frame, (bw, bh), dst=scratch('weight', (bh, bw)),
                                      flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
            # Tight box of non-zero weight, in box coordinates (one C pass over a mask, not two reductions).
            c0, r0, nc, nr = cv2.boundingRect((w_w != 0).view(np.uint8))
            if nc == 0:
                self._frames += 1
                return PaintResult(index, (), footprint, (0, 0, 0, 0))
            c1, r1 = c0 + nc, r0 + nr
            gx0, gy0, gx1, gy1 = x0 + c0, y0 + r0, x0 + c1, y0 + r1
            part_w = None
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
        # Every tile first (loading spilled ones may fail: then nothing is written), then write.
        tiles = [self._store.get(key, create=True) for key, _, _ in jobs]
        self._frames += 1
        # The colour over the whole box at once (what the seams' cut compares), or, painting on
        # threads, warped tile by tile: each in cache through its updates, no box-sized array
        img_w = None
        if (self._seam_cut or self._threads == 1) and w_w is not None:
            img_w = self._warp_colour(src, box_h_frame, (slice(0, bh), slice(0, bw)), gains, 'colour')
        cut = self._cut(jobs, tiles, img_w, w_w, index) if self._seam_cut and img_w is not None and w_w is not None \
            else None

        def offer(job: tuple[TileKey, tuple[slice, slice], tuple[slice, slice]], tile: Any) -> None:
            key, box, loc = job
            sub_w = w_w[box] if w_w is not None else part_w[key]  # type: ignore[index]
            # a tile's colour warped on its own stays in cache through the updates below
            colour = img_w[box] if img_w is not None else self._warp_colour(src, box_h_frame, box, gains, 'tile_colour')
            tile_cut = None if cut is None else (cut[0][box], cut[1][box])
            _add_into(tile.acc[loc], _times_weight(colour, sub_w))  # per tile: the product stays in cache
            _add_into(tile.wsum[loc], sub_w)
            if best_view:
                update_best(tile, loc, colour, sub_w, index, self._recency_frames, self._agree, self._moving,
                            cut=tile_cut)
            if multiband:
                update_max_weight(tile, loc, colour, sub_w, index, cut=tile_cut)

        workers = min(self._threads, len(jobs))
        if workers > 1:  # tiles are independent; OpenCV and numpy release the GIL on their arrays
            if self._pool is None:  # the same threads (and their scratch arrays) from paint to paint
                self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix='paint')
            for _ in self._pool.map(offer, jobs, tiles):
                pass
        else:
            for job, tile in zip(jobs, tiles):
                offer(job, tile)
        touched: list[TileKey] = [key for key, _, _ in jobs]
        for key in touched:
            self._tile_frames[key] = self._tile_frames.get(key, 0) + 1
        del tiles
        self._touched.update(touched)
        self._reader.mark_painted(touched)
        bbox = (gx0, gy0, gx1, gy1)
        self._bounds = bbox if self._bounds is None else (
            min(gx0, self._bounds[0]), min(gy0, self._bounds[1]),
            max(gx1, self._bounds[2]), max(gy1, self._bounds[3]))
        self._store.trim()  # back to the bound; may raise TileStoreError (the frame is painted)
        return PaintResult(index, tuple(sorted(touched, key=lambda k: (k[1], k[0]))), footprint, bbox)

    def _rect_weights(self, weight: np.ndarray, box_h_frame: np.ndarray,
                      rects: dict[TileKey, tuple[int, int, int, int]], placement: tuple[int, int, int, int],
                      ) -> list[tuple[TileKey, tuple[slice, slice], tuple[slice, slice], tuple[int, int, int, int],
                                      np.ndarray]]:
        """Jobs of a paint in part: (tile, box slices, tile slices, tight mosaic box (x0, y0, x1, y1) of
        non-zero weight, the warped weight over the box): the weight (frame-sized float32, warped
        through ``box_h_frame``, whose box starts at ``placement``'s corner) over each tile's
        asked-for box of ``rects`` within ``placement``, where it is non-zero somewhere."""
        x0, y0, x1, y1 = placement
        t = self._tile_size
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

    def _warp_colour(self, src: FrameSampler, box_h_frame: np.ndarray, box: tuple[slice, slice],
                     gains: np.ndarray | None, name: str) -> np.ndarray:
        """float32 (h, w, C) colour of the frame ``src`` (float32, or uint8: warped as integers, then
        converted with ``gains``) over ``box`` (slices of the paint's box, whose homography from the
        frame is ``box_h_frame``), in this thread's scratch array ``name``."""
        ys, xs = box
        h, w, c = ys.stop - ys.start, xs.stop - xs.start, self._channels
        m = np.array([[1.0, 0.0, -xs.start], [0.0, 1.0, -ys.start], [0.0, 0.0, 1.0]]) @ box_h_frame
        if src.src.dtype == np.uint8:  # gains (if any) applied after the warp
            return _to_float(src.warp(m, (w, h)), gains, scratch(name, (h, w, c)))
        return src.warp(m, (w, h), dst=scratch(name, (h, w, *src.src.shape[2:])))

    def _cut(self, jobs: list[tuple[TileKey, tuple[slice, slice], tuple[slice, slice]]], tiles: list[Any],
             img_w: np.ndarray, w_w: np.ndarray, index: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The seams' graph cut (:mod:`.seam_cut`) between the warped frame (img_w, its quality w_w,
        over the paint's box) and the winners of the tiles under it (``jobs``, ``tiles``), on blocks:
        (free, take) bool over the box, where the cut decides and where the frame leads there; None
        where the scores decide everywhere."""
        bh, bw = w_w.shape
        s = block_size(bh, bw)
        best = np.zeros((bh, bw, self._channels), np.float32)
        best_view = self._blend == 'bestview'  # best_w: log scores (-inf: none); multiband: weights (0: none)
        best_w = np.full((bh, bw), -1e30 if best_view else 0.0, np.float32)
        for (_, box, loc), tile in zip(jobs, tiles):
            best[box] = tile.best[loc]
            if best_view:
                np.maximum(tile.best_w[loc], np.float32(-1e30), out=best_w[box])  # no winner: never free
            else:
                best_w[box] = tile.best_w[loc]
        score = np.log(np.maximum(block_means(w_w, s), np.float32(1e-30)))
        if best_view:
            score += np.float32(index / self._recency_frames if self._recency_frames > 0 else 0.0)
            winners = block_means(best_w, s)
        else:  # the log of the mean weight, as the frame's; a block with a pixel no frame won is never free
            winners = np.log(np.maximum(block_means(best_w, s), np.float32(1e-30)))
            winners[block_means(best_w <= 0, s) > 0] = -1e30
        diff = block_means(img_w, s) - block_means(best, s)
        free, take = cut_nodes(score, winners, diff.reshape(*score.shape, -1), s)
        if not free.any():
            return None
        return expand(free, s, (bh, bw)), expand(take, s, (bh, bw))

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
