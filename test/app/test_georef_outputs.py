"""Georeferenced outputs: GeoTIFF (opened with rasterio), KML GroundOverlay, poses.csv."""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import cv2
import numpy as np
import pytest

import rasterio  # a pinned dependency: a missing install must fail, not skip
from rio_cogeo.cogeo import cog_validate  # the field's validator of the COG layout
from pyproj import Transformer

from srmosaic_ros.core.georef import FramePose, GeoRaster, GeorefConfig, Georeferencer
from srmosaic_ros.core.georef.ground_homography import apply_H
from srmosaic_ros.io.geotiff import write_geotiff
from srmosaic_ros.io.kml import GX_NS, KML_NS, latlonbox_from_corners, write_kml, write_kml_for_raster
from srmosaic_ros.io.poses_csv import POSES_CSV_HEADER, read_poses_csv, write_poses_csv
from srmosaic_ros.sim import SimConfig

from sim_geometry import simulate_geometry


@pytest.fixture(scope='module')
def georeferenced():
    """A 60-frame flight through the Georeferencer: (flight, georef, poses, raster_H_frames)."""
    flight = simulate_geometry(SimConfig(width=320, height=240, world_gsd_m=0.3, frames=60, speed_m_s=8.0,
                                         heading_deg=30.0, seed=5))
    georef = Georeferencer(GeorefConfig(), flight.camera)
    events = sorted([(f.stamp_ns, 0, f) for f in flight.fixes] + [(i.stamp_ns, 1, i) for i in flight.imus]
                    + [(fr.stamp_ns, 2, k) for k, fr in enumerate(flight.frames)], key=lambda e: (e[0], e[1]))
    poses, placed = [], []
    for stamp, kind, item in events:
        if kind == 0:
            georef.feed_fix(item)
        elif kind == 1:
            georef.feed_imu(item)
        else:
            H = None if item == 0 else flight.truth.frames[item].prev_H_cur
            pose = georef.feed_frame(stamp, H, None, rms_px=0.3)
            poses.append(pose)
            if item == 0:
                georef.make_raster(pose)
                placed.append(georef.raster_H_frame(pose))
            else:
                placed.append(georef.correct(placed[-1] @ H, pose))
    return flight, georef, poses, placed


def truth_footprint_utm(flight, epsg: int) -> np.ndarray:
    """(4 N, 2) UTM easting, northing of every frame's corners, from the simulator's truth."""
    cam, world = flight.camera, flight.world
    c = np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5], [cam.width - 0.5, cam.height - 0.5], [-0.5, cam.height - 0.5]])
    enu = np.concatenate([apply_H(world.enu_H_world_px @ t.world_px_H_frame, c) for t in flight.truth.frames])
    lat, lon, _ = world.origin.geodetic_from_enu(np.c_[enu, np.zeros(len(enu))])
    e, n = Transformer.from_crs(4326, epsg, always_xy=True).transform(lon, lat)
    return np.c_[e, n]


def paint_coverage(flight, placed: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(coverage (H, W) bool, mosaic_H_raster translation) of all frames on the raster grid."""
    cam = flight.camera
    c = np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5], [cam.width - 0.5, cam.height - 0.5], [-0.5, cam.height - 0.5]])
    pts = np.concatenate([apply_H(H, c) for H in placed])
    x0, y0 = np.floor(pts.min(axis=0)).astype(int)
    x1, y1 = np.ceil(pts.max(axis=0)).astype(int)
    shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    cov = np.zeros((y1 - y0 + 1, x1 - x0 + 1), np.uint8)
    ones = np.ones((cam.height, cam.width), np.uint8)
    for H in placed:
        cov |= cv2.warpPerspective(ones, shift @ H, (cov.shape[1], cov.shape[0]), flags=cv2.INTER_NEAREST)
    return cov.astype(bool), shift


# --- GeoTIFF -----------------------------------------------------------------------------------


def test_geotiff_opens_in_the_right_utm_zone_where_the_ground_truth_is(georeferenced, tmp_path) -> None:
    flight, georef, _, placed = georeferenced
    raster = georef.raster
    assert raster.epsg == 32614  # caliterra, Texas: UTM 14 N
    coverage, shift = paint_coverage(flight, placed)
    mosaic_raster = raster.shifted(-shift[0, 2], -shift[1, 2])  # mosaic pixel (0, 0) = raster pixel (x0, y0)
    image = np.dstack([coverage * 0.5] * 3).astype(np.float32)
    path = tmp_path / 'mosaic.tif'
    write_geotiff(path, image, mosaic_raster, coverage=coverage)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['mosaic.tif']  # atomic: no temporary left
    with rasterio.open(path) as ds:
        assert ds.crs.to_epsg() == 32614
        assert ds.count == 4 and ds.colorinterp[-1] == rasterio.enums.ColorInterp.alpha
        assert ds.res == pytest.approx((raster.gsd_m_per_px, raster.gsd_m_per_px))
        mask = ds.dataset_mask() > 0
        np.testing.assert_array_equal(mask, coverage)
        rows, cols = np.nonzero(mask)
        # pixel edges of the covered area, in map coordinates
        left, top = ds.transform @ (cols.min(), rows.min())
        right, bottom = ds.transform @ (cols.max() + 1, rows.max() + 1)
        # every pixel centre maps where GeoRaster says
        x, y = ds.xy(7, 11)
        np.testing.assert_allclose((x, y), mosaic_raster.utm_from_pixels(np.array([11.0, 7.0])), atol=1e-6)
    truth = truth_footprint_utm(flight, 32614)
    got = np.array([left, bottom, right, top])
    want = np.array([truth[:, 0].min(), truth[:, 1].min(), truth[:, 0].max(), truth[:, 1].max()])
    # metres; the west edge is the first frame, placed by the first fix alone (2.5 m sigma per axis)
    assert np.abs(got - want).max() < 5.0, got - want


def test_geotiff_grey_float_nan_and_large_outputs(tmp_path) -> None:
    raster = GeoRaster(32633, 0.25, 500_000.0, 5_000_000.0)
    grey = np.linspace(0.0, 1.0, 40 * 30).reshape(30, 40)
    grey[:5, :5] = np.nan  # uncovered
    write_geotiff(tmp_path / 'g.tif', grey, raster)
    with rasterio.open(tmp_path / 'g.tif') as ds:
        assert ds.count == 2 and ds.crs.to_epsg() == 32633
        assert ds.bounds.left == pytest.approx(500_000.0 - 0.125) and ds.bounds.top == pytest.approx(5_000_000.125)
        alpha = ds.read(2)
        assert alpha[:5, :5].max() == 0 and alpha[5:, 5:].min() == 255
    rgba = np.zeros((1300, 1100, 4), np.uint8)
    rgba[..., 3] = 255
    write_geotiff(tmp_path / 'big.tif', rgba, raster)
    with rasterio.open(tmp_path / 'big.tif') as ds:
        assert ds.profile['tiled'] and ds.block_shapes[0] == (256, 256)
        assert ds.overviews(1) == [2, 4, 8]
    for tif in ('g.tif', 'big.tif'):  # small or large, each a Cloud Optimized GeoTIFF
        assert cog_validate(tmp_path / tif, quiet=True) == (True, [], []), tif
    with pytest.raises(ValueError, match='images'):
        write_geotiff(tmp_path / 'bad.tif', np.zeros((4, 4, 5), np.uint8), raster)
    with pytest.raises(ValueError, match='coverage'):
        write_geotiff(tmp_path / 'bad.tif', np.zeros((4, 4), np.uint8), raster, coverage=np.ones((3, 3), bool))
    assert not (tmp_path / 'bad.tif').exists()


# --- KML ---------------------------------------------------------------------------------------


def test_kml_ground_overlay_has_the_mosaic_corners(georeferenced, tmp_path) -> None:
    _, georef, _, _ = georeferenced
    raster = georef.raster.shifted(-100.0, -50.0)
    width, height = 600, 300
    write_kml_for_raster(tmp_path / 'mosaic.kml', 'mosaic.png', raster, width, height)
    root = ET.parse(tmp_path / 'mosaic.kml').getroot()
    ns = {'k': KML_NS, 'gx': GX_NS}
    overlay = root.find('k:Document/k:GroundOverlay', ns)
    assert overlay is not None and overlay.find('k:Icon/k:href', ns).text == 'mosaic.png'
    coords = overlay.find('gx:LatLonQuad/k:coordinates', ns).text.split()
    quad = np.array([[float(v) for v in c.split(',')[:2]] for c in coords])
    # lower-left, lower-right, upper-right, upper-left (counter-clockwise from the lower left)
    ul, ur, lr, ll = raster.corners_lonlat(width, height)
    np.testing.assert_allclose(quad, [ll, lr, ur, ul], atol=1e-9)
    assert quad[0, 1] < quad[3, 1] and quad[0, 0] < quad[1, 0]  # south below north, west left of east
    # the corners are the raster's outer pixel edges
    to_utm = Transformer.from_crs(4326, raster.epsg, always_xy=True)
    e, n = to_utm.transform(*ul)
    assert (e, n) == pytest.approx((raster.origin_easting_m - raster.gsd_m_per_px / 2,
                                    raster.origin_northing_m + raster.gsd_m_per_px / 2), abs=1e-3)


def test_kml_latlonbox_mode(tmp_path) -> None:
    raster = GeoRaster(32614, 0.5, 600_000.0, 3_340_000.0)
    corners = raster.corners_lonlat(800, 400)
    write_kml(tmp_path / 'b.kml', 'm.png', corners, mode='box', name='a <b> & c')
    root = ET.parse(tmp_path / 'b.kml').getroot()
    ns = {'k': KML_NS}
    box = root.find('k:Document/k:GroundOverlay/k:LatLonBox', ns)
    vals = {k: float(box.find(f'k:{k}', ns).text) for k in ('north', 'south', 'east', 'west', 'rotation')}
    assert root.find('k:Document/k:name', ns).text == 'a <b> & c'
    ref = latlonbox_from_corners(corners)
    assert vals == pytest.approx(ref, abs=1e-6)
    assert vals['north'] > vals['south'] and vals['east'] > vals['west']
    # UTM north is east of true north west of the central meridian (-99 deg): a small rotation
    assert 0.0 < abs(vals['rotation']) < 1.0
    with pytest.raises(ValueError, match='mode'):
        write_kml(tmp_path / 'x.kml', 'm.png', corners, mode='circle')
    with pytest.raises(ValueError, match='corners'):
        write_kml(tmp_path / 'x.kml', 'm.png', corners[:3])


# --- poses.csv ---------------------------------------------------------------------------------


def test_poses_csv_header_units_and_missing_poses(georeferenced, tmp_path) -> None:
    flight, _, poses, _ = georeferenced
    rows_in = [FramePose.invalid(flight.frames[0].stamp_ns - 1, 'no fix yet')] + poses
    write_poses_csv(tmp_path / 'poses.csv', rows_in)
    with open(tmp_path / 'poses.csv') as f:
        assert f.readline().strip() == ','.join(POSES_CSV_HEADER)
    assert POSES_CSV_HEADER == ['stamp_ns', 'latitude', 'longitude', 'altitude', 'roll', 'pitch', 'yaw',
                                'std_east_m', 'std_north_m', 'std_up_m']
    rows = read_poses_csv(tmp_path / 'poses.csv')
    assert len(rows) == len(rows_in)
    assert rows[0]['stamp_ns'] == rows_in[0].stamp_ns and math.isnan(rows[0]['latitude'])
    last, pose = rows[-1], poses[-1]
    assert last['latitude'] == pytest.approx(pose.latitude_deg, abs=1e-9)
    assert last['yaw'] == pytest.approx(math.degrees(pose.rpy_rad[2]), abs=1e-5)  # degrees
    assert last['std_east_m'] == pytest.approx(pose.std_enu_m[0], abs=1e-4)
    truth = flight.truth.frames[-1]
    assert last['yaw'] == pytest.approx(truth.yaw_deg, abs=1.0)  # body yaw in ENU: ~30 deg (the heading)
    assert abs(last['latitude'] - truth.latitude_deg) * 111_000 < 3.0


def test_a_flight_whose_first_fixes_are_unusable_starts_on_the_map(tmp_path):
    """The demo with its first 20 fixes NaN (the receiver without a fix for 4 s): the first frames
    used to be processed before any fix, so the mosaic began off the map and the whole flight fell
    back to the geotag fit (7.8 m RMS, no poses.csv). Frames now wait for the first fix
    (pipeline.FIRST_FIX_HOLD_FRAMES) and the filter starts from it: measured 0.81 m RMS (the
    unchanged demo: 1.14 m)."""
    import json

    from demo_bags import DEMO, rewrite_demo
    from srmosaic_ros.config import PipelineConfig
    from srmosaic_ros.app.evaluate import evaluate_dir
    from srmosaic_ros.app.process import process_input

    def no_fix(kind: str, index: int, msg) -> None:
        if kind == 'fix' and index < 20:
            msg.latitude = float('nan')

    bag = rewrite_demo(tmp_path / 'late_fix', no_fix)
    report = process_input(bag, tmp_path / 'out', PipelineConfig(), progress=False)
    assert sum(n for k, n in report['skipped_messages'].items() if 'NaN' in k) == 20
    assert report['georeferenced']['method'] == 'filter' and report['georeferenced']['poses'] == 60
    figures = evaluate_dir(tmp_path / 'out', DEMO / 'ground_truth.json')
    assert figures['georef_error_rms_m'] < 2.0, figures['georef_error_rms_m']
    assert figures['corner_error_mean_px'] < 0.2, figures['corner_error_mean_px']
    assert json.loads((tmp_path / 'out' / 'report.json').read_text())['georeferenced']['method'] == 'filter'
