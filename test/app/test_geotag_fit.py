"""Georeferencing by geotags (core/georef/geotag_fit.py): a mosaic without camera intrinsics placed
on the map by the GNSS positions of its frames, checked against known similarities, a simulated
flight's ground truth, and the real survey stills."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from pyproj import Transformer

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.georef.geodetic import LocalTangentPlane
from srmosaic_ros.core.georef.geotag_fit import (
    MAX_MEDIAN_DEPTH_RATIO,
    check_views_nadir,
    fit_mosaic_to_geotags,
    geotags_at,
    view_depth_ratios,
)
from srmosaic_ros.core.georef.ground_homography import apply_H, ground_H_image
from srmosaic_ros.app.process import process_input
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.record import write_stills_folder
from flights import processed, simulated
from repo_paths import REPO

SEQUENCES = REPO / 'data' / 'sequences'
EPSG = 32633  # UTM 33N


def _lonlat(utm: np.ndarray) -> np.ndarray:
    lon, lat = Transformer.from_crs(EPSG, 4326, always_xy=True).transform(utm[:, 0], utm[:, 1])
    return np.stack([lon, lat], axis=1)


def _similarity(scale: float, angle_deg: float, e0: float, n0: float) -> np.ndarray:
    """mosaic pixel (x, y down) -> UTM: UTM = scale R(angle) (x, -y) + (e0, n0)."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return np.array([[scale * c, scale * s, e0], [scale * s, -scale * c, n0], [0, 0, 1]])


def test_fit_recovers_a_known_similarity_and_leaves_out_a_wrong_geotag() -> None:
    rng = np.random.default_rng(4)
    centres = rng.uniform(0, 2000, size=(25, 2))
    truth = _similarity(0.12, 35.0, 500_000.0, 5_000_000.0)
    utm = apply_H(truth, centres)
    noisy = utm + rng.normal(0, 2.0, utm.shape)
    noisy[7] += [40.0, -25.0]                       # one geotag 47 m off
    fit = fit_mosaic_to_geotags(centres, _lonlat(noisy))
    assert fit.raster.epsg == EPSG
    assert not fit.used[7] and fit.used.sum() == 24
    assert fit.raster.gsd_m_per_px == pytest.approx(0.12, rel=0.02)
    assert math.degrees(fit.raster.rotation_rad) == pytest.approx(35.0, abs=1.0)
    err = np.linalg.norm(fit.raster.utm_from_pixels(centres) - utm, axis=1)
    assert err.max() < 2.0                          # the fit averages the 2 m noise of 24 tags
    assert 2.0 < fit.rms_m < 3.6                    # 2-D distance: sigma sqrt(2) = 2.8 m
    f = fit.figures()
    assert f['method'] == 'geotags' and f['frames_rejected'] == 1 and f['scale_rel_sigma'] < 0.02


def test_fit_refuses_what_cannot_place_a_mosaic() -> None:
    centres = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0]])
    with pytest.raises(ValueError, match='at least 3'):
        fit_mosaic_to_geotags(centres[:2], _lonlat(np.array([[5e5, 5e6], [5e5 + 10, 5e6]])))
    hover = _lonlat(np.array([[5e5, 5e6]] * 3) + np.random.default_rng(0).normal(0, 0.3, (3, 2)))
    with pytest.raises(ValueError, match='too close'):
        fit_mosaic_to_geotags(centres, hover)


def test_a_perfectly_straight_flight_is_placed_too() -> None:
    """Frame centres exactly on one line: without reflection the line's direction fixes the rotation
    and its length the scale (the fit fell back to a translation, scale 1 m a pixel, and the
    residual check then refused it as oblique)."""
    centres = np.c_[np.linspace(100.0, 900.0, 30), np.full(30, 400.0)]
    truth = _similarity(0.2, -60.0, 500_000.0, 5_000_000.0)
    utm = apply_H(truth, centres)
    fit = fit_mosaic_to_geotags(centres, _lonlat(utm))
    assert fit.raster.gsd_m_per_px == pytest.approx(0.2, rel=1e-3)
    assert math.degrees(fit.raster.rotation_rad) == pytest.approx(-60.0, abs=0.05)
    assert np.linalg.norm(fit.raster.utm_from_pixels(centres) - utm, axis=1).max() < 0.05
    off_line = np.array([[500.0, 100.0]])  # a pixel beside the line lands on its side of the track
    assert np.linalg.norm(fit.raster.utm_from_pixels(off_line) - apply_H(truth, off_line)) < 0.05


def test_fit_refuses_frame_centres_that_do_not_follow_the_track() -> None:
    """An oblique camera's frame centres do not lie under the aircraft: circling at 50 m and looking
    at the orbit's centre, they stay near that centre while the geotags go round. The best similarity
    leaves residuals as large as the track: refused with the reason and a way out, not placed 50 m
    off. A nadir camera with consumer GNSS noise over the least extent accepted still fits."""
    rng = np.random.default_rng(5)
    angle = np.linspace(0.0, 2.0 * math.pi, 40, endpoint=False)
    track = np.c_[5e5 + 50.0 * np.cos(angle), 5e6 + 50.0 * np.sin(angle)]
    looked_at = np.array([1000.0, 800.0]) + rng.normal(0, 30.0, (40, 2))   # mosaic px around the centre
    with pytest.raises(ValueError, match='do not follow their geotags') as err:
        fit_mosaic_to_geotags(looked_at, _lonlat(track))
    assert 'gimbal_elevation_deg' in str(err.value)
    # nadir: centres under the track (0.1 m a pixel), 5 m GNSS noise a coordinate, a 12 m RMS line
    line = np.c_[5e5 + np.linspace(-20.0, 20.0, 40), np.full(40, 5e6)]
    centres = np.c_[np.linspace(-200.0, 200.0, 40), rng.normal(0, 3.0, 40)] + 1000.0   # the chain's own wobble
    fit = fit_mosaic_to_geotags(centres, _lonlat(line + rng.normal(0, 5.0, line.shape)))
    assert 0.4 < fit.rms_m / fit.extent_m < 0.7   # noise-dominated (measured 0.50), yet not refused


def _tilted(deg: float, f: float = 400.0, w: int = 640, h: int = 480) -> np.ndarray:
    """plane_H_frame of a camera pitched ``deg`` from the plane's camera (same centre): K R K^-1."""
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return k @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.linalg.inv(k)


def test_depth_ratios_measure_how_obliquely_a_frame_sees_the_mosaic_plane() -> None:
    size = (640, 480)
    similarity = np.array([[0.5, -0.1, 30.0], [0.1, 0.5, -7.0], [0.0, 0.0, 1.0]])
    r = view_depth_ratios([np.eye(3), similarity, -similarity, _tilted(5.0), _tilted(30.0), _tilted(70.0)], [size] * 6)
    assert r[0] == r[1] == r[2] == 1.0                  # parallel to the plane, whatever the sign of H
    assert 1.05 < r[3] < 1.2 and 1.5 < r[4] < 3.0       # 5 deg: 1.10; 30 deg: 1.95
    assert math.isinf(r[5])                             # 70 deg with a 77 deg lens: past the horizon
    check_views_nadir([np.eye(3)] + [_tilted(5.0)] * 4, [size] * 5)   # a nadir chain with gusts passes
    with pytest.raises(ValueError, match='do not look straight down') as err:
        check_views_nadir([np.eye(3)] + [_tilted(40.0)] * 4, [size] * 5)
    assert 'gimbal_elevation_deg' in str(err.value) and MAX_MEDIAN_DEPTH_RATIO == 1.5


def test_geotags_at_frame_stamps() -> None:
    ts = np.array([0, 1_000_000_000, 2_000_000_000, 10_000_000_000])
    ll = np.array([[10.0, 50.0], [10.001, 50.0], [10.002, 50.001], [10.01, 50.01]])
    got = geotags_at(ts, ll, np.array([1_000_000_000, 1_500_000_000, 5_000_000_000, -1]))
    np.testing.assert_allclose(got[0], ll[1])
    np.testing.assert_allclose(got[1], [10.0015, 50.0005])
    assert np.all(np.isnan(got[2])) and np.all(np.isnan(got[3]))   # 8 s gap; before the first fix


@pytest.mark.parametrize(('mode', 'max_rms', 'max_error'), [('chain', 1.7, 3.5), ('global', 1.7, 3.5)])
def test_stills_without_intrinsics_are_georeferenced_by_their_geotags(tmp_path: Path, tmp_path_factory: pytest.TempPathFactory,
                                                                     mode: str, max_rms: float, max_error: float) -> None:
    """A simulated survey (stills 2 s apart over a lawnmower from a gimbal, 0.3 deg RMS off nadir,
    GNSS sigma 2.5 m, no camera model): mosaic.tif opens with a UTM CRS and puts the frames' centres
    and corners within the GNSS noise averaged over the flight of the truth; chained and fitted to
    the geotags (survey.mode: chain), or aligned globally with the GPS positions as priors."""
    flight = simulated(tmp_path_factory, SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='lawnmower', legs=2,
                                                   leg_length_m=160.0, leg_spacing_m=50.0, speed_m_s=10.0, rate_hz=0.5,
                                                   fix_rate_hz=0.5, gust_deg=0.3, seed=3))  # one flight for both modes
    write_stills_folder(flight, tmp_path / 'survey')
    report = process_input(tmp_path / 'survey', tmp_path / 'out', pipeline_config({'survey.mode': mode}),
                           progress=False)
    geo = report['georeferenced']
    assert geo is not None and geo['method'] == ('geotags' if mode == 'chain' else 'global alignment')
    assert report['frames_registered'] == len(flight.frames)
    with rasterio.open(tmp_path / 'out' / 'mosaic.tif') as ds:
        assert ds.crs.to_epsg() == geo['epsg']
        transform = ds.transform
    rows = list(csv.DictReader(open(tmp_path / 'out' / 'frames.csv')))
    ltp = LocalTangentPlane(*flight.truth.origin)
    to_utm = Transformer.from_crs(4326, geo['epsg'], always_xy=True)
    cam = flight.camera
    errors = []
    for row, t in zip(rows, flight.truth.frames):
        H = np.array([float(row[f'h{i}{j}']) for i in range(3) for j in range(3)]).reshape(3, 3)
        for px in ([cam.cx, cam.cy], [0.0, 0.0], [cam.width - 1.0, cam.height - 1.0]):
            m = apply_H(H, np.array([px]))[0]
            e, n = transform @ (m[0] + 0.5, m[1] + 0.5)      # GDAL: pixel corner convention
            g = apply_H(ground_H_image(cam.K, t.R_enu_from_cam, t.camera_enu_m), np.array([px]))[0]
            lat, lon, _ = ltp.geodetic_from_enu(np.array([g[0], g[1], 0.0]))
            errors.append(math.dist((e, n), to_utm.transform(float(lon), float(lat))))
    errors = np.array(errors)
    # measured: chain 1.30 m RMS, 2.5 m max; global 1.26 m, 2.2 m (one geotag alone: 3.5 m RMS)
    assert np.sqrt(np.mean(errors**2)) < max_rms and errors.max() < max_error, (errors.mean(), errors.max())
    residual = geo['geotag_residual_rms_m'] if mode == 'chain' else report['survey']['position_residual_rms_m']
    assert 1.0 < residual < 4.5
    assert geo['gsd_m_per_px'] == pytest.approx(100.0 / cam.fx, rel=0.05)


@pytest.mark.parametrize(('name', 'epsg', 'max_rms'), [('brighton_beach', 32615, 4.0), ('caliterra', 32614, 6.0)])
def test_real_stills_are_georeferenced_by_their_geotags(tmp_path: Path, name: str, epsg: int, max_rms: float) -> None:
    """The real surveys: GeoTIFF in the right UTM zone, every frame centre within consumer-GNSS
    distance of its EXIF position. Brighton's DJI also records its height above take-off and its
    lens, which the fit does not use: the fitted scale must agree with them (an independent check)."""
    report = process_input(SEQUENCES / name, tmp_path / 'out', pipeline_config({'survey.mode': 'chain'}),
                           progress=False)
    geo = report['georeferenced']
    assert geo['method'] == 'geotags' and geo['epsg'] == epsg
    assert geo['frames_used'] == report['frames_in'] and geo['geotag_residual_rms_m'] < max_rms
    with rasterio.open(tmp_path / 'out' / 'mosaic.tif') as ds:
        assert ds.crs.to_epsg() == epsg
    kml = (tmp_path / 'out' / 'mosaic.kml').read_text()
    assert '<GroundOverlay>' in kml or 'LatLonQuad' in kml or 'LatLonBox' in kml
    if name == 'brighton_beach':
        rows = list(csv.DictReader(open(SEQUENCES / name / 'telemetry_from_exif.csv')))
        width = cv2.imread(str(next((SEQUENCES / name / 'images').iterdir()))).shape[1]
        fx = float(rows[0]['focal_mm']) / 6.17 * width          # FC300S: 1/2.3" sensor, 6.17 mm wide
        gsd_exif = np.mean([float(r['RelativeAltitude']) for r in rows]) / fx
        assert geo['gsd_m_per_px'] == pytest.approx(gsd_exif, rel=0.08)
    json.dumps(report)  # the report stays JSON


@pytest.mark.parametrize(('name', 'epsg', 'max_rms'), [('brighton_beach', 32615, 4.0), ('caliterra', 32614, 12.0)])
def test_real_stills_are_aligned_globally_on_the_map(tmp_path_factory: pytest.TempPathFactory, name: str, epsg: int,
                                                     max_rms: float) -> None:
    """The same real surveys aligned globally (the default): every still placed, in the right UTM
    zone, its centre within consumer-GNSS distance of its own position; Brighton's scale from the GPS
    baselines agrees with its DJI's height above take-off and lens (an independent check). One run
    per survey for the session (test/flights.py): test_survey_process.py reads caliterra's too."""
    out, report = processed(tmp_path_factory, SEQUENCES / name)
    geo, survey = report['georeferenced'], report['survey']
    assert geo['method'] == 'global alignment' and geo['epsg'] == epsg
    assert report['frames_registered'] == report['frames_in']
    # measured: brighton 1.7 m, caliterra 5.5 m (its camera's own GPS wanders: see bench/survey.py)
    assert survey['position_residual_rms_m'] < max_rms, survey
    with rasterio.open(out / 'mosaic.tif') as ds:
        assert ds.crs.to_epsg() == epsg
    if name == 'brighton_beach':
        rows = list(csv.DictReader(open(SEQUENCES / name / 'telemetry_from_exif.csv')))
        width = cv2.imread(str(next((SEQUENCES / name / 'images').iterdir()))).shape[1]
        fx = float(rows[0]['focal_mm']) / 6.17 * width
        gsd_exif = np.mean([float(r['RelativeAltitude']) for r in rows]) / fx
        assert geo['gsd_m_per_px'] == pytest.approx(gsd_exif, rel=0.08)
    json.dumps(report, allow_nan=False)


def test_image_folder_refuses_video_options() -> None:
    from srmosaic_ros.errors import InputError
    from srmosaic_ros.app.process import open_source

    with pytest.raises(InputError, match='--telemetry and --deinterlace apply to video input'):
        open_source(SEQUENCES / 'caliterra', hfov_deg=60.0)


def test_fit_with_attitudes_takes_the_tilt_out_and_finds_the_height() -> None:
    """Frames tilted by slow gusts (2 degrees RMS, correlated over the flight): the centre of each
    frame is h tan(tilt) from its geotag. With each frame's axis offset (from its attitude) the fit
    finds h and the similarity; without, a bias in scale and rotation remains."""
    rng = np.random.default_rng(8)
    centres = np.c_[np.linspace(0, 1500, 40), 200 + 30 * np.sin(np.linspace(0, 3, 40))]
    truth = _similarity(0.1, -80.0, 600_000.0, 4_000_000.0)
    ground = apply_H(truth, centres)
    tilt = np.radians(2.0) * np.c_[np.sin(np.linspace(0, 4, 40)), np.cos(np.linspace(0, 2.5, 40))]
    offsets = np.tan(tilt)                                          # axis meets the ground h * offset away
    tags = ground - 100.0 * offsets + rng.normal(0, 1.0, ground.shape)
    fit = fit_mosaic_to_geotags(centres, _lonlat(tags), offsets)
    plain = fit_mosaic_to_geotags(centres, _lonlat(tags))
    err = np.linalg.norm(fit.raster.utm_from_pixels(centres) - ground, axis=1)
    err_plain = np.linalg.norm(plain.raster.utm_from_pixels(centres) - ground, axis=1)
    assert fit.height_m == pytest.approx(100.0, rel=0.1) and plain.height_m is None
    assert fit.figures()['tilt_corrected'] and fit.figures()['height_above_ground_m'] == pytest.approx(100, rel=0.1)
    assert np.sqrt(np.mean(err**2)) < 0.6 < 2.0 < np.sqrt(np.mean(err_plain**2)), (err.mean(), err_plain.mean())
    # an attitude missing for a few frames: they are left out; for most: the plain similarity for all
    offsets[3] = np.nan
    few = fit_mosaic_to_geotags(centres, _lonlat(tags), offsets)
    assert few.height_m == pytest.approx(100.0, rel=0.1) and not few.used[3] and few.used.sum() == 39
    offsets[10:] = np.nan
    assert fit_mosaic_to_geotags(centres, _lonlat(tags), offsets).height_m is None


@pytest.fixture(scope='module')
def stills_bag(tmp_path_factory) -> Path:
    """A survey of stills 2 s apart as a bag with CameraInfo, fixes (5 Hz) and IMU (50 Hz)."""
    from srmosaic_ros.sim.record import write_flight

    flight = simulate(SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='lawnmower', legs=2,
                                leg_length_m=160.0, leg_spacing_m=50.0, speed_m_s=10.0, rate_hz=0.5, gust_deg=0.3,
                                seed=3))
    return write_flight(flight, tmp_path_factory.mktemp('stills') / 'bag', transport='raw')


def test_stills_with_intrinsics_are_anchored_on_frame_centres(stills_bag: Path, tmp_path: Path) -> None:
    """With georef.max_step_s 1 s the frames 2 s apart are bridged and their registrations not
    fused, so the ground height stays at its +-30 m prior; the offline re-anchoring then fits frame
    centres, not corners (whose spread would carry the height error into the scale: 2.7 m RMS)."""
    from srmosaic_ros.app.evaluate import evaluate_dir

    report = process_input(stills_bag, tmp_path / 'out', pipeline_config({'georef.max_step_s': 1.0}), progress=False)
    geo = report['georeferenced']
    assert geo['method'] == 'filter' and geo['anchor_points'] == 'centres'
    assert geo['skipped_telemetry'].get('homography_after_gap', 0) >= 15
    figures = evaluate_dir(tmp_path / 'out', stills_bag / 'ground_truth.json')
    assert figures['georef_error_rms_m'] < 1.3, figures['georef_error_rms_m']   # measured 0.85 m


def test_stills_registrations_are_fused_with_a_step_as_long_as_their_spacing(stills_bag: Path, tmp_path: Path) -> None:
    """Default georef.max_step_s (10 s): one filter step per still, every registration fused (the
    filter learns the ground; poses 0.74 m RMS instead of 1.2 m bridged). It needs the bound on the
    attitude noise per step: without it (90 deg) the 2 s steps spread the sigma points over +-290
    deg and the filter diverged (pose error 1.5 km)."""
    from srmosaic_ros.app.evaluate import evaluate_dir

    def run(cap_deg: float) -> tuple[dict, dict]:
        out = tmp_path / f'out_{cap_deg}'
        report = process_input(stills_bag, out, pipeline_config({'georef.max_attitude_step_sigma_deg': cap_deg}),
                               progress=False)
        return report['georeferenced'], evaluate_dir(out, stills_bag / 'ground_truth.json')

    geo, figures = run(20.0)
    assert not geo['skipped_telemetry'], geo['skipped_telemetry']
    assert geo['anchor_points'] == 'corners'                      # the ground was learnt
    assert figures['pose_rmse_horizontal_m'] < 1.0 and figures['georef_error_rms_m'] < 1.3, figures
    _, unbounded = run(90.0)
    assert unbounded['pose_rmse_horizontal_m'] > 10.0 * figures['pose_rmse_horizontal_m']
