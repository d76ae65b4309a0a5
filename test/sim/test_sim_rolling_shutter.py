"""A rolling shutter (SimConfig.rolling_shutter_s): each sensor row is exposed at its own pose, the
frame's stamp and truth are its middle row's."""
from __future__ import annotations

import argparse

import cv2
import numpy as np
import pytest

from srmosaic_ros.errors import ConfigError
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.cli import add_arguments, config_from_args


def test_rows_are_exposed_at_their_own_time() -> None:
    """20 m/s without gusts, a 50 ms readout: against the global-shutter frame, a band of rows centred
    at row y is shifted along the flight by v (y - (H - 1) / 2) / (H - 1) x 50 ms (about 1.1 px at the
    top and bottom bands, of opposite signs), and the middle rows not at all."""
    base = SimConfig(frames=4, width=320, height=240, rate_hz=4.0, seed=1, speed_m_s=20.0, gust_deg=0.0,
                     gust_pos_m=0.0, noise_sigma=0.0)
    glob, roll = simulate(base), simulate(base.replace(rolling_shutter_s=0.05))
    a, b = (cv2.cvtColor(f.frames[3].image, cv2.COLOR_RGB2GRAY).astype(np.float32) for f in (glob, roll))
    win = cv2.createHanningWindow((320, 48), cv2.CV_32F)
    px_per_s = 20.0 / glob.truth.camera_gsd_m
    for y0 in (0, 96, 192):
        (dx, dy), _ = cv2.phaseCorrelate(a[y0:y0 + 48], b[y0:y0 + 48], win)
        expected = (y0 + 23.5 - 119.5) / 239.0 * 0.05 * px_per_s
        assert np.hypot(dx, dy) == pytest.approx(abs(expected), abs=0.2), (y0, dx, dy, expected)
        if abs(expected) > 0.5:
            assert np.sign(dx + dy) == np.sign(expected)
    assert np.abs(a[118:122] - b[118:122]).mean() < 0.1  # the middle rows: the truth's pose
    assert roll.truth.frames[3].world_px_H_frame == pytest.approx(glob.truth.frames[3].world_px_H_frame)


def test_rolling_shutter_option_is_checked_and_reaches_the_cli() -> None:
    with pytest.raises(ConfigError, match='rolling_shutter_s 0.5'):
        SimConfig(rolling_shutter_s=0.5)
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert config_from_args(parser.parse_args(['--rolling-shutter', '0.03', '--out', 'x'])).rolling_shutter_s == 0.03
