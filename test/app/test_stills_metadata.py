"""Folders of stills with their metadata in EXIF and XMP only (no sidecar): what real surveys carry.

A simulated DJI survey (JPEG stills with EXIF time, GPS, focal length and DJI XMP gimbal angles,
sim/record.write_drone_stills) is georeferenced through the filter against its truth; the real
caliterra stills (EXIF without attitude) by their geotags; report.json says what was used.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.app.process import process_input
from repo_paths import TEST_DATA

REAL_EXIF = TEST_DATA / 'real' / 'exif'
CHAIN = pipeline_config({'survey.mode': 'chain'})
# drone_survey: 20 stills 2 s apart over two lawnmower legs, 2 deg gusts, gimbal angles with 0.5 deg noise,
# in survey/ with truth.json beside it; hover_stills: stills whose GPS tags span a few metres (test/flights.py)


def test_exif_xmp_stills_are_georeferenced_through_the_filter(drone_survey: Path, tmp_path: Path) -> None:
    assert not list((drone_survey / 'survey').glob('*.csv'))  # nothing but the images
    report = process_input(drone_survey / 'survey', tmp_path, CHAIN, progress=False)
    assert report['frames_registered'] == 20 and len(report['segments']) == 1
    meta = report['metadata']
    assert meta['source'] == 'EXIF/XMP'
    assert {'gps position', 'gimbal attitude (XMP)', 'intrinsics', 'time'} <= set(meta['fields'])
    assert meta['frames_with_position'] == meta['frames_with_attitude'] == meta['frames_with_intrinsics'] == 20
    assert meta['intrinsics_source'].startswith('focal length 8.8 mm')
    # the take-off point from GPS altitude minus the XMP height above it: the ground is at 0 m
    assert abs(meta['ground_altitude']['m']) < 3.0
    assert report['georeferenced']['method'] == 'filter'
    figures = evaluate_dir(tmp_path, drone_survey / 'truth.json')
    assert figures['georef_error_rms_m'] < 2.0, figures  # measured 1.30 m (GNSS sigma 2.5 m)
    # every still's own GPS position is written beside its row for the truth-free figures
    header = (tmp_path / 'frames.csv').read_text().splitlines()[0].split(',')
    assert header[-3:] == ['meta_latitude', 'meta_longitude', 'placed_by']


def test_without_gimbal_angles_stills_fall_back_to_the_geotag_fit(tmp_path: Path) -> None:
    """Real Canon stills: intrinsics from EXIF, no attitude: placed by the similarity to the geotags."""
    report = process_input(REAL_EXIF, tmp_path, CHAIN, progress=False)
    meta = report['metadata']
    # IMG_9371's tag repeats IMG_9370's fix, taken 2 s before it: no position within 1 s for it
    assert meta['frames'] == 3 and meta['frames_with_position'] == 2 and meta['frames_with_attitude'] == 0
    assert any('no gimbal angles' in n for n in meta['notes'])
    geo = report['georeferenced']
    assert geo is None or geo['method'] == 'geotags'
    if geo is None:
        assert report['not_georeferenced_reason']


def test_a_still_without_gps_is_counted_not_fatal(drone_survey: Path, tmp_path: Path) -> None:
    from PIL import Image

    folder = tmp_path / 'survey'
    shutil.copytree(drone_survey / 'survey', folder)
    first = sorted((folder / 'images').iterdir())[0]
    with Image.open(first) as im:
        pixels, xmp = im.copy(), im.info.get('xmp')
    pixels.save(first, quality=95, xmp=xmp)  # EXIF (GPS, time, focal length) gone, XMP kept
    report = process_input(folder, tmp_path / 'out', CHAIN, progress=False)
    assert report['metadata']['problems'].get('exif_no_gps') == 1
    assert report['metadata']['frames_with_position'] >= 19
    assert report['georeferenced'] is not None
    json.dumps(report)  # the report stays JSON


def test_gps_tags_are_stamped_at_their_own_fix_time() -> None:
    """IMG_9371 repeats IMG_9370's GPS tag (time and position) though taken 2 s later: its fix is
    stamped at that GPS time (moved onto the capture clock), so the two fixes share a stamp and the
    repeat is not taken for a position 2 s later."""
    from srmosaic_ros.core.types import Frame, GeoFix
    from srmosaic_ros.io.image_folder import ImageFolderReader

    items = list(ImageFolderReader(REAL_EXIF))
    fixes = {i: it for i, it in enumerate(items) if isinstance(it, GeoFix)}
    frames = [it for it in items if isinstance(it, Frame)]
    by_name = {}
    fix_list = list(fixes.values())
    for frame, fix in zip(frames, fix_list):
        by_name[frame.frame_id] = (frame.stamp_ns, fix.stamp_ns)
    cap_70, fix_70 = by_name['IMG_9370.jpg']
    cap_71, fix_71 = by_name['IMG_9371.jpg']
    assert cap_71 - cap_70 == 2_000_000_000
    assert fix_71 == fix_70  # the same fix; the georeferencer drops the second (not after the first)


def test_geotags_of_a_hover_cannot_place_the_mosaic(hover_stills: Path, tmp_path: Path) -> None:
    """Stills whose GPS tags span a few metres (a hover, a pan: karma.mp4's 3.3 m) would get the
    mosaic's scale and rotation from GNSS noise: refused, with the reason in the report."""
    report = process_input(hover_stills, tmp_path / 'out', CHAIN, progress=False)
    assert report['frames_registered'] == 10
    assert report['georeferenced'] is None
    assert 'less than 10 m' in report['not_georeferenced_reason'], report['not_georeferenced_reason']


def test_a_gps_tag_that_jumps_is_gated_not_followed(drone_survey: Path, tmp_path: Path) -> None:
    """One still tagged 300 m away (a glitch of the receiver): the filter refuses that fix, counts it,
    and the survey stays where the truth is."""
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
    report = process_input(folder, tmp_path / 'out', CHAIN, progress=False)
    assert report['georeferenced']['method'] == 'filter'
    assert report['georeferenced']['skipped_telemetry'].get('fix_gated', 0) >= 1
    figures = evaluate_dir(tmp_path / 'out', drone_survey / 'truth.json')
    assert figures['georef_error_rms_m'] < 2.5, figures['georef_error_rms_m']  # 1.30 m without the glitch
