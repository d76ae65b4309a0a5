"""Simulated traffic (srmosaic_ros/sim/traffic.py): cars painted into the rendered frames, with their
true masks, so that moving-object handling can be measured against truth."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from srmosaic_ros.errors import ConfigError
from srmosaic_ros.sim import SimConfig, load_truth, simulate
from srmosaic_ros.sim.cli import add_arguments, config_from_args
from srmosaic_ros.sim.traffic import Vehicle, paint_vehicles, restore_world, vehicle_mask
from srmosaic_ros.sim.truth import save_truth

CFG = SimConfig(frames=8, width=320, height=240, vehicles=6, vehicle_speed_m_s=10.0, rate_hz=4.0, seed=3)


@pytest.fixture(scope='module')
def flights() -> tuple:
    return simulate(CFG), simulate(CFG.replace(vehicles=0))


def test_vehicles_appear_where_their_true_masks_say(flights: tuple) -> None:
    """The same flight with and without traffic differs only on (and within the blur of) the true
    vehicle masks, and nearly everywhere on them."""
    cars, empty = flights
    for k in range(CFG.frames):
        mask = cars.truth.vehicle_mask(k)
        assert mask.shape == (240, 320) and mask.sum() > 100
        diff = np.abs(cars.frames[k].image.astype(int) - empty.frames[k].image.astype(int)).max(axis=2)
        near = cv2.dilate(mask.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
        assert not (diff[~near] > 20).any()       # noise is 2 grey levels: nothing else changed
        assert (diff[mask] > 20).mean() > 0.85    # measured 0.94 to 0.99 (cars on ground of their colour)
    assert not empty.truth.vehicles and empty.truth.vehicle_mask(0).sum() == 0


def test_vehicles_drive_at_their_speed(flights: tuple) -> None:
    """A car's mask centroid, taken back to the ground, moves speed x dt between frames."""
    truth = flights[0].truth
    v = truth.vehicles[0]
    gsd = truth.world_gsd_m
    assert np.hypot(*v.velocity_px_s) * gsd == pytest.approx(10.0)
    dt = 1.0 / CFG.rate_hz
    c0, c1 = v.polygon(0.0).mean(axis=0), v.polygon(dt).mean(axis=0)
    assert np.hypot(*(c1 - c0)) * gsd == pytest.approx(10.0 * dt)
    length = np.linalg.norm(v.polygon(0.0)[0] - v.polygon(0.0)[3]) * gsd
    assert length == pytest.approx(4.5)


def test_paint_and_restore_leave_the_world_as_it_was() -> None:
    world = np.random.default_rng(0).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    before = world.copy()
    cars = [Vehicle((40.0, 30.0), (5.0, 2.0), 20.0, 8.0, (250, 0, 0)), Vehicle((42.0, 32.0), (0.0, 0.0), 10.0, 4.0, (0, 0, 250))]
    saved = paint_vehicles(world, cars, 0.5)
    assert (world != before).any() and tuple(world[31, 42]) == (0, 0, 250)  # the second car on top
    restore_world(world, saved)
    np.testing.assert_array_equal(world, before)
    mask = vehicle_mask(cars[:1], 0.0, np.eye(3), (80, 60))
    assert mask[30, 40] and not mask[30, 55] and abs(int(mask.sum()) - 160) < 30


def test_truth_file_keeps_the_vehicles(flights: tuple, tmp_path: Path) -> None:
    truth = flights[0].truth
    save_truth(truth, tmp_path / 'ground_truth.json')
    back = load_truth(tmp_path / 'ground_truth.json')
    assert back.vehicles == truth.vehicles
    np.testing.assert_array_equal(back.vehicle_mask(3), truth.vehicle_mask(3))
    data = json.loads((tmp_path / 'ground_truth.json').read_text())
    del data['vehicles']  # a file written before traffic existed
    (tmp_path / 'old.json').write_text(json.dumps(data))
    assert load_truth(tmp_path / 'old.json').vehicles == []


def test_traffic_options() -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    cfg = config_from_args(parser.parse_args(['--vehicles', '4', '--vehicle-speed', '12', '--out', 'x']))
    assert cfg.vehicles == 4 and cfg.vehicle_speed_m_s == 12.0
    with pytest.raises(ConfigError, match='vehicles'):
        SimConfig(vehicles=-1)
