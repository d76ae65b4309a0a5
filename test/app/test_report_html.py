"""report.html (app/run_report.py): every `process` run writes it, self-contained and offline; it opens
in headless Chromium from file:// with every figure loaded and no request leaving the machine, and
a frame the run lost is marked in it."""
from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np

from demo_bags import rewrite_demo
from srmosaic_ros.app.process import process_input
from srmosaic_ros.app.run_report import EARLY_SECTIONS, MOSAIC_SECTIONS, start_sections, write_run_report
from srmosaic_ros.config import pipeline_config

#: Sections drawn for the demo bag (georeferenced, chained, no SR), and those that say they have no data.
DEMO_FIGURES = ('coverage', 'registration', 'map', 'time')
DEMO_EMPTY = ('pairs', 'sr')
# demo_run: the demo bag processed with the defaults, once for the session (test/flights.py): (out, the
# report process_input returned)


def _sections(page: str) -> dict[str, int]:
    return {k: int(n) for k, n in re.findall(r'<section id="[^"]*" data-section="([^"]+)" data-figures="(\d+)"', page)}


def _images(page: str) -> list[str]:
    return re.findall(r'<img [^>]*data-figure="([^"]+)"', page)


def test_every_run_writes_a_self_contained_report(demo_run) -> None:
    out, report = demo_run
    page = (out / 'report.html').read_text(encoding='utf-8')
    assert not re.search(r'https?://', page), 'the page refers to a resource on the network'
    assert '<script' not in page.lower() and "default-src 'none'" in page
    sections = _sections(page)
    assert all(sections[k] >= 1 for k in DEMO_FIGURES), sections
    assert all(sections[k] == 0 for k in DEMO_EMPTY), sections
    images = _images(page)
    assert sorted(set(images)) == sorted(DEMO_FIGURES) and len(images) == report['report_html']['figures']
    assert report['report_html']['sections_failed'] == []
    # its time is counted among the outputs and in the wall time
    saved = json.loads((out / 'report.json').read_text())
    assert saved['report_html'] == report['report_html'] and report['report_html']['time_s'] > 0
    assert saved['stage_times']['outputs']['total_s'] >= report['report_html']['time_s']
    # the map shows the bag's GNSS fixes and the fused poses
    assert re.search(r'data-figure="map" data-tracks="(\d+)"', page).group(1) == '3'


def test_sections_drawn_while_the_mosaic_renders_make_the_same_page(demo_run, tmp_path: Path) -> None:
    """`process` draws the sections of the tables (EARLY_SECTIONS) on a thread while the mosaic renders
    (start_sections), and those over preview.png (MOSAIC_SECTIONS) once it is written: the page is the
    one drawn after the run, byte for byte, and a section that cannot be drawn there is reported as
    one drawn after."""
    import shutil

    out, report = demo_run
    frame_sizes = [(640, 480)] * report['frames_in']
    pages = {}
    for name, ahead in (('after', False), ('ahead', True)):
        folder = tmp_path / name
        shutil.copytree(out, folder)
        early = start_sections(folder, report, frame_sizes=frame_sizes) if ahead else None
        if early is not None:
            early.add_mosaic_sections()
        figures = write_run_report(folder, report, frame_sizes=frame_sizes, early=early)
        pages[name] = ((folder / 'report.html').read_bytes(), figures['figures'], figures['sections_failed'])
    assert {b.__name__.strip('_') for b in EARLY_SECTIONS + MOSAIC_SECTIONS} - {'pair_graph'} <= set(DEMO_FIGURES)
    assert pages['ahead'] == pages['after'] and pages['after'][1] == len(DEMO_FIGURES)
    broken = tmp_path / 'broken'  # poses.csv damaged: the map fails ahead as it fails after the run, the rest drawn
    shutil.copytree(out, broken)
    (broken / 'poses.csv').write_text('stamp_ns\n1\n')
    figures = write_run_report(broken, report, frame_sizes=frame_sizes, early=start_sections(broken, report,
                                                                                             frame_sizes=frame_sizes))
    plain = write_run_report(broken, report, frame_sizes=frame_sizes)
    assert figures == {**plain, 'time_s': figures['time_s']} and figures['sections_failed'] == ['Positions on the map']


def test_the_report_opens_offline_in_a_browser_with_every_figure(demo_run, chromium) -> None:
    out, report = demo_run
    page = chromium.new_page()
    requests: list[str] = []
    page.on('request', lambda r: requests.append(r.url))
    page.goto((out / 'report.html').as_uri())
    page.wait_for_load_state('load')
    sizes = page.eval_on_selector_all('img', 'els => els.map(e => [e.complete, e.naturalWidth, e.naturalHeight])')
    assert len(sizes) == report['report_html']['figures'] and all(c and w > 0 and h > 0 for c, w, h in sizes), sizes
    assert all(u.startswith(('file://', 'data:')) for u in requests), requests
    assert page.locator('section#pairs .empty').inner_text().startswith('Not a survey')
    page.close()


def _noise_frame(kind: str, index: int, msg) -> None:
    """The demo's 31st image replaced by blurred noise of the same size: no registration places it."""
    if kind != 'image' or index != 30:
        return
    h, w = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR).shape[:2]
    noise = cv2.GaussianBlur(np.random.default_rng(1).integers(0, 255, (h, w, 3), dtype=np.uint8), (0, 0), 2.0)
    msg.data = np.frombuffer(cv2.imencode('.jpg', noise)[1].tobytes(), np.uint8)


def test_a_frame_the_run_lost_is_marked(tmp_path: Path) -> None:
    bag = rewrite_demo(tmp_path / 'bag', _noise_frame)
    report = process_input(bag, tmp_path / 'out', pipeline_config(), progress=False)
    lost = report['frames_in'] - report['frames_registered']
    assert lost >= 1
    page = (tmp_path / 'out' / 'report.html').read_text(encoding='utf-8')
    marked = dict(re.findall(r'data-figure="(coverage|registration)" data-failed-frames="(\d+)"', page))
    assert marked == {'coverage': str(lost), 'registration': str(lost)}
    assert re.search(r'data-figure="coverage" data-failed-frames="\d+" data-outlines="(\d+)"', page).group(1) \
        == str(report['frames_registered'])


def test_sr_gains_and_ground_control_are_drawn_from_the_report(tmp_path: Path) -> None:
    """A run folder with only report.json's data: the SR section draws one bar per checked tile; the
    map draws the control and check points; the sections without their files say so."""
    report = {
        'input': 'x', 'input_kind': 'images', 'frames_in': 0, 'frames_registered': 0,
        'sr': {'factor': 2, 'tiles': 3, 'tiles_planned': 4, 'tiles_refused': 1, 'psf_sigma_px': 0.5, 'wall_s': 1.0,
               'per_tile': [{'held_out_rms': [2.0, 3.0]}, {'held_out_rms': [2.5, 2.6]}, {'held_out_rms': [None, None]},
                            {'error': 'refused'}]},
        'gcp': {'epsg': 32631, 'control_rms_m': 0.1, 'check_rms_m': 0.2, 'control_rms_gsd': 1.0, 'check_rms_gsd': 2.0,
                'points': [{'name': 'a', 'role': 'control', 'surveyed_utm': [500000.0, 5e6], 'residual_m': [0.1, 0.0]},
                           {'name': 'b', 'role': 'check', 'surveyed_utm': [500050.0, 5e6], 'residual_m': [0.0, -0.2]},
                           {'name': 'c', 'role': 'check', 'surveyed_utm': [500020.0, 5e6 + 30], 'residual_m': None}]},
    }
    page_info = write_run_report(tmp_path, report)
    page = (tmp_path / 'report.html').read_text(encoding='utf-8')
    assert page_info['sections_failed'] == []
    assert re.search(r'data-figure="sr" data-tiles="(\d+)"', page).group(1) == '2'
    assert re.search(r'data-figure="map" data-tracks="0" data-gcp-points="(\d+)"', page).group(1) == '3'
    assert _sections(page)['coverage'] == 0 and 'No mosaic.png' in page
