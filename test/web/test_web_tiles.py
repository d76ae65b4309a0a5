"""web/tiles.py: the XYZ grid against known coordinates, the zoom range from the GSD, transparency, encodings."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import rasterio  # a pinned dependency: a missing install must fail, not skip
from pyproj import Transformer
from web_fixtures import GSD, HEIGHT, WIDTH, ground_pixel_m, synthetic_run

from srmosaic_ros.web.tiles import RasterGrid, encode_tile, render_tile, tile_bounds, tiles_covering, zoom_range

TO_3857 = Transformer.from_crs(4326, 3857, always_xy=True)


def _tile_pixel_of(lon: float, lat: float, z: int) -> tuple[int, int, float, float]:
    """(x, y) of the tile holding a point, and the point's pixel (column, row) in it, found with PROJ
    (EPSG:4326 -> 3857) and the grid's extent, independently of web/tiles.py."""
    half = 20037508.342789244  # EPSG:3857's half extent (m)
    mx, my = TO_3857.transform(lon, lat)
    n = 2 ** z
    fx, fy = (mx + half) / (2 * half) * n, (half - my) / (2 * half) * n
    x, y = int(fx), int(fy)
    return x, y, (fx - x) * 256, (fy - y) * 256


def _red_centroid(rgba: np.ndarray) -> tuple[float, float]:
    red = (rgba[..., 0] > 200) & (rgba[..., 1] < 80) & (rgba[..., 2] < 80) & (rgba[..., 3] > 200)
    assert red.any(), 'the marker is not in the tile'
    rows, cols = np.nonzero(red)
    return float(cols.mean()), float(rows.mean())


@pytest.mark.parametrize('rotation_rad', [0.0, 0.3])
def test_marker_lands_on_its_tile_pixel(tmp_path, rotation_rad):
    """A red square painted at a known lon/lat lands in the tile and tile pixel the XYZ grid puts it at
    (within a pixel), for a north-up mosaic and a turned one (re-anchored mosaics are turned)."""
    run = synthetic_run(tmp_path, rotation_rad=rotation_rad, sr=False)
    lon, lat = run.marker_lonlat
    with rasterio.open(run.out / 'mosaic.tif') as ds:
        grid = RasterGrid(ds.crs, ds.transform, ds.width, ds.height)
        _, maxzoom = zoom_range(grid)
        for z in (maxzoom, maxzoom + 2):  # at maxzoom the marker is 7 px; deeper, larger
            x, y, col, row = _tile_pixel_of(lon, lat, z)
            # the tile and its 8 neighbours side by side: the marker may straddle a tile's edge
            block = np.zeros((768, 768, 4), np.uint8)
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    rgba = render_tile(ds, z, x + dx, y + dy, resampling='nearest')
                    if rgba is not None:
                        assert rgba.shape == (256, 256, 4) and rgba.dtype == np.uint8
                        block[256 * (dy + 1):256 * (dy + 2), 256 * (dx + 1):256 * (dx + 2)] = rgba
            cx, cy = _red_centroid(block)
            assert abs(cx - (256 + col)) <= 1.0 and abs(cy - (256 + row)) <= 1.0, (z, (cx, cy), (col, row))
            left, bottom, right, top = tile_bounds(z, x, y)
            mx, my = TO_3857.transform(lon, lat)
            assert left <= mx < right and bottom < my <= top


def test_zoom_range_follows_the_gsd(tmp_path):
    run = synthetic_run(tmp_path, sr=False)
    with rasterio.open(run.out / 'mosaic.tif') as ds:
        grid = RasterGrid(ds.crs, ds.transform, ds.width, ds.height)
    minzoom, maxzoom = zoom_range(grid)
    lat = run.marker_lonlat[1]
    # maxzoom: the first whose pixel is no larger than the GSD (UTM's scale near the zone's middle: < 0.1 %)
    assert ground_pixel_m(maxzoom, lat) <= GSD * 1.001 < ground_pixel_m(maxzoom - 1, lat)
    # minzoom: the whole mosaic in one to four tiles, and at the next zoom it is larger than one tile
    assert 1 <= len(list(tiles_covering(grid.bounds_lonlat, minzoom))) <= 4
    side_m = max(WIDTH, HEIGHT) * GSD
    assert side_m > 256 * ground_pixel_m(minzoom + 1, lat)
    assert minzoom < maxzoom


def test_uncovered_pixels_are_transparent_and_empty_tiles_none(tmp_path):
    run = synthetic_run(tmp_path, sr=False)
    with rasterio.open(run.out / 'mosaic.tif') as ds:
        grid = RasterGrid(ds.crs, ds.transform, ds.width, ds.height)
        _, maxzoom = zoom_range(grid)
        # the raster's upper-left corner is outside the covered ellipse: transparent, and nothing under it
        corner = run.raster.lonlat_from_pixels(np.array([[2.0, 2.0]]))[0]
        x, y, col, row = _tile_pixel_of(corner[0], corner[1], maxzoom)
        rgba = render_tile(ds, maxzoom, x, y)
        if rgba is not None:
            assert rgba[int(row), int(col), 3] == 0 and not rgba[int(row), int(col), :3].any()
        # the middle is covered and opaque
        middle = run.raster.lonlat_from_pixels(np.array([[WIDTH / 2, HEIGHT / 2]]))[0]
        x, y, col, row = _tile_pixel_of(middle[0], middle[1], maxzoom)
        assert render_tile(ds, maxzoom, x, y)[int(row), int(col), 3] == 255
        # a tile far away paints nothing
        x, y, _, _ = _tile_pixel_of(middle[0] + 1.0, middle[1], maxzoom)
        assert render_tile(ds, maxzoom, x, y) is None


def test_array_source_matches_the_dataset(tmp_path):
    """An in-memory raster (the live map's canvas) renders as the same raster read from a file."""
    run = synthetic_run(tmp_path, sr=False)
    with rasterio.open(run.out / 'mosaic.tif') as ds:
        bands, transform, crs = ds.read(), ds.transform, ds.crs
        z = zoom_range(RasterGrid(crs, transform, ds.width, ds.height))[1]
        x, y, _, _ = _tile_pixel_of(*run.marker_lonlat, z)
        from_file = render_tile(ds, z, x, y)
    from_array = render_tile(bands, z, x, y, transform=transform, crs=crs)
    assert from_file is not None and np.array_equal(from_file, from_array)


def test_grey_and_alpha_becomes_rgba(tmp_path):
    from srmosaic_ros.core.georef import GeoRaster
    from srmosaic_ros.io.geotiff import write_geotiff

    raster = GeoRaster(32614, 0.5, 587500.0, 3338200.0)
    grey = np.full((200, 300), 0.5, np.float32)
    covered = np.zeros((200, 300), bool)
    covered[50:150, 50:250] = True
    write_geotiff(tmp_path / 'g.tif', grey, raster, coverage=covered)
    centre = raster.lonlat_from_pixels(np.array([[150.0, 100.0]]))[0]
    with rasterio.open(tmp_path / 'g.tif') as ds:
        assert ds.count == 2
        z = zoom_range(RasterGrid(ds.crs, ds.transform, ds.width, ds.height))[1]
        x, y, col, row = _tile_pixel_of(centre[0], centre[1], z)
        rgba = render_tile(ds, z, x, y)
    assert tuple(rgba[int(row), int(col)]) == (128, 128, 128, 255)


@pytest.mark.parametrize('fmt', ['png', 'webp'])
def test_encodings_keep_alpha(fmt):
    rgba = np.zeros((256, 256, 4), np.uint8)
    rgba[64:192, 64:192] = (200, 100, 50, 255)
    data = encode_tile(rgba, fmt)
    assert data[:4] == b'\x89PNG' if fmt == 'png' else data[8:12] == b'WEBP'
    back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert back.shape == (256, 256, 4)
    assert back[0, 0, 3] == 0 and back[128, 128, 3] == 255
    assert np.abs(back[128, 128, :3].astype(int) - (50, 100, 200)).max() <= 4  # BGR, lossy WebP within a few levels
    with pytest.raises(ValueError, match='tile format'):
        encode_tile(rgba, 'jpeg')
