"""XYZ tiles of a georeferenced raster: the tile grid of EPSG:3857 and the rendering of one tile.

The grid is morecantile's ``WebMercatorQuad`` (the XYZ grid of Leaflet, OpenLayers and MapLibre:
zoom z, column x from the west, row y from the north, 256x256 pixels); each tile is reprojected
from the raster's own CRS (the mosaic's UTM zone) by GDAL's warper (``rasterio.warp.reproject``),
the raster's alpha band weighting the resampling so that uncovered pixels stay transparent. No
projection formula is written here: tile bounds come from morecantile, every coordinate change
from PROJ through rasterio.

- :func:`zoom_range`: the zooms worth serving for a raster: the deepest is the first whose pixel is
  no larger than the raster's ground sample distance, the shallowest the one where the whole raster
  fits in one tile (it then spans one to four).
- :func:`render_tile`: (256, 256, 4) uint8 RGBA of one tile of a raster (a dataset or an array with
  its transform and CRS), or None where nothing is painted. A dataset is read from the overview
  whose pixel is the finest that is still no finer than the tile's (a COG's overviews, so a
  zoomed-out tile reads few blocks).
- :func:`render_block`: the same for a block of nx x ny tiles in one warp (the files of ``process --tiles``).
- :func:`encode_tile`: PNG or WebP bytes of such a tile (alpha kept).
- :func:`tiles_covering`: the tiles of one zoom that meet a lon/lat box.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from .source import MAX_ZOOM, TILE_SIZE

__all__ = ['WEB_MERCATOR', 'RasterGrid', 'encode_tile', 'render_block', 'render_tile', 'tile_bounds', 'tile_transform',
           'tiles_covering', 'zoom_range']

#: The CRS of the tiles (Web Mercator).
WEB_MERCATOR = 'EPSG:3857'


#: The start of the one rasterio warning that :func:`_quiet_rasterio` silences.
_NO_TRANSFORM = 'Dataset has no geotransform'


def _quiet_rasterio() -> None:
    """rasterio warns that the in-memory datasets it makes of reproject's arrays have no transform, before it
    sets the one given; said once per process, it is noise in a command's output. Only that message is
    silenced, by a filter (catch_warnings is not safe across the server's threads), added again if
    something (a test harness) reset the filters."""
    import warnings

    from rasterio.errors import NotGeoreferencedWarning

    if not any(f[0] == 'ignore' and f[1] is not None and f[1].pattern == _NO_TRANSFORM for f in warnings.filters):
        warnings.filterwarnings('ignore', message=_NO_TRANSFORM, category=NotGeoreferencedWarning)


@functools.cache
def _tms() -> Any:
    """The WebMercatorQuad grid (morecantile copies it on each ``get``: kept once)."""
    import morecantile

    return morecantile.tms.get('WebMercatorQuad')


def tile_bounds(z: int, x: int, y: int) -> tuple[float, float, float, float]:
    """(left, bottom, right, top) of tile (z, x, y) in EPSG:3857 metres."""
    import morecantile

    b = _tms().xy_bounds(morecantile.Tile(x, y, z))
    return (b.left, b.bottom, b.right, b.top)


def tile_transform(z: int, x: int, y: int) -> Any:
    """The affine transform (pixel corners, rasterio's ``Affine``) of tile (z, x, y)'s 256x256 pixels in EPSG:3857."""
    from rasterio.transform import Affine

    left, bottom, right, top = tile_bounds(z, x, y)
    return Affine((right - left) / TILE_SIZE, 0.0, left, 0.0, -(top - bottom) / TILE_SIZE, top)


@functools.cache
def _tile_pixel_3857(z: int) -> float:
    """The side of one tile pixel at zoom z, in EPSG:3857 metres (its true ground size shrinks away from the equator)."""
    return float(_tms().matrix(z).cellSize)


def tiles_covering(bounds_lonlat: tuple[float, float, float, float], z: int) -> Iterator[tuple[int, int, int]]:
    """(z, x, y) of every tile of zoom z that meets the box (west, south, east, north), in degrees."""
    for tile in _tms().tiles(*bounds_lonlat, [z]):
        yield tile.z, tile.x, tile.y


@dataclass(frozen=True)
class RasterGrid:
    """A raster's place on the map: CRS, affine transform (pixel corners), size and the tile grid's view of it.

    crs: a rasterio CRS (or anything ``rasterio.crs.CRS.from_user_input`` takes); transform: rasterio's
    ``Affine`` of pixel corners (rotation allowed); width, height: pixels.
    """

    crs: Any
    transform: Any
    width: int
    height: int

    @functools.cached_property
    def bounds_3857(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) of the raster in EPSG:3857 (its edges densified)."""
        from rasterio.warp import transform_bounds

        left, bottom, right, top = self._native_bounds()
        return tuple(transform_bounds(self.crs, WEB_MERCATOR, left, bottom, right, top, densify_pts=21))

    @functools.cached_property
    def bounds_lonlat(self) -> tuple[float, float, float, float]:
        """(west, south, east, north) of the raster in degrees (WGS84)."""
        from rasterio.warp import transform_bounds

        return tuple(transform_bounds(self.crs, 'EPSG:4326', *self._native_bounds(), densify_pts=21))

    def _native_bounds(self) -> tuple[float, float, float, float]:
        t, w, h = self.transform, self.width, self.height
        xs, ys = zip(*(t @ (c, r) for c, r in ((0, 0), (w, 0), (w, h), (0, h))), strict=True)
        return (min(xs), min(ys), max(xs), max(ys))

    def pixel_size(self) -> float:
        """Side of one raster pixel in its CRS's units (metres for UTM)."""
        t = self.transform
        return math.hypot(t.a, t.d)

    @functools.cached_property
    def pixel_size_3857(self) -> float:
        """Side of one raster pixel at its centre, in EPSG:3857 metres (PROJ maps a pixel-sized step there)."""
        from rasterio.warp import transform

        cx, cy = self.transform @ (self.width / 2.0, self.height / 2.0)
        step = self.pixel_size()
        xs, ys = transform(self.crs, WEB_MERCATOR, [cx - step / 2, cx + step / 2], [cy, cy])
        return math.hypot(xs[1] - xs[0], ys[1] - ys[0])


def zoom_range(grid: RasterGrid, *, max_zoom: int = MAX_ZOOM) -> tuple[int, int]:
    """(minzoom, maxzoom) of the XYZ tiles of a raster.

    maxzoom: the first zoom whose tile pixel is no larger than the raster's pixel on the ground (both
    measured in EPSG:3857 at the raster's centre), capped at max_zoom. minzoom: the deepest zoom at
    which the raster's longer side in EPSG:3857 is at most one tile (so one to four tiles hold it),
    never above maxzoom.
    """
    px = grid.pixel_size_3857
    maxzoom = next((z for z in range(max_zoom + 1) if _tile_pixel_3857(z) <= px), max_zoom)
    left, bottom, right, top = grid.bounds_3857
    side = max(right - left, top - bottom)
    minzoom = max((z for z in range(maxzoom + 1) if TILE_SIZE * _tile_pixel_3857(z) >= side), default=0)
    return min(minzoom, maxzoom), maxzoom


def dataset_grid(dataset: Any) -> RasterGrid:
    """The RasterGrid of an open rasterio dataset (kept per file and grid: its bounds are computed once)."""
    return _grid(dataset.name, dataset.crs.to_wkt(), tuple(dataset.transform)[:6], dataset.width, dataset.height)


@functools.lru_cache(maxsize=64)
def _grid(name: str, crs_wkt: str, transform: tuple[float, ...], width: int, height: int) -> RasterGrid:
    from rasterio.crs import CRS
    from rasterio.transform import Affine

    return RasterGrid(CRS.from_wkt(crs_wkt), Affine(*transform), width, height)


def overview_for(dataset: Any, z: int) -> int | None:
    """The index (rasterio's ``overview_level``) of ``dataset``'s overview to read for a tile of zoom z:
    the coarsest whose pixel is still no larger than the tile's pixel; None: the full resolution."""
    factors = dataset.overviews(1)
    if not factors:
        return None
    grid = dataset_grid(dataset)
    tile_px = _tile_pixel_3857(z)
    level = None
    for i, f in enumerate(factors):
        if grid.pixel_size_3857 * f <= tile_px:
            level = i
    return level


def _alpha_band(dataset: Any) -> int:
    """1-based index of the dataset's alpha band, 0 if it has none."""
    from rasterio.enums import ColorInterp

    for i, interp in enumerate(dataset.colorinterp, start=1):
        if interp == ColorInterp.alpha:
            return i
    return 0


def render_tile(source: Any, z: int, x: int, y: int, *, transform: Any = None, crs: Any = None,
                resampling: str = 'bilinear') -> np.ndarray | None:
    """(256, 256, 4) uint8 RGBA of tile (z, x, y) of a raster, or None where it paints nothing.

    source: an open rasterio dataset (uint8; grey, grey+alpha, RGB or RGBA, the alpha band marked
    as such), or a (C, H, W) uint8 array of the same bands (alpha last when C is 2 or 4) with its
    ``transform`` (rasterio ``Affine``, pixel corners) and ``crs``. A band layout without alpha is
    opaque wherever the raster reaches. Grey becomes R = G = B.

    resampling: a ``rasterio.enums.Resampling`` name (bilinear: smooth at every zoom; nearest:
    the raster's own pixels). Pixels the alpha band leaves uncovered never bleed into covered ones:
    GDAL's warper weights the resampling by alpha.
    """
    block = render_block(source, z, x, y, 1, 1, transform=transform, crs=crs, resampling=resampling)
    return None if block is None or not block[:, :, 3].any() else block


def render_block(source: Any, z: int, x0: int, y0: int, nx: int, ny: int, *, transform: Any = None, crs: Any = None,
                 resampling: str = 'bilinear') -> np.ndarray | None:
    """(256 ny, 256 nx, 4) uint8 RGBA of the nx x ny tiles of zoom z from (x0, y0), in one warp; None when
    the raster does not reach them. Tile (x0 + i, y0 + j) is the block's [256 j:256 (j + 1), 256 i:256 (i + 1)].
    Arguments as :func:`render_tile` (which is the 1 x 1 block); one warp of many tiles spares the
    warper's set-up per tile (``process --tiles``).

    The warp is of premultiplied colour (colour x alpha / 255, alpha as a fourth band), then divided
    by the warped alpha: the alpha-weighted resampling of GDAL's masked warp (uncovered pixels add
    nothing to covered ones), on GDAL's unmasked path, several times faster. Only the window of
    the raster that the block needs is read (from a dataset: its blocks, at the overview given).
    """
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    _quiet_rasterio()
    first, last = tile_bounds(z, x0, y0), tile_bounds(z, x0 + nx - 1, y0 + ny - 1)
    box = (first[0], last[1], last[2], first[3])
    if isinstance(source, np.ndarray):
        bands = source if source.ndim == 3 else source[None]
        grid = RasterGrid(crs, transform, bands.shape[2], bands.shape[1])
        interp_alpha = bands.shape[0] in (2, 4)
    else:
        grid = dataset_grid(source)
        interp_alpha = _alpha_band(source) == source.count
    if not _meets(grid.bounds_3857, box):
        return None
    window = _source_window(grid, box)
    if window is None:
        return None
    c0, r0, c1, r1 = window
    if isinstance(source, np.ndarray):
        cut = bands[:, r0:r1, c0:c1]
    else:
        from rasterio.windows import Window

        cut = source.read(window=Window(c0, r0, c1 - c0, r1 - r0))
    colour = cut.shape[0] - (1 if interp_alpha else 0)
    src = np.empty((colour + 1, r1 - r0, c1 - c0), np.uint8)
    if interp_alpha:
        alpha = cut[colour]
        # premultiplied colour: C A / 255, rounded (exact where alpha is 0 or 255, as in the mosaics)
        src[:colour] = ((cut[:colour].astype(np.uint16) * alpha + 127) // 255).astype(np.uint8)
        src[colour] = alpha
    else:
        src[:colour] = cut
        src[colour] = 255
    height, width = TILE_SIZE * ny, TILE_SIZE * nx
    dst = np.zeros((colour + 1, height, width), np.uint8)  # pixels the raster does not reach stay alpha 0
    t = grid.transform
    from rasterio.transform import Affine

    src_transform = t @ Affine.translation(c0, r0)
    reproject(src, dst, src_transform=src_transform, src_crs=grid.crs, src_nodata=None, dst_transform=tile_transform(z, x0, y0),
              dst_crs=WEB_MERCATOR, dst_nodata=None, resampling=Resampling[resampling], init_dest_nodata=False)
    a = dst[colour]
    rgba = np.zeros((height, width, 4), np.uint8)
    covered = a > 0
    scale = np.zeros(a.shape, np.float32)
    scale[covered] = 255.0 / a[covered]
    for i in range(3):
        c = dst[min(i, colour - 1)].astype(np.float32) * scale
        rgba[:, :, i] = np.minimum(c + 0.5, 255.0).astype(np.uint8)
    rgba[:, :, 3] = a
    return rgba


def _source_window(grid: RasterGrid, box_3857: tuple[float, float, float, float], margin: int = 2) -> tuple[int, int, int, int] | None:
    """(col0, row0, col1, row1) of the raster's pixels that an EPSG:3857 box needs, with ``margin`` pixels
    around for the resampling kernel; None when it misses the raster."""
    from rasterio.warp import transform_bounds

    left, bottom, right, top = transform_bounds(WEB_MERCATOR, grid.crs, *box_3857, densify_pts=21)
    inv = ~grid.transform
    cols, rows = zip(*(inv @ (x, y) for x, y in ((left, bottom), (left, top), (right, bottom), (right, top))), strict=True)
    c0, r0 = max(0, math.floor(min(cols)) - margin), max(0, math.floor(min(rows)) - margin)
    c1, r1 = min(grid.width, math.ceil(max(cols)) + margin), min(grid.height, math.ceil(max(rows)) + margin)
    if c1 <= c0 or r1 <= r0:
        return None
    return c0, r0, c1, r1


def _meets(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


#: Encoders of encode_tile: format -> (file suffix, OpenCV parameters).
ENCODINGS = {'png': ('.png', 'IMWRITE_PNG_COMPRESSION'), 'webp': ('.webp', 'IMWRITE_WEBP_QUALITY')}


def encode_tile(rgba: np.ndarray, fmt: str = 'png', *, level: int | None = None) -> bytes:
    """PNG or WebP bytes of an RGBA tile (H, W, 4) uint8, alpha kept.

    level: PNG's zlib level (0-9; None: 3, quick and close to the smallest) or WebP's quality
    (1-100; None: 90; above 100: lossless).
    """
    import cv2

    if fmt not in ENCODINGS:
        msg = f'tile format {fmt!r} is not one of {sorted(ENCODINGS)}.'
        raise ValueError(msg)
    suffix, param = ENCODINGS[fmt]
    value = level if level is not None else (3 if fmt == 'png' else 90)
    ok, buf = cv2.imencode(suffix, cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA), [getattr(cv2, param), int(value)])
    if not ok:
        msg = f'OpenCV could not encode a {fmt} tile.'
        raise RuntimeError(msg)
    return buf.tobytes()
