"""LiveMapSource without a graph: plane tiles on a known raster come out as XYZ tiles where the map says."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from srmosaic_ros.errors import SrMosaicError
from srmosaic_ros.live.map_tiles import encode_tile as encode_plane_tile
from srmosaic_ros.live.raster import ImagePlacement, LiveRaster
from srmosaic_ros.web.live_source import LiveMapSource
from srmosaic_ros.web.source import MapSource
from srmosaic_ros.web.tiles import tile_bounds

# UTM 32614 (zone 14N), 0.5 m per plane pixel, north-up; plane pixel (0, 0) at this easting/northing
RASTER = LiveRaster(32614, 0.5, 587500.0, 3338000.0)


def lonlat_of_plane(px: float, py: float) -> tuple[float, float]:
    from rasterio.warp import transform

    e, n = RASTER.origin_easting_m + 0.5 * px, RASTER.origin_northing_m - 0.5 * py
    lon, lat = transform('EPSG:32614', 'EPSG:4326', [e], [n])
    return lon[0], lat[0]


def xyz_of(lon: float, lat: float, z: int) -> tuple[int, int, float, float]:
    """Tile (x, y) at zoom z holding (lon, lat), and the pixel (col, row) inside it (through morecantile)."""
    import morecantile

    tms = morecantile.tms.get('WebMercatorQuad')
    t = tms.tile(lon, lat, z)
    left, bottom, right, top = tile_bounds(z, t.x, t.y)
    mx, my = tms.xy(lon, lat)
    return t.x, t.y, (mx - left) / (right - left) * 256, (top - my) / (top - bottom) * 256


def plane_tile(colour: tuple[int, int, int], n: int = 64) -> np.ndarray:
    rgba = np.zeros((n, n, 4), np.uint8)
    rgba[..., :3] = colour
    rgba[..., 3] = 255
    return rgba


@pytest.fixture(scope='module')
def source() -> LiveMapSource:
    s = LiveMapSource()
    # two 128-px plane tiles side by side, sent at half resolution (64 px images): red west, blue east
    s.add_tile('mosaic', ImagePlacement(0, 0, 0, 128, 128).frame_id(), plane_tile((255, 0, 0)))
    s.add_png('mosaic', ImagePlacement(0, 128, 0, 128, 128).frame_id(),
              encode_plane_tile(np.tile(np.array([0.0, 0.0, 1.0], np.float32), (64, 64, 1)), np.ones((64, 64), bool)))
    return s


def test_no_raster_no_tiles_and_a_status_that_says_so(source: LiveMapSource) -> None:
    assert isinstance(source, MapSource)
    lon, lat = lonlat_of_plane(64, 64)
    x, y, _, _ = xyz_of(lon, lat, 18)
    assert source.tile_png('mosaic', 18, x, y) is None  # not placed yet
    status = source.status()
    assert status['georeferenced'] is False and status['bounds'] is None and status['live'] is True


def test_tiles_land_where_the_raster_puts_them(source: LiveMapSource) -> None:
    v0 = source.version()
    source.set_raster(RASTER)
    assert source.version() > v0
    for (px, py), colour in (((32, 64), (255, 0, 0)), ((224, 64), (0, 0, 255))):
        lon, lat = lonlat_of_plane(px, py)
        for z in (17, 19):
            x, y, col, row = xyz_of(lon, lat, z)
            png = source.tile_png('mosaic', z, x, y)
            assert png is not None and png[:8] == b'\x89PNG\r\n\x1a\n'
            rgba = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA)
            assert rgba.shape == (256, 256, 4)
            pixel = rgba[int(row), int(col)]
            assert pixel[3] == 255 and np.abs(pixel[:3].astype(int) - colour).max() <= 2, (z, pixel)
    # a tile far away: nothing
    lon, lat = lonlat_of_plane(5000, 5000)
    x, y, _, _ = xyz_of(lon, lat, 19)
    assert source.tile_png('mosaic', 19, x, y) is None
    assert source.tile_png('sr', 19, x, y) is None


def test_zoomed_out_tiles_and_a_changed_tile_is_a_new_picture(source: LiveMapSource) -> None:
    source.set_raster(RASTER)
    lon, lat = lonlat_of_plane(128, 64)
    x, y, col, row = xyz_of(lon, lat, 12)  # one XYZ pixel ~ 38 m: the whole map is a few pixels
    png = source.tile_png('mosaic', 12, x, y)
    assert png is not None
    rgba = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert rgba[..., 3].any()
    lon, lat = lonlat_of_plane(32, 64)
    x, y, col, row = xyz_of(lon, lat, 19)
    before = source.tile_png('mosaic', 19, x, y)
    assert source.tile_png('mosaic', 19, x, y) == before  # the cache
    source.add_tile('mosaic', ImagePlacement(0, 0, 0, 128, 128).frame_id(), plane_tile((0, 255, 0)))
    after = source.tile_png('mosaic', 19, x, y)
    rgba = cv2.cvtColor(cv2.imdecode(np.frombuffer(after, np.uint8), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA)
    assert tuple(rgba[int(row), int(col)][:3]) == (0, 255, 0)


def test_status_pose_footprint_track_and_zooms(source: LiveMapSource) -> None:
    source.set_raster(RASTER)
    lon, lat = lonlat_of_plane(128, 64)
    source.set_yaw(0.0)  # facing east
    source.set_pose(lat, lon, 100.0)
    source.set_pose(lat + 1e-5, lon + 1e-5, 101.0)
    source.set_frames(7)
    source.set_footprint(np.array([[99.5, 19.5], [139.5, 19.5], [139.5, 49.5], [99.5, 49.5]]))  # raster pixels
    source.set_diagnostics({'message': 'registering', 'frames_processed': '7'})
    status = source.status()
    assert status['frames'] == 7 and status['pose']['alt'] == 101.0
    assert status['pose']['yaw_deg'] == 0.0 and status['pose']['heading_deg'] == 90.0
    assert status['track']['type'] == 'LineString' and len(status['track']['coordinates']) == 2
    ring = status['footprint']['coordinates'][0]
    assert len(ring) == 5 and ring[0] == ring[-1]
    # its south-west corner (plane pixel corner (99.5, 49.5)), within a metre: UTM's grid north is not
    # quite true north, so the ring's westmost and southmost points are near, not at, that corner
    west, south = lonlat_of_plane(99.5, 49.5)
    assert min(p[0] for p in ring) == pytest.approx(west, abs=1e-5) and min(p[1] for p in ring) == pytest.approx(south, abs=1e-5)
    w, s, e, n = status['bounds']
    assert w < lon < e and s < lat < n
    # maxzoom: the first whose pixel is no larger than a plane image pixel (1 m on the ground here)
    assert 17 <= status['maxzoom'] <= 19 and status['minzoom'] <= status['maxzoom']
    assert status['diagnostics']['message'] == 'registering' and status['version'] == source.version()
    assert status['sr_maxzoom'] is None
    assert math.isclose(status['pose']['lat'], lat + 1e-5)


def test_sr_tiles_and_bad_input(source: LiveMapSource) -> None:
    source.set_raster(RASTER)
    sr = np.zeros((64, 64, 3), np.uint8)
    sr[...] = (255, 255, 0)
    source.add_tile('sr', 'srmosaic_segment_0;x0=0;y0=0;width=32;height=32;factor=2', sr)
    lon, lat = lonlat_of_plane(16, 16)
    x, y, col, row = xyz_of(lon, lat, 20)
    png = source.tile_png('sr', 20, x, y)
    rgba = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA)
    assert tuple(rgba[int(row), int(col)]) == (255, 255, 0, 255)
    assert source.status()['sr_maxzoom'] is not None
    with pytest.raises(SrMosaicError):
        source.add_tile('mosaic', 'not a placement', sr)
    with pytest.raises(SrMosaicError):
        source.add_tile('elsewhere', 'srmosaic_segment_0;x0=0;y0=0;width=32;height=32', sr)
    with pytest.raises(SrMosaicError):
        source.add_png('mosaic', 'srmosaic_segment_0;x0=0;y0=0;width=32;height=32', b'garbage')
    assert source.tile_png('mosaic', 30, 0, 0) is None and source.tile_png('mosaic', 2, 4, 0) is None
