"""GPS and intrinsics, no measured attitude, a camera fixed obliquely: `process` reads the mount
from the frames' chain (core/georef/chain_mount.py) and starts again with it, so that the filter
places them. A straight line 70 deg below the horizon passed the NIS check alone (median 36.1
under the gate 37.3) and was placed 14.9 px off in the mosaic, 9.4 m on the map."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from srmosaic_ros.app.checkpoint import read_header
from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.app.process import process_input
from srmosaic_ros.cli import main as cli_main
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.georef.pose_check import mount_axis_angle_deg
from srmosaic_ros.io.bags import TopicConfig
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.record import write_flight

LINE = {'trajectory': 'line', 'frames': 40, 'rate_hz': 2.0, 'altitude_m': 80.0, 'hfov_deg': 40.0, 'width': 160,
        'height': 120, 'gimbal_elevation_deg': -70.0, 'seed': 4}


@pytest.fixture(scope='module')
def oblique_bag(tmp_path_factory):
    return write_flight(simulate(SimConfig(**LINE)), tmp_path_factory.mktemp('line') / 'bag')


def _process(bag, out, overrides):
    """report.json and the truth figures of `process` over the bag without its Imu topic."""
    report = process_input(bag, out, pipeline_config(overrides), topics=TopicConfig(imu=''), progress=False)
    assert json.loads((out / 'report.json').read_text())['input'] == report['input']
    return report, evaluate_dir(out, bag / 'ground_truth.json')


def test_an_oblique_camera_is_placed_with_the_mount_its_frames_show(oblique_bag, tmp_path, caplog, capsys) -> None:
    """`srmosaic process` as a user runs it. Measured: the frames show 69.4 deg below the horizon,
    6.8 deg from the travel (true: 70, 0); with that mount the filter places them: 0.31 px, 1.27 m
    (with the true mount 0.26 px, 0.96 m)."""
    out = tmp_path / 'out'
    with caplog.at_level('WARNING', logger='srmosaic_ros.app.process'):
        assert cli_main(['process', str(oblique_bag), '--out', str(out), '--imu-topic', '', '--no-progress']) == 0
    printed = capsys.readouterr().out
    restart = json.loads((out / 'report.json').read_text())['mount_from_frames']
    assert f"camera mount from the frames (no attitude measured): {-restart['elevation_deg']:g} deg below" in printed
    report, fig = json.loads((out / 'report.json').read_text()), evaluate_dir(out, oblique_bag / 'ground_truth.json')
    restart = report['mount_from_frames']
    assert mount_axis_angle_deg((restart['azimuth_deg'], restart['elevation_deg']), (0.0, -70.0)) < 3.0, restart
    assert 0 < restart['after_frames'] < 20  # the settling frames only were processed twice
    first = restart['first_check']
    assert first['used'] is False and first['mount_elevation_deg'] == -90.0
    assert '69 deg below the horizon' in first['reason']
    assert report['pose_placement']['used'] is True
    assert report['pose_placement']['mount_elevation_deg'] == restart['elevation_deg']
    assert report['georeferenced']['method'] == 'filter'
    assert fig['frames_registered'] == fig['frames_in'] == 40
    assert fig['corner_error_mean_px'] < 0.6, fig  # 14.9 px on the nadir assumption
    assert fig['georef_error_rms_m'] < 3.0, fig  # 9.4 m on the nadir assumption
    said = ' '.join(r.getMessage() for r in caplog.records)
    assert 'starting again with that mount' in said and 'georef.mount_from_frames: false' in said


def test_without_the_restart_it_is_chained_and_not_put_on_the_map(oblique_bag, tmp_path) -> None:
    """georef.mount_from_frames: false: refused by the chain's mount (the NIS alone passed it), chained
    (0.085 px); its geotags do not place it either (as nadir they put it 37 m off), the reason says
    which mount to set."""
    report, fig = _process(oblique_bag, tmp_path / 'out', {'georef.mount_from_frames': False})
    assert 'mount_from_frames' not in report
    assert report['pose_placement']['used'] is False
    assert report['pose_placement']['median_nis'] < report['pose_placement']['gate_nis']
    assert report['georeferenced'] is None
    reason = report['not_georeferenced_reason']
    assert 'chain shows the camera 69 deg below the horizon' in reason and 'georef.gimbal_elevation_deg: -69' in reason
    assert fig['corner_error_mean_px'] < 0.2, fig


def test_a_run_started_again_with_the_frames_mount_resumes_with_it(tmp_path) -> None:
    """kill -9 after the restart, then --resume: the resumed run keeps the frames' mount and says so
    in report.json (it used to report no mount_from_frames), and writes what the whole run writes."""
    bag = write_flight(simulate(SimConfig(**{**LINE, 'frames': 80, 'rate_hz': 5.0})), tmp_path / 'bag')
    cli = [sys.executable, '-m', 'srmosaic_ros.cli', 'process', str(bag), '--imu-topic', '', '--no-progress',
           '--checkpoint-every', '5']
    full = tmp_path / 'full'
    assert subprocess.run([*cli, '--out', str(full)], capture_output=True, timeout=600).returncode == 0
    restart = json.loads((full / 'report.json').read_text())['mount_from_frames']
    assert restart['after_frames'] < 30

    out = tmp_path / 'interrupted'
    proc = subprocess.Popen([*cli, '--out', str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while _checkpointed_frames(out) < 30 and time.monotonic() < deadline:  # past the restart
        assert proc.poll() is None, 'the run finished before it could be killed'
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    resumed = subprocess.run([*cli, '--out', str(out), '--resume'], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    report = json.loads((out / 'report.json').read_text())
    assert report['resumed_after_frames']['input_items_skipped'] > 0
    assert report['mount_from_frames'] == restart
    assert report['pose_placement']['mount_elevation_deg'] == restart['elevation_deg']
    assert (out / 'frames.csv').read_bytes() == (full / 'frames.csv').read_bytes()


def _checkpointed_frames(out) -> int:
    header = read_header(out / '.checkpoint' / 'state.pkl')
    return int(header['frames_consumed']) if header else 0
