"""The ground scale of a survey of stills when no consecutive pair has a GPS baseline long enough to
give it (app/survey.py metadata_scale): from the stills' height above take-off (DJI XMP
RelativeAltitude) with their intrinsics, then their GPS altitude above the ground height prior,
then, named a guess, georef.nominal_agl_m."""
from __future__ import annotations

import dataclasses
import logging
import math
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.app.process import process_input
from srmosaic_ros.app.run_report import read_run_frames
from srmosaic_ros.app.survey import SurveyStill, metadata_scale
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.sim import SimConfig, save_truth, simulate
from srmosaic_ros.sim.record import write_drone_stills

#: The simulated stills' height above the ground: not georef.nominal_agl_m (100 m), so a guess shows.
HEIGHT_M = 50.0


@pytest.fixture(scope='module')
def close_stills(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    """16 DJI stills (EXIF GPS, XMP RelativeAltitude and gimbal angles) 3 m apart at 50 m: GNSS of 1 m
    sd cannot tell baselines that short (the survey asks for 3 sd of georef.gps_sigma_h_m, 7.5 m), so
    no consecutive pair gives the scale. (folder, the true mean camera height above the ground)."""
    flight = simulate(SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='line', frames=16, altitude_m=HEIGHT_M,
                                speed_m_s=3.0, rate_hz=1.0, fix_rate_hz=5.0, gps_sigma_h_m=1.0, gust_deg=2.0, seed=5))
    root = tmp_path_factory.mktemp('scale')
    write_drone_stills(flight, root / 'survey')
    save_truth(flight.truth, root / 'truth.json')
    return root, float(np.mean([f.camera_enu_m[2] for f in flight.truth.frames]))


def test_the_scale_comes_from_the_relative_altitude_when_no_gps_baseline_registers(close_stills, tmp_path: Path,
                                                                                     caplog: pytest.LogCaptureFixture) -> None:
    root, height = close_stills
    with caplog.at_level(logging.INFO, logger='srmosaic_ros.app.survey'):
        report = process_input(root / 'survey', tmp_path / 'out', pipeline_config(), progress=False)
    survey = report['survey']
    assert survey['scale_source'].startswith('the stills\' height above take-off (XMP RelativeAltitude')
    assert 'no consecutive pair with a GPS baseline registered' in survey['scale_source']
    assert survey['scale_is_guess'] is False
    # measured: 49.1 m against 50.0 m (barometric noise 0.3 m; the gusts move each still by 1 m)
    assert survey['scale_m'] == pytest.approx(height, rel=0.03)
    assert any('ground scale' in r.getMessage() and 'RelativeAltitude' in r.getMessage() for r in caplog.records)
    # the stills' positions against their own tags (the goal: 5 m RMS): each still's centre in the
    # mosaic (through mosaic.tif's grid) against its EXIF GPS position
    frames = read_run_frames(tmp_path / 'out' / 'frames.csv')
    gt = report['georeferenced']['geotransform']
    c = frames.mosaic_H_frame @ np.array([159.5, 119.5, 1.0])
    x, y = c[:, 0] / c[:, 2], c[:, 1] / c[:, 2]
    en = np.stack([gt[0] + (x + 0.5) * gt[1] + (y + 0.5) * gt[2], gt[3] + (x + 0.5) * gt[4] + (y + 0.5) * gt[5]], 1)
    from pyproj import Transformer

    tags = np.stack(Transformer.from_crs(4326, report['georeferenced']['epsg'], always_xy=True).transform(
        frames.meta_latlon[:, 1], frames.meta_latlon[:, 0]), axis=1)
    rms = math.sqrt(float(np.mean(np.sum((en - tags) ** 2, axis=1))))
    assert rms < 5.0, rms  # measured: 3.3 m (tags of 1 m sd; 2 deg gusts tilt the view 1.7 m at 50 m)
    figures = evaluate_dir(tmp_path / 'out', root / 'truth.json')
    assert figures['georef_error_rms_m'] < 1.5, figures
    # the report page names the source of the scale and draws the survey's pair graph
    page = (tmp_path / 'out' / 'report.html').read_text(encoding='utf-8')
    assert 'RelativeAltitude' in page
    assert int(re.search(r'data-figure="pairs" data-pairs="(\d+)"', page).group(1)) == survey['pairs_registered']


def _still(k: int, *, height: float = math.nan, altitude: float = math.nan, focal: bool = True) -> SurveyStill:
    K = np.array([[400.0, 0, 159.5], [0, 400.0, 119.5], [0, 0, 1]])
    return SurveyStill(Path(f'{k}.jpg'), (320, 240), k, K, focal, np.zeros(2), (0.0, 0.0), True, None, height, altitude)


def test_the_metadata_scale_ladder_in_its_order() -> None:
    config = pipeline_config()
    no_reader = None
    # 1. the height above take-off, over the GPS altitude
    scale, source, guess = metadata_scale([_still(0, height=40.0, altitude=140.0), _still(1, height=42.0, altitude=141.0),
                                           _still(2, altitude=150.0)], config, no_reader, why='w')
    assert (scale, guess) == (41.0, False) and 'RelativeAltitude' in source and source.endswith(': w')
    # 2. the GPS altitude above the ground height prior: the configured one first, then the metadata's
    stills = [_still(0, altitude=130.0), _still(1, altitude=134.0)]
    given = dataclasses.replace(config, georef=dataclasses.replace(config.georef, ground_altitude_m=100.0))
    scale, source, guess = metadata_scale(stills, given, no_reader, why='w')
    assert (scale, guess) == (32.0, False) and 'georef.ground_altitude_m' in source
    reader = SimpleNamespace(summary=SimpleNamespace(ground_altitude_m=110.0, ground_altitude_source='the take-off point'))
    scale, source, guess = metadata_scale(stills, config, reader, why='w')
    assert (scale, guess) == (22.0, False) and 'the take-off point' in source
    # 3. nothing: the nominal height, named a guess; and without intrinsics a height is no scale
    scale, source, guess = metadata_scale(stills, config, no_reader, why='w')
    assert (scale, guess) == (config.georef.nominal_agl_m, True) and 'a guess' in source
    scale, source, guess = metadata_scale([_still(0, height=40.0, focal=False)], config, no_reader, why='w')
    assert guess and 'intrinsics are unknown' in source


def test_a_guessed_scale_is_said_in_the_report_page(tmp_path: Path) -> None:
    """report.html lists a guessed scale among the warnings (from report.json alone)."""
    from srmosaic_ros.app.run_report import write_run_report

    report = {'input': 'x', 'input_kind': 'images', 'frames_in': 0, 'frames_registered': 0,
              'survey': {'scale_m': 100.0, 'scale_is_guess': True,
                         'scale_source': 'georef.nominal_agl_m (100 m), a guess: no consecutive pair ...'}}
    write_run_report(tmp_path, report)
    page = (tmp_path / 'report.html').read_text(encoding='utf-8')
    assert re.search(r'class="warn">the ground scale is a guess: georef.nominal_agl_m', page)


def test_stills_that_no_pair_joins_are_placed_by_their_height_and_attitude(tmp_path: Path) -> None:
    """Eight DJI stills 50 m apart at 50 m up (no two overlap): nothing registers, so each is placed by
    its GPS position, turned by its gimbal yaw and sized by its height above take-off (not by the
    nominal 100 m, nor along its track with the image's x axis forward)."""
    flight = simulate(SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='line', frames=8, altitude_m=HEIGHT_M,
                                speed_m_s=5.0, rate_hz=0.1, fix_rate_hz=5.0, gust_deg=2.0, seed=5))
    write_drone_stills(flight, tmp_path / 'survey')
    save_truth(flight.truth, tmp_path / 'truth.json')
    report = process_input(tmp_path / 'survey', tmp_path / 'out', pipeline_config(), progress=False)
    assert report['placed_by'] == {'pose': 8} and report['survey']['pairs_registered'] == 0
    assert report['survey']['scale_m'] == pytest.approx(HEIGHT_M, rel=0.05)
    figures = evaluate_dir(tmp_path / 'out', tmp_path / 'truth.json')
    # measured: 4.6 m RMS over the footprints' centres and corners (GNSS of 2.5 m sd, gimbal noise
    # 0.5 deg); turned 90 deg or sized for 100 m, the corners were tens of metres off
    assert figures['georef_error_rms_m'] < 8.0, figures
