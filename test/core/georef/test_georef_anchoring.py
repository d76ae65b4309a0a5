"""Offline re-anchoring: the similarity fit, rotated GeoRaster grids, and a rotated GeoTIFF that
rasterio reads back in place."""
from __future__ import annotations

import math

import numpy as np
import pytest
import rasterio

from srmosaic_ros.core.georef.anchoring import fit_similarity
from srmosaic_ros.core.georef.georeferencer import GeoRaster
from srmosaic_ros.io.geotiff import write_geotiff


def _similarity(scale: float, angle: float, tx: float, ty: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[scale * c, -scale * s, tx], [scale * s, scale * c, ty], [0.0, 0.0, 1.0]])


def test_fit_recovers_similarity_and_averages_noise():
    rng = np.random.default_rng(1)
    src = rng.uniform(0, 2000, (400, 2))
    truth = _similarity(1.012, math.radians(-0.6), 17.0, -9.0)
    dst = (np.c_[src, np.ones(len(src))] @ truth.T)[:, :2]
    assert np.abs(fit_similarity(src, dst) - truth).max() < 1e-9
    noisy = fit_similarity(src, dst + rng.normal(0, 5.0, dst.shape))   # 5 px per point
    assert abs(math.degrees(math.atan2(noisy[1, 0], noisy[0, 0])) + 0.6) < 0.05
    assert abs(math.hypot(noisy[0, 0], noisy[1, 0]) - 1.012) < 1e-3


def test_fit_degenerate_sets_fall_back_to_translation():
    pts = np.array([[10.0, 10.0]] * 5)
    fix = fit_similarity(pts, pts + [3.0, -2.0])
    assert np.allclose(fix, [[1, 0, 3], [0, 1, -2], [0, 0, 1]])
    line = np.c_[np.arange(10.0), np.zeros(10)]
    assert np.allclose(fit_similarity(line, line + 1.0)[:2, :2], np.eye(2))
    assert np.allclose(fit_similarity(line, line, rotation_and_scale=False), np.eye(3))
    with pytest.raises(ValueError, match='same size'):
        fit_similarity(line, line[:3])


def test_reflection_is_never_fitted():
    rng = np.random.default_rng(2)
    src = rng.uniform(0, 100, (30, 2))
    mirrored = src * [1.0, -1.0]
    fix = fit_similarity(src, mirrored)
    assert np.linalg.det(fix[:2, :2]) > 0


def test_transformed_raster_maps_pixels_like_the_product():
    base = GeoRaster(32614, 0.18, 587500.0, 3338100.0)
    fix = _similarity(1.004, math.radians(0.5), 12.5, -3.25)
    new = base.transformed(fix).shifted(-40.0, 25.0)
    px = np.array([[0.0, 0.0], [100.0, 50.0], [1399.0, 764.0]])
    expected = (np.c_[px + [-40.0, 25.0], np.ones(3)] @ (base.utm_H_raster @ fix).T)[:, :2]
    assert np.allclose(new.utm_from_pixels(px), expected, atol=1e-6)
    assert math.isclose(new.gsd_m_per_px, 0.18 * 1.004) and math.isclose(math.degrees(new.rotation_rad), -0.5)
    assert np.allclose(new.pixels_from_lonlat(new.lonlat_from_pixels(px)), px, atol=1e-6)
    with pytest.raises(ValueError, match='reflection'):
        base.transformed(np.diag([1.0, -1.0, 1.0]))


def test_rotated_geotiff_reads_back_in_place(tmp_path):
    raster = GeoRaster(32614, 0.2, 587500.0, 3338100.0, math.radians(1.5))
    image = np.full((40, 60, 3), 128, np.uint8)
    write_geotiff(tmp_path / 'r.tif', image, raster)
    with rasterio.open(tmp_path / 'r.tif') as ds:
        assert ds.crs.to_epsg() == 32614
        for x, y in [(0, 0), (59, 0), (59, 39), (10, 30)]:
            e, n = ds.transform @ (x + 0.5, y + 0.5)            # centre of pixel (x, y)
            assert np.allclose([e, n], raster.utm_from_pixels(np.array([x, y], float)), atol=1e-6)
    north_up = GeoRaster(32614, 0.2, 587500.0, 3338100.0)
    assert north_up.geotransform == (587499.9, 0.2, 0.0, 3338100.1, 0.0, -0.2)


def test_read_raster_gives_back_the_grid_written(tmp_path):
    from srmosaic_ros.io.geotiff import read_raster, write_geotiff_blocks

    raster = GeoRaster(32614, 0.2, 587500.0, 3338100.0, math.radians(-2.0))
    write_geotiff(tmp_path / 'r.tif', np.full((30, 20), 9, np.uint8), raster)
    back = read_raster(tmp_path / 'r.tif')
    assert back.epsg == 32614
    np.testing.assert_allclose(back.utm_H_raster, raster.utm_H_raster, atol=1e-7)
    write_geotiff_blocks(tmp_path / 'plain.tif', [(0, np.zeros((8, 8), np.uint8), None)], None, 8, 8, tiled=False)
    with pytest.raises(ValueError, match='no CRS'):
        read_raster(tmp_path / 'plain.tif')
