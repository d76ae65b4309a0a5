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
- :func:`encode_tile`: PNG or WebP bytes of such a tile (alpha kept).
- :func:`tiles_covering`: the tiles of one zoom that meet a lon/lat box.
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from .source import MAX_ZOOM, TILE_SIZE

__all__ = ['WEB_MERCATOR', 'RasterGrid', 'encode_tile', 'render_tile', 'tile_bounds', 'tile_transform',
           'tiles_covering', 'zoom_range']

#: The CRS of the tiles (Web Mercator).
WEB_MERCATOR = 'EPSG:3857'


def _tms() -> Any:
    import morecantile

    return morecantile.tms.get('WebMercatorQuad')


def tile_bounds(z: int, x: int, y: int) -> tuple[float, float, float, float]:
    """(left, bottom, right, top) of tile (z, x, y) in EPSG:3857 metres."""
    import morecantile

    b = _tms().xy_bounds(morecantile.Tile(x, y, z))
    return (b.left, b.bottom, b.right, b.top)


def tile_transform(z: int, x: int, y: int) -> Any:
    """The affine transform (pixel corners, rasterio's ``Affine``) of tile (z, x, y)'s 256x256 pixels in EPSG:3857."""
    from rasterio.transform import from_bounds

    return from_bounds(*tile_bounds(z, x, y), TILE_SIZE, TILE_SIZE)


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

    def bounds_3857(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) of the raster in EPSG:3857 (its edges densified)."""
        from rasterio.warp import transform_bounds

        left, bottom, right, top = self._native_bounds()
        return tuple(transform_bounds(self.crs, WEB_MERCATOR, left, bottom, right, top, densify_pts=21))

    def bounds_lonlat(self) -> tuple[float, float, float, float]:
        """(west, south, east, north) of the raster in degrees (WGS84)."""
        from rasterio.warp import transform_bounds

        return tuple(transform_bounds(self.crs, 'EPSG:4326', *self._native_bounds(), densify_pts=21))

    def _native_bounds(self) -> tuple[float, float, float, float]:
        t, w, h = self.transform, self.width, self.height
        xs, ys = zip(*(t * (c, r) for c, r in ((0, 0), (w, 0), (w, h), (0, h))), strict=True)
        return (min(xs), min(ys), max(xs), max(ys))

    def pixel_size(self) -> float:
        """Side of one raster pixel in its CRS's units (metres for UTM)."""
        t = self.transform
        return math.hypot(t.a, t.d)

    def pixel_size_3857(self) -> float:
        """Side of one raster pixel at its centre, in EPSG:3857 metres (PROJ maps a pixel-sized step there)."""
        from rasterio.warp import transform

        cx, cy = self.transform * (self.width / 2.0, self.height / 2.0)
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
    px = grid.pixel_size_3857()
    maxzoom = next((z for z in range(max_zoom + 1) if _tile_pixel_3857(z) <= px), max_zoom)
    left, bottom, right, top = grid.bounds_3857()
    side = max(right - left, top - bottom)
    minzoom = max((z for z in range(maxzoom + 1) if TILE_SIZE * _tile_pixel_3857(z) >= side), default=0)
    return min(minzoom, maxzoom), maxzoom


def overview_for(dataset: Any, z: int) -> int | None:
    """The index (rasterio's ``overview_level``) of ``dataset``'s overview to read for a tile of zoom z:
    the coarsest whose pixel is still no larger than the tile's pixel; None: the full resolution."""
    factors = dataset.overviews(1)
    if not factors:
        return None
    grid = RasterGrid(dataset.crs, dataset.transform, dataset.width, dataset.height)
    tile_px = _tile_pixel_3857(z)
    level = None
    for i, f in enumerate(factors):
        if grid.pixel_size_3857() * f <= tile_px:
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
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    dst_transform = tile_transform(z, x, y)
    if isinstance(source, np.ndarray):
        bands = source if source.ndim == 3 else source[None]
        count = bands.shape[0]
        alpha = count if count in (2, 4) else 0
        grid = RasterGrid(crs, transform, bands.shape[2], bands.shape[1])
        src_args: dict[str, Any] = {'source': bands, 'src_transform': transform, 'src_crs': crs}
    else:
        import rasterio

        count = source.count
        alpha = _alpha_band(source)
        grid = RasterGrid(source.crs, source.transform, source.width, source.height)
        src_args = {'source': rasterio.band(source, list(range(1, count + 1)))}
    if not _meets(grid.bounds_3857(), tile_bounds(z, x, y)):
        return None
    colour = count - (1 if alpha else 0)
    out_count = colour + 1
    dst = np.zeros((out_count, TILE_SIZE, TILE_SIZE), np.uint8)
    if not alpha:  # an alpha for the warper to write: where the raster reaches
        src_args['src_nodata'] = None
    reproject(**src_args, destination=dst if alpha else dst[:colour], dst_transform=dst_transform,
              dst_crs=WEB_MERCATOR, resampling=Resampling[resampling], src_alpha=alpha, dst_alpha=out_count if alpha else 0,
              init_dest_nodata=False)
    if not alpha:
        reach = np.zeros((1, TILE_SIZE, TILE_SIZE), np.uint8)
        ones = np.full((1, grid.height, grid.width), 255, np.uint8)
        reproject(ones, reach, src_transform=grid.transform, src_crs=grid.crs, dst_transform=dst_transform,
                  dst_crs=WEB_MERCATOR, resampling=Resampling.nearest, src_nodata=0, dst_nodata=0)
        dst[colour] = reach[0]
    if not dst[colour].any():
        return None
    rgba = np.empty((TILE_SIZE, TILE_SIZE, 4), np.uint8)
    rgba[:, :, :3] = dst[:colour].transpose(1, 2, 0) if colour == 3 else dst[0][:, :, None]
    rgba[:, :, 3] = dst[colour]
    rgba[rgba[:, :, 3] == 0, :3] = 0  # nothing under alpha 0: tiles compress better, viewers agree
    return rgba


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
