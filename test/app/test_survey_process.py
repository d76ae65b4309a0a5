"""`srmosaic process FOLDER` on surveys of stills, aligned globally (srmosaic_ros/survey.py): a
simulated DJI survey (EXIF/XMP only) against its truth, with a glitched GPS tag, a textureless still
and a hover; the repository's real caliterra stills through the truth-free figures."""
from __future__ import annotations

import collections
import csv
import dataclasses
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.app.evaluate_real import evaluate_real
from srmosaic_ros.io.mosaic_files import read_frames_csv
from srmosaic_ros.app.process import process_input
from srmosaic_ros.app.survey import read_reduced, reduction_for
from repo_paths import REPO

CALITERRA = REPO / 'data' / 'sequences' / 'caliterra'
# drone_survey (20 DJI stills over two overlapping lawnmower legs, survey/ and truth.json), hover_stills
# and caliterra_run (the caliterra stills processed with the defaults): test/flights.py, once for the session


@pytest.fixture(scope='module')
def default_run(drone_survey: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The simulated survey processed once with the defaults: (output folder, report). Shared by the
    tests that check it or compare against it; they only read it."""
    out = tmp_path_factory.mktemp('default_run')
    return out, process_input(drone_survey / 'survey', out, pipeline_config(), progress=False)


def _placed_by(frames_csv: Path) -> list[str]:
    with open(frames_csv, newline='') as handle:
        return [r['placed_by'] for r in csv.DictReader(handle)]


def test_a_survey_is_aligned_globally_and_placed_within_its_gps_error(drone_survey: Path, default_run) -> None:
    out, report = default_run
    survey = report['survey']
    assert report['georeferenced']['method'] == 'global alignment'
    assert report['frames_registered'] == 20 and len(report['segments']) == 1
    assert _placed_by(out / 'frames.csv') == ['registration'] * 20
    # pairs beyond the consecutive ones: the two legs overlap
    assert survey['pairs_by_footprint_tried'] > 0 and survey['pairs_registered'] > 19
    assert survey['solver_converged']
    # the height above ground from GPS baselines over registered displacements (truth: 100 m)
    assert survey['height_above_ground_m'] == pytest.approx(100.0, rel=0.05)
    figures = evaluate_dir(out, drone_survey / 'truth.json')
    # measured: 1.36 m RMS on the ground (GNSS sigma 2.5 m, gimbal angles 0.5 deg; the filter: 1.30 m),
    # 0.17 px mean corner error of the mosaic
    assert figures['georef_error_rms_m'] < 2.0, figures
    assert figures['corner_error_mean_px'] < 1.5, figures
    for name in ('mosaic.png', 'mosaic.tif', 'mosaic.kml', 'preview.png', 'report.json'):
        assert (out / name).is_file()
    assert not (out / 'poses.csv').exists()
    json.dumps(report, allow_nan=False)


def test_a_bounded_feature_cache_gives_the_same_survey(drone_survey: Path, default_run, tmp_path: Path) -> None:
    """Two described stills kept instead of 48: stills are described again, the result is the same."""
    base = pipeline_config()
    small = dataclasses.replace(base, survey=dataclasses.replace(base.survey, feature_cache_frames=2))
    a_dir, a = default_run
    b = process_input(drone_survey / 'survey', tmp_path / 'b', small, progress=False)
    assert b['survey']['frames_described'] > a['survey']['frames_described'] == 20
    ha = [r['mosaic_H_frame'] for r in read_frames_csv(a_dir / 'frames.csv')]
    hb = [r['mosaic_H_frame'] for r in read_frames_csv(tmp_path / 'b' / 'frames.csv')]
    assert np.allclose(ha, hb, atol=1e-6)


def test_a_textureless_still_is_placed_by_its_pose(drone_survey: Path, tmp_path: Path) -> None:
    """A still of bare, even ground (no features: a gentle slope of shade; a picture of one flat colour
    has no content and is left out, test_hostile_inputs.py): no pair registers it; its GPS position and
    its heading place it, marked 'pose' in frames.csv, the others still by registration."""
    from PIL import Image

    folder = tmp_path / 'survey'
    shutil.copytree(drone_survey / 'survey', folder)
    still = sorted((folder / 'images').iterdir())[5]
    with Image.open(still) as im:
        xmp, exif = im.info.get('xmp'), im.getexif()
        ramp = np.linspace(0.0, 12.0, im.size[0])[None, :, None]
        flat = Image.fromarray((np.array([120.0, 110.0, 90.0]) + ramp + np.zeros((im.size[1], 1, 1))).astype(np.uint8))
    flat.save(still, quality=95, exif=exif, xmp=xmp)
    report = process_input(folder, tmp_path / 'out', pipeline_config(), progress=False)
    placed = _placed_by(tmp_path / 'out' / 'frames.csv')
    assert placed[5] == 'pose' and placed.count('registration') == 19
    assert report['placed_by'] == {'registration': 19, 'pose': 1}
    # the OpenCV second opinion is asked about the pairs of the still that has none (in vain), and
    # not about every failed pair of well-connected stills
    asked = report['survey']['pairs_second_opinion']
    assert any(5 in (i, j) for i, j, _ in asked) and not any(ok for i, j, ok in asked if 5 in (i, j))
    count = collections.Counter(k for (i, j), _ in report['survey']['pairs_graph'] for k in (i, j))
    assert all(min(count[i], count[j]) - ok < 3 for i, j, ok in asked)
    failed = report['survey']['pairs_tried'] - report['survey']['pairs_registered']
    assert len(asked) < failed
    figures = evaluate_dir(tmp_path / 'out', drone_survey / 'truth.json')
    assert figures['georef_error_max_m'] < 3 * 2.5 * 2 + 5.0, figures  # within its GPS error, tilt included


def test_a_gps_tag_that_jumps_does_not_move_the_survey(drone_survey: Path, tmp_path: Path) -> None:
    """One still tagged 300 m away: the registrations hold it; the robust solve leaves that tag out."""
    from PIL import Image

    folder = tmp_path / 'survey'
    shutil.copytree(drone_survey / 'survey', folder)
    still = sorted((folder / 'images').iterdir())[10]
    with Image.open(still) as im:
        pixels, xmp, exif = im.copy(), im.info.get('xmp'), im.getexif()
    gps = exif.get_ifd(0x8825)
    d, m, sec = gps[2]
    gps[2] = (d, m, float(sec) + 10.0)  # 10 arc seconds north: about 300 m
    pixels.save(still, quality=95, exif=exif, xmp=xmp)
    report = process_input(folder, tmp_path / 'out', pipeline_config(), progress=False)
    assert report['frames_registered'] == 20
    figures = evaluate_dir(tmp_path / 'out', drone_survey / 'truth.json')
    assert figures['georef_error_rms_m'] < 3.0, figures


def test_a_hover_is_aligned_but_not_georeferenced(hover_stills: Path, tmp_path: Path) -> None:
    """GPS tags spanning a few metres cannot set the scale and rotation: aligned, not on the map."""
    report = process_input(hover_stills, tmp_path / 'out', pipeline_config(), progress=False)
    assert report['frames_registered'] == 10
    assert report['georeferenced'] is None and not (tmp_path / 'out' / 'mosaic.tif').exists()
    assert 'less than 10 m' in report['not_georeferenced_reason'], report['not_georeferenced_reason']


def test_real_stills_in_one_mosaic_that_agrees_with_them(caliterra_run) -> None:
    """The 14 real caliterra stills (positions from telemetry_from_exif.csv, no focal length): one
    georeferenced mosaic, every still in it, each agreeing with the composite."""
    out, report = caliterra_run
    assert report['georeferenced']['method'] == 'global alignment'
    assert report['frames_registered'] == 14
    fig = evaluate_real(out, progress=False)
    # measured: NCC median 0.95, p10 0.92; the chained pipeline on the same stills: 0.99 (it
    # upsamples them into a coarser mosaic, which hides misalignment)
    assert fig['ncc_median'] > 0.9 and fig['ncc_p10'] > 0.85, fig
    assert fig['position'] is not None and fig['position']['rms_m'] < 15.0, fig['position']


def test_stills_are_decoded_reduced_in_the_dct(tmp_path: Path) -> None:
    assert reduction_for(4000, 3000, 1.0) == 4 and reduction_for(2000, 1500, 1.0) == 2
    assert reduction_for(1000, 750, 1.0) == 1 and reduction_for(8000, 6000, 0.1) == 8
    still = sorted((CALITERRA / 'images').iterdir())[0]
    full = read_reduced(still, 1)
    half = read_reduced(still, 2)
    assert half.shape[0] == -(-full.shape[0] // 2) and half.shape[1] == -(-full.shape[1] // 2)
    ref = cv2.resize(full, (half.shape[1], half.shape[0]), interpolation=cv2.INTER_AREA)
    assert float(np.mean(np.abs(ref.astype(float) - half))) < 3.0  # the DCT-scaled decode is the image, halved


def test_without_gps_the_chain_predicts_the_pairs_that_join_the_lines(drone_survey: Path, tmp_path: Path) -> None:
    """The DJI survey with its GPS tags removed, aligned globally (survey.mode: global; 'auto' chains
    stills without GPS): not georeferenced, but the legs are still joined by pairs the chain
    predicts (not only consecutive ones), and the mosaic agrees with the truth."""
    from PIL import Image

    folder = tmp_path / 'survey'
    shutil.copytree(drone_survey / 'survey', folder)
    for still in sorted((folder / 'images').iterdir()):
        with Image.open(still) as im:
            pixels, xmp, exif = im.copy(), im.info.get('xmp'), im.getexif()
        del exif[0x8825]  # the GPS IFD
        pixels.save(still, quality=95, exif=exif, xmp=xmp)
    report = process_input(folder, tmp_path / 'out', pipeline_config({'survey.mode': 'global'}), progress=False)
    assert report['georeferenced'] is None and report['frames_registered'] == 20
    assert report['survey']['pairs_by_footprint_tried'] > 0
    figures = evaluate_dir(tmp_path / 'out', drone_survey / 'truth.json')
    assert figures['corner_error_mean_px'] < 1.0, figures  # measured 0.13 px mean, 0.42 max (80 pairs predicted)


def test_a_run_into_an_earlier_runs_folder_leaves_one_runs_files(caliterra_run, tmp_path: Path) -> None:
    """A georeferenced run, then one without georeferencing into the same --out: the earlier
    mosaic.tif and mosaic.kml (which would place the new mosaic.png wrongly) are removed, and the
    report says so; the files of the new run stay."""
    import os
    import time

    shutil.copytree(caliterra_run[0], tmp_path, dirs_exist_ok=True)  # the earlier run's folder
    assert (tmp_path / 'mosaic.tif').is_file() and (tmp_path / 'mosaic.kml').is_file()
    old = time.time() - 60  # as if that run had ended a minute ago
    for f in tmp_path.iterdir():
        os.utime(f, (old, old))
    report = process_input(CALITERRA, tmp_path, pipeline_config({'georef.enabled': False, 'survey.mode': 'chain'}),
                           progress=False)
    assert report['georeferenced'] is None
    assert sorted(report['stale_outputs_removed']) == ['mosaic.kml', 'mosaic.tif']
    assert not (tmp_path / 'mosaic.tif').exists() and not (tmp_path / 'mosaic.kml').exists()
    for name in ('mosaic.png', 'frames.csv', 'report.json', 'preview.png'):
        assert (tmp_path / name).stat().st_mtime > old + 30


def test_stills_exposed_differently_are_matched_before_painting(drone_survey: Path, default_run, tmp_path: Path) -> None:
    """Four stills of one leg darkened to 70 % and one given a blue cast (auto exposure and white
    balance): painted with their exposure gains (survey.exposure, the default 'channels') their
    ground comes out as the untouched survey's; without ('none') it stays 30 % dark."""
    from PIL import Image

    folder = tmp_path / 'survey'
    shutil.copytree(drone_survey / 'survey', folder)
    stills = sorted((folder / 'images').iterdir())
    changed = {6: (0.7, 0.7, 0.7), 7: (0.7, 0.7, 0.7), 8: (0.7, 0.7, 0.7), 9: (0.7, 0.7, 0.7), 14: (0.9, 1.0, 1.2)}
    for k, factor in changed.items():
        with Image.open(stills[k]) as im:
            pixels, xmp, exif = np.asarray(im.convert('RGB'), np.float32), im.info.get('xmp'), im.getexif()
        Image.fromarray(np.clip(pixels * np.array(factor, np.float32), 0, 255).round().astype(np.uint8)).save(
            stills[k], quality=95, exif=exif, xmp=xmp)
    reference = default_run[1]
    report = process_input(folder, tmp_path / 'on', pipeline_config(), progress=False)
    process_input(folder, tmp_path / 'off', pipeline_config({'survey.exposure': 'none'}), progress=False)
    assert reference['exposure']['mode'] == 'channels' and report['exposure']['gain_max'][0] > 1.3

    def means(run: str) -> np.ndarray:
        """(still, channel) mean of the mosaic over the middle half of each changed still's footprint."""
        folder = default_run[0] if run == 'ref' else tmp_path / run
        mosaic = cv2.imread(str(folder / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
        rows = read_frames_csv(folder / 'frames.csv')
        out = []
        for k in changed:
            inside = np.zeros(mosaic.shape[:2], np.uint8)
            quad = np.array([[80, 60], [240, 60], [240, 180], [80, 180]], np.float64)  # of 320 x 240
            q = cv2.perspectiveTransform(quad[None], rows[k]['mosaic_H_frame'])[0]
            cv2.fillConvexPoly(inside, np.round(q).astype(np.int32), 1)
            out.append(mosaic[:, :, 2::-1][inside > 0].mean(axis=0))  # RGB
        return np.array(out)

    ref, on, off = means('ref'), means('on'), means('off')
    # measured: with the gains within 0.2 % of the untouched survey on every channel; without,
    # the darkened stills at 0.77 to 0.85 (the multiband blend spreads their neighbours' light
    # into them), the cast still 1.08 bluer than red
    assert np.all(np.abs(on / ref - 1) < 0.02), on / ref
    assert np.all(off[:4] / ref[:4] < 0.87), off / ref
    cast = off[4] / ref[4]
    assert cast[2] / cast[0] > 1.05, cast


def test_stills_painted_where_they_can_win_give_the_mosaic_of_painting_all(drone_survey: Path, tmp_path: Path) -> None:
    """survey.paint_rank (core/survey/paint_plan.py) against 0 (every still wherever it falls), on
    64 px tiles (a 320 x 240 still spans about 5 x 4): the same coverage and nearly the same pixels
    from fewer tile paints."""
    base = pipeline_config()
    base = dataclasses.replace(base, mosaic=dataclasses.replace(base.mosaic, tile_size=64))
    every = dataclasses.replace(base, survey=dataclasses.replace(base.survey, paint_rank=0))
    a = process_input(drone_survey / 'survey', tmp_path / 'plan', base, progress=False)
    b = process_input(drone_survey / 'survey', tmp_path / 'all', every, progress=False)
    assert b['paint_plan'] is None
    # two legs of ten stills: little of the ground is seen three times or more
    assert a['paint_plan']['rank'] == 2 and a['paint_plan']['tiles_painted'] < a['paint_plan']['tiles_touched']
    pa = cv2.imread(str(tmp_path / 'plan' / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    pb = cv2.imread(str(tmp_path / 'all' / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    assert pa.shape == pb.shape
    cov = pb[..., 3] > 0
    inner = cv2.erode(cov.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert (pa[..., 3][inner] > 0).all()  # no hole
    diff = np.abs(pa[..., :3].astype(float) - pb[..., :3])[inner]
    assert 10 * np.log10(255.0**2 / np.mean(diff**2)) > 35.0


def test_bad_survey_settings_are_refused() -> None:
    from srmosaic_ros.core.survey.config import SurveyConfig

    with pytest.raises(ValueError, match=r'survey.paint_rank=-1'):
        SurveyConfig(paint_rank=-1)
