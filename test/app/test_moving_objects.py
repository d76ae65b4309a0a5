"""Moving objects against the simulator's truth (mosaic.moving, core/mosaic/best_view.py): cars are
kept out of the mosaic's background, and moving.png says where they drove."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from srmosaic_ros.app.process import process_input
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.io.mosaic_files import read_frames_csv
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, simulate, write_flight
from srmosaic_ros.sim.traffic import vehicle_mask

CFG = SimConfig(frames=24, width=320, height=240, vehicles=14, vehicle_speed_m_s=8.0, rate_hz=4.0, seed=5)


@pytest.fixture(scope='module')
def flights() -> tuple:
    return simulate(CFG), simulate(CFG.replace(vehicles=0))


def trail_of(truth, world_px_H_mosaic: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """bool (h, w): mosaic pixels some vehicle covered in some frame."""
    trail = np.zeros((size[1], size[0]), bool)
    for f in truth.frames:
        trail |= vehicle_mask(truth.vehicles, (f.stamp_ns - truth.frames[0].stamp_ns) * 1e-9, world_px_H_mosaic, size)
    return trail


def test_cars_are_kept_out_of_the_mosaic_background(flights: tuple) -> None:
    """Over the ground some car covered, the mosaic shows the traffic-free flight's mosaic: trail
    pixels more than 25 grey levels off it, plain best view against the vote (bench/traffic.py has
    the figures for a longer flight)."""
    cars, empty = flights

    def segment_of(flight, moving: float):
        pipe = Pipeline(pipeline_config({'georef.enabled': False, 'mosaic.moving': moving}))
        for frame in flight.frames:
            pipe.feed_frame(frame)
        seg = pipe.finish().main_segment
        assert len(seg.frames) == CFG.frames
        return seg

    shows, from_cars = {}, {}
    for moving in (0.0, 0.05):
        seg = segment_of(cars, moving)
        canvas = seg.canvas
        x0, y0, x1, y1 = region = canvas.bounds()
        image, covered = canvas.render(region)
        clean, clean_covered = segment_of(empty, moving).canvas.render(region)
        h0 = cars.truth.frames[0].world_px_H_frame @ np.array([[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1.0]])
        trail = trail_of(cars.truth, h0, (x1 - x0, y1 - y0)) & covered & clean_covered
        assert trail.sum() > 5000
        shows[moving] = float((np.abs(image - clean).max(axis=2)[trail] * 255.0 > 25.0).mean())
        # the truth's own count: trail pixels taken from a frame in which a car is there
        from_cars[moving] = float(cars.truth.vehicles_shown(canvas.labels(region), seg.frames, h0)[trail].mean())
    print(shows, from_cars)
    assert shows[0.0] > 0.05
    assert shows[0.05] < 0.03
    assert from_cars[0.0] > 0.04 and from_cars[0.05] < 0.01


def test_moving_png_marks_where_cars_drove(flights: tuple, tmp_path) -> None:
    """process with mosaic.moving writes moving.png (mosaic.png's grid, frames kept out per pixel) and
    report.json's 'moving'; what it marks lies on the true trail (grown by the vote's 5 x 5 box twice
    and the registration), and it marks much of the trail."""
    cars, _ = flights
    bag = write_flight(cars, tmp_path / 'bag')
    out = tmp_path / 'out'
    process_input(bag, out, pipeline_config({'georef.enabled': False, 'mosaic.moving': 0.05}), progress=False)
    report = json.loads((out / 'report.json').read_text())
    counts = cv2.imread(str(out / 'moving.png'), cv2.IMREAD_UNCHANGED)
    mosaic = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    assert counts.dtype == np.uint8 and counts.shape == mosaic.shape[:2]
    assert report['moving']['file'] == 'moving.png' and report['moving']['pixels'] == np.count_nonzero(counts)
    rows = read_frames_csv(out / 'frames.csv')
    assert all(r['ok'] for r in rows)
    world_px_H_mosaic = cars.truth.frames[0].world_px_H_frame @ np.linalg.inv(rows[0]['mosaic_H_frame'])
    h, w = counts.shape
    trail = trail_of(cars.truth, world_px_H_mosaic, (w, h))
    near = cv2.dilate(trail.astype(np.uint8), np.ones((11, 11), np.uint8)) > 0
    marked = counts > 0
    precision = float((marked & near).sum() / marked.sum())
    recall = float((marked & trail).sum() / trail.sum())
    print(precision, recall)
    assert precision > 0.9, precision
    assert recall > 0.3, recall
    # the vote off: no moving.png, no report entry
    process_input(bag, tmp_path / 'plain', pipeline_config({'georef.enabled': False}), progress=False)
    assert not (tmp_path / 'plain' / 'moving.png').exists()
    assert 'moving' not in json.loads((tmp_path / 'plain' / 'report.json').read_text())
