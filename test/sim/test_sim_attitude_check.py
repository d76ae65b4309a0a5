"""A measured camera attitude against the one the frames show (pose_check.check_measured_attitude):
a gimbal angle read in another convention than its carrier's (relative to the body instead of the
horizon, a sign) is said in report.json `attitude_check` and a warning; the measurement still
places the frames."""
from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from srmosaic_ros.app.process import write_outputs
from srmosaic_ros.config import PipelineConfig
from srmosaic_ros.core.georef.frames import rot_x
from srmosaic_ros.core.types import CameraAttitude
from srmosaic_ros.io.metadata import merge_by_time
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, simulate

# test_mount_from_frames.py's oblique line, 60 deg below the horizon
LINE = {'trajectory': 'line', 'frames': 30, 'rate_hz': 2.0, 'altitude_m': 80.0, 'hfov_deg': 40.0, 'width': 160,
        'height': 120, 'gimbal_elevation_deg': -60.0, 'seed': 4}


@pytest.fixture(scope='module')
def flight():
    return simulate(SimConfig(**LINE))


def _run(flight, tilt_deg: float, tmp_path):
    """report.json of the line fed with its fixes and, at every frame, its true camera attitude
    tilted ``tilt_deg`` about the image x axis (positive: the optical axis raised)."""
    attitudes = [CameraAttitude(t.stamp_ns, np.asarray(t.R_enu_from_cam) @ rot_x(math.radians(tilt_deg)),
                                math.radians(1.0)) for t in flight.truth.frames]
    telemetry = sorted(flight.fixes + attitudes, key=lambda x: x.stamp_ns)
    config = PipelineConfig()
    pipeline = Pipeline(config)
    for item in merge_by_time(flight.frames, telemetry):
        pipeline.feed(item)
    result = pipeline.finish()
    return result, write_outputs(result, tmp_path, config, {})


def test_the_true_attitude_agrees_with_the_frames(flight, tmp_path) -> None:
    result, report = _run(flight, 0.0, tmp_path)
    check = report['attitude_check']
    assert check['measured_elevation_deg'] == pytest.approx(-60.0, abs=3.0)  # the simulator's 2 deg gusts
    assert check['agrees'] and check['difference_deg'] < 3.0, check
    assert 'pose_placement' not in report and report['georeferenced']['method'] == 'filter'


def test_an_attitude_read_25_deg_off_is_said(flight, tmp_path, caplog) -> None:
    """A gimbal pitch 25 deg too high (e.g. relative to a body pitched nose-down, read as if to the
    horizon): the frames still show 60 deg below the horizon, the warning says both."""
    with caplog.at_level(logging.WARNING, logger='srmosaic_ros.pipeline'):
        result, report = _run(flight, 25.0, tmp_path)
    check = report['attitude_check']
    assert check['measured_elevation_deg'] == pytest.approx(-35.0, abs=3.0)
    assert check['frames_elevation_deg'] == pytest.approx(-60.0, abs=3.0)
    assert not check['agrees'] and check['difference_deg'] > 20.0, check
    said = ' '.join(r.getMessage() for r in caplog.records)
    assert 'where its measured attitude says 35 deg below the horizon' in said and 'convention' in said
    assert report['georeferenced']['method'] == 'filter'  # the measurement places them, as it did
