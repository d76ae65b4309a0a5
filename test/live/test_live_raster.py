"""The /srmosaic/raster text (live/raster.py): round trip, refusal of other text, and SR tile
geotransforms that agree with the GeoRaster and with the tile placement convention."""
from __future__ import annotations

import math

import numpy as np
import pytest

from srmosaic_ros.core.georef.drift import similarity_homography
from srmosaic_ros.core.georef.georeferencer import GeoRaster
from srmosaic_ros.errors import SrMosaicError
from srmosaic_ros.live.raster import ImagePlacement, LiveRaster
from srmosaic_ros.live.sr import SRTilePlacement


def test_text_round_trip_and_refusals():
    sim = similarity_homography(np.array([1.5, -2.0, 0.003, -0.01]), np.array([320.0, 240.0]))
    raster = LiveRaster.from_georaster(GeoRaster(32614, 0.18, 587501.4, 3338166.2, 0.0), sim)
    back = LiveRaster.parse(raster.text())
    assert (back.epsg, back.gsd_m_per_px, back.origin_easting_m) == (32614, 0.18, 587501.4)
    np.testing.assert_array_equal(back.canvas_H_raster, sim)
    assert LiveRaster.parse(LiveRaster.from_georaster(GeoRaster(32633, 0.1, 1.0, 2.0), None).text()).canvas_H_raster is None
    for bad in ('', 'srmosaic_mosaic', '{"epsg": 32614}', '{"epsg": 1, "gsd_m_per_px": -1, "origin_easting_m": 0, '
                '"origin_northing_m": 0}'):
        with pytest.raises(SrMosaicError, match='srmosaic/raster'):
            LiveRaster.parse(bad)


def test_tile_geotransform_follows_the_placement_and_the_canvas_similarity():
    geo = GeoRaster(32614, 0.2, 587500.0, 3338100.0, math.radians(1.0))
    sim = similarity_homography(np.array([3.0, -1.0, 0.002, 0.01]), np.array([100.0, 50.0]))
    raster = LiveRaster.from_georaster(geo, sim)
    place = SRTilePlacement(0, 256, -128, 128, 128, 2)
    for removed in (False, True):
        gt = raster.tile_geotransform(place, canvas_frame_removed=removed)
        for u, v in ((0, 0), (255, 17), (100, 200)):
            plane = np.array([place.x0 + (u + 0.5) / 2 - 0.5, place.y0 + (v + 0.5) / 2 - 0.5, 1.0])  # tiles.json's convention
            raster_px = np.linalg.solve(sim, plane) if removed else plane
            expect = geo.utm_from_pixels((raster_px[:2] / raster_px[2])[None])[0]
            got = (gt[0] + gt[1] * (u + 0.5) + gt[2] * (v + 0.5), gt[3] + gt[4] * (u + 0.5) + gt[5] * (v + 0.5))
            np.testing.assert_allclose(got, expect, atol=1e-6)


def test_image_placement_of_previews_and_tiles():
    tile = SRTilePlacement(3, 256, -128, 128, 64, 2)
    region = ImagePlacement.parse(tile.frame_id())          # an SR tile's text parses as a region too
    assert region == ImagePlacement(3, 256, -128, 128, 64)
    np.testing.assert_allclose(region.plane_H_image(256, 128), tile.plane_H_tile())
    preview = ImagePlacement(0, -64, 128, 1024, 512)
    assert ImagePlacement.parse(preview.frame_id()) == preview
    h = preview.plane_H_image(700, 350)                     # a preview resized to 700 x 350
    np.testing.assert_allclose(h @ [-0.5, -0.5, 1], [-64 - 0.5, 128 - 0.5, 1])   # the outer corners
    np.testing.assert_allclose(h @ [699.5, 349.5, 1], [-64 + 1024 - 0.5, 128 + 512 - 0.5, 1])
    raster = LiveRaster.from_georaster(GeoRaster(32614, 0.2, 587500.0, 3338100.0), None)
    gt = raster.image_geotransform(preview.frame_id(), 700, 350)
    assert gt[0] == pytest.approx(587500.0 + 0.2 * (-64 - 0.5)) and gt[1] == pytest.approx(0.2 * 1024 / 700)
    for bad in ('srmosaic_mosaic', 'srmosaic_segment_0;x0=1;y0=2'):
        with pytest.raises(SrMosaicError, match='placement'):
            ImagePlacement.parse(bad)


def test_moved_m_measures_how_far_the_plane_moves():
    geo = GeoRaster(32614, 0.2, 587500.0, 3338100.0)
    a = LiveRaster.from_georaster(geo, None)
    b = LiveRaster.from_georaster(geo, similarity_homography(np.array([0.5, 0.0, 0.0, 0.0]), np.zeros(2)))
    assert a.moved_m(None) == math.inf and a.moved_m(a) == 0.0
    assert b.moved_m(a) == pytest.approx(0.1)   # half a pixel of 0.2 m
    assert a.moved_m(LiveRaster.from_georaster(GeoRaster(32615, 0.2, 0.0, 0.0), None)) == math.inf
