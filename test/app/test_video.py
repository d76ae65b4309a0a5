"""Video input: frame selection modes, the growing-mosaic video, and bad video files."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from srmosaic_ros.errors import InputError
from srmosaic_ros.io.mosaic_files import read_frames_csv
from srmosaic_ros.io.telemetry_csv import read_telemetry_csv
from srmosaic_ros.io.video import VideoReader, parse_selection, write_video
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.cli import _write_video_and_sidecar
from srmosaic_ros.sim.truth import save_truth
from cli_runner import run_cli
from repo_paths import REPO

GOP = 12
N = 48


@pytest.fixture(scope='module')
def flight_video(tmp_path_factory):
    root = tmp_path_factory.mktemp('video')
    flight = simulate(SimConfig(frames=N, width=320, height=240, seed=3))
    video = root / 'flight.mp4'
    _write_video_and_sidecar(flight, video, GOP)
    save_truth(flight.truth, root / 'ground_truth.json')
    return flight, video, root / 'ground_truth.json'


ROOT = REPO


def srmosaic_process(*args: str) -> subprocess.CompletedProcess:
    """A real `srmosaic` process, as a user runs it."""
    return subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', *args], capture_output=True, text=True,
                          timeout=600)


srmosaic = run_cli  # the same command in this process (test/cli_runner.py)


@pytest.mark.parametrize(('select', 'expected'), [('all', N), ('every:3', N // 3), ('iframes', N // GOP)])
def test_selection_counts_and_stamps(flight_video, select, expected):
    flight, video, _ = flight_video
    frames = list(VideoReader(video, selection=parse_selection(select)))
    assert len(frames) == expected
    step = {'all': 1, 'every:3': 3, 'iframes': GOP}[select]
    period_ns = 1e9 / flight.config.rate_hz
    assert [f.stamp_ns for f in frames] == [round(i * step * period_ns) for i in range(expected)]
    if select == 'iframes':  # I-frames are the frames at multiples of the GOP: compare pixels
        for i, f in enumerate(frames):
            ref = flight.frames[i * GOP].image.astype(float)
            assert np.abs(f.image.astype(float) - ref).mean() < 4.0


def test_overlap_selection_keeps_overlap_near_threshold(flight_video):
    flight, video, _ = flight_video
    frames = list(VideoReader(video, selection=parse_selection('overlap:0.7')))
    assert 2 < len(frames) < N
    # True overlap between successive selected frames, from the ground truth (translation part).
    truth = {f.stamp_ns - flight.truth.frames[0].stamp_ns: f for f in flight.truth.frames}
    for a, b in zip(frames, frames[1:]):
        H = np.linalg.inv(truth[a.stamp_ns].world_px_H_frame) @ truth[b.stamp_ns].world_px_H_frame
        c = H @ np.array([159.5, 119.5, 1.0])
        dx, dy = np.abs(c[:2] / c[2] - (159.5, 119.5))
        overlap = max(0, 320 - dx) * max(0, 240 - dy) / (320 * 240)
        assert 0.55 < overlap < 0.85


def test_parse_selection_refuses_garbage():
    for text in ('every:0', 'overlap:1.5', 'iframe', 'all:3', 'every:x'):
        with pytest.raises(InputError, match='--select'):
            parse_selection(text)


def test_process_video_iframes_with_telemetry_and_mosaic_video(flight_video, tmp_path):
    _, video, truth = flight_video
    out = tmp_path / 'out'
    run = srmosaic('process', str(video), '--out', str(out), '--select', 'iframes', '--hfov', '60',
                   '--telemetry', str(video.with_suffix('.csv')), '--mosaic-video', '--no-progress')
    assert run.returncode == 0, run.stderr
    rows = read_frames_csv(out / 'frames.csv')
    assert [r['stamp_ns'] for r in rows] == [round(i * GOP * 0.25e9) for i in range(N // GOP)]
    report = json.loads((out / 'report.json').read_text())
    assert report['input_kind'] == 'video' and report['video']['frames_selected'] == N // GOP
    assert report['telemetry']['fixes'] > 0
    assert report['mosaic_video_frames'] == report['frames_registered']
    assert (out / 'mosaic.mp4').stat().st_size > 1000
    ev = srmosaic('evaluate', str(out), '--truth', str(truth), '--json')
    assert ev.returncode == 0, ev.stderr
    assert json.loads(ev.stdout)['corner_error_mean_px'] < 2.0


def test_empty_video_is_a_clear_error(tmp_path):
    empty = tmp_path / 'empty.mp4'
    empty.write_bytes(b'')
    run = srmosaic('process', str(empty), '--out', str(tmp_path / 'out'))
    assert run.returncode == 2 and 'empty' in run.stderr and 'Traceback' not in run.stderr


def test_garbage_video_is_a_clear_error(tmp_path):
    bad = tmp_path / 'bad.mp4'
    bad.write_bytes(np.random.default_rng(0).integers(0, 255, 20000, dtype=np.uint8).tobytes())
    run = srmosaic('process', str(bad), '--out', str(tmp_path / 'out'))
    assert run.returncode == 2 and 'Traceback' not in run.stderr
    assert 'bad.mp4' in run.stderr


def test_truncated_video_keeps_what_was_processed(flight_video, tmp_path):
    _, video, _ = flight_video
    cut = tmp_path / 'cut.ts'
    # MPEG-TS survives truncation (no index at the end): write one, cut it in the middle.
    write_video(cut, (f.image for f in flight_video[0].frames), fps=4.0, gop=GOP)
    data = cut.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    out = tmp_path / 'out'
    run = srmosaic('process', str(cut), '--out', str(out), '--no-progress')
    assert 'Traceback' not in run.stderr
    rows = read_frames_csv(out / 'frames.csv')
    assert 5 < len(rows) < N  # the frames before the cut were processed and written
    if run.returncode != 0:  # the decoder may also just stop at the cut; either way nothing is lost
        assert 'damaged' in run.stderr or 'truncated' in run.stderr


def test_a_video_cut_short_says_so(flight_video, tmp_path):
    """An MKV cut at 60 % decodes cleanly up to the cut and used to pass for a whole file: the run
    now says where it ended against the duration the header declares (stderr and report.json)."""
    whole = tmp_path / 'whole.mkv'
    write_video(whole, (f.image for f in flight_video[0].frames), fps=4.0, gop=GOP)
    cut = tmp_path / 'cut.mkv'
    data = whole.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    run = srmosaic('process', str(cut), '--out', str(tmp_path / 'out'), '--no-progress')
    assert run.returncode == 0 and 'Traceback' not in run.stderr, run.stderr
    assert 'cut.mkv ended after' in run.stderr and 'cut short' in run.stderr, run.stderr
    video = json.loads((tmp_path / 'out' / 'report.json').read_text())['video']
    assert 'cut short' in video['ended_early'] and video['frames_decoded'] < N
    run = srmosaic('process', str(whole), '--out', str(tmp_path / 'whole_out'), '--no-progress')
    assert run.returncode == 0 and 'cut short' not in run.stderr, run.stderr
    assert 'ended_early' not in json.loads((tmp_path / 'whole_out' / 'report.json').read_text())['video']


def _size_change_video(flight, tmp_path: Path) -> Path:
    """12 frames of the flight, then 12 at half size, as one MPEG-TS."""
    a, b = tmp_path / 'a.ts', tmp_path / 'b.ts'
    write_video(a, (f.image for f in flight.frames[:12]), fps=4.0, gop=GOP)
    write_video(b, (f.image[::2, ::2] for f in flight.frames[12:24]), fps=4.0, gop=GOP)
    joined = tmp_path / 'joined.ts'
    joined.write_bytes(a.read_bytes() + b.read_bytes())
    return joined


def test_size_change_mid_stream_stops_with_message_and_keeps_frames(flight_video, tmp_path):
    flight = flight_video[0]
    joined = _size_change_video(flight, tmp_path)
    out = tmp_path / 'out'
    run = srmosaic('process', str(joined), '--out', str(out), '--no-progress')
    assert run.returncode == 2, run.stdout + run.stderr
    assert '160x120' in run.stderr and 'Traceback' not in run.stderr
    assert len(read_frames_csv(out / 'frames.csv')) == 12
    assert 'error' in json.loads((out / 'report.json').read_text())


def test_video_options_refused_for_bags(tmp_path):
    demo = REPO / 'bags' / 'demo'
    run = srmosaic('process', str(demo), '--out', str(tmp_path / 'out'), '--select', 'iframes')
    assert run.returncode == 2 and 'video input' in run.stderr


def test_telemetry_csv_errors(tmp_path):
    bad = tmp_path / 't.csv'
    bad.write_text('time,lat\n0,1\n')
    with pytest.raises(InputError, match='lacks columns'):
        read_telemetry_csv(bad)
    bad.write_text('time_s,latitude,longitude,altitude,roll,pitch,yaw\n0,x,1,1,0,0,0\n')
    with pytest.raises(InputError, match='line 2'):
        read_telemetry_csv(bad)


def test_video_with_telemetry_writes_tiled_mosaic_tif_and_matching_png(flight_video, tmp_path):
    """End to end through process_input: mosaic.tif tiled (512 px) with the pixels of mosaic.png, no
    temporary files left behind."""
    import cv2
    import rasterio

    from srmosaic_ros.config import pipeline_config
    from srmosaic_ros.app.process import process_input

    _, video, _ = flight_video
    out = tmp_path / 'out'
    report = process_input(video, out, pipeline_config(), select='every:4', hfov_deg=60.0,
                           telemetry_csv=video.with_suffix('.csv'), progress=False)
    assert report['georeferenced'] is not None
    png = cv2.cvtColor(cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA)
    with rasterio.open(out / 'mosaic.tif') as ds:
        assert ds.profile['tiled'] and ds.block_shapes[0] == (512, 512)
        np.testing.assert_array_equal(ds.read().transpose(1, 2, 0), png)
    assert not [p.name for p in out.iterdir() if p.name.startswith('.')]


def test_video_with_a_flight_log_but_no_camera_model_is_georeferenced_by_its_geotags(flight_video, tmp_path):
    """No --hfov or --camera: the fixes of the flight log, interpolated at the frames, place the
    mosaic (core/georef/geotag_fit.py); evaluate measures it against the truth."""
    _, video, truth = flight_video
    out = tmp_path / 'out'
    run = srmosaic('process', str(video), '--out', str(out), '--telemetry', str(video.with_suffix('.csv')),
                   '--no-progress')
    assert run.returncode == 0, run.stderr
    report = json.loads((out / 'report.json').read_text())
    assert report['georeferenced']['method'] == 'geotags'
    # the log's attitudes take the camera's tilt (2 degree gusts, no gimbal) out of the geotags
    assert report['georeferenced']['tilt_corrected']
    assert report['georeferenced']['height_above_ground_m'] == pytest.approx(100.0, rel=0.15)
    assert report['georeferenced']['frames_used'] >= 0.9 * N
    assert (out / 'mosaic.tif').is_file() and not (out / 'poses.csv').exists()
    ev = srmosaic('evaluate', str(out), '--truth', str(truth), '--json')
    assert ev.returncode == 0, ev.stderr
    figures = json.loads(ev.stdout)
    print('georef error of mosaic points:', figures['georef_error_rms_m'], figures['georef_error_max_m'])
    assert figures['georef_error_rms_m'] < 4.5  # measured 3.1 m (12.7 m without the tilt correction)


@pytest.mark.parametrize(('matrix', 'size', 'expect'), [
    ([0, 0, 0, 0, 0, 0, 0, 0, 1], (64, 48), 'fx and fy'),
    ([50, 0, 31.5, 0, 50, 23.5, 0, 0, 1], (0, 48), 'must be positive'),
    ([50, 0, 31.5, 0, 50, 23.5, 0, 0, 1], (64, 64), 'another aspect ratio'),
])
def test_bad_camera_files_are_refused(tmp_path: Path, matrix: list, size: tuple, expect: str) -> None:
    """A zero camera matrix used to end in a ZeroDivisionError traceback after the work; a
    calibration of another image size is refused (another aspect ratio) or scaled (the same)."""
    from srmosaic_ros.io.video import load_camera_yaml

    video = tmp_path / 'v.mp4'
    write_video(video, (np.full((48, 64, 3), 10 * i, np.uint8) for i in range(3)), fps=4.0, gop=2)
    cam = tmp_path / 'cam.yaml'
    cam.write_text(json.dumps({'image_width': size[0], 'image_height': size[1],
                               'camera_matrix': {'rows': 3, 'cols': 3, 'data': matrix}}))
    with pytest.raises(InputError, match=expect):
        VideoReader(video, camera=load_camera_yaml(cam))


def test_a_calibration_of_the_same_aspect_ratio_is_scaled_to_the_video(tmp_path: Path) -> None:
    from srmosaic_ros.io.video import load_camera_yaml

    video = tmp_path / 'v.mp4'
    write_video(video, (np.full((48, 64, 3), 10 * i, np.uint8) for i in range(3)), fps=4.0, gop=2)
    cam = tmp_path / 'cam.yaml'
    cam.write_text(json.dumps({'image_width': 128, 'image_height': 96,
                               'camera_matrix': {'rows': 3, 'cols': 3, 'data': [100, 0, 63.5, 0, 100, 47.5, 0, 0, 1]}}))
    reader = VideoReader(video, camera=load_camera_yaml(cam))
    assert (reader.camera.width, reader.camera.height) == (64, 48)
    assert reader.camera.fx == pytest.approx(50.0) and reader.camera.cx == pytest.approx(31.5)


def test_a_failed_run_keeps_the_earlier_complete_run(flight_video, tmp_path):
    """A good run, then a run that breaks mid-way into the same --out: the good run's files stay as
    they were (the partial run goes to failed_run/), not a mix of both runs."""
    flight = flight_video[0]
    joined = _size_change_video(flight, tmp_path)
    out = tmp_path / 'out'
    assert srmosaic('process', str(flight_video[1]), '--out', str(out), '--no-progress').returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    run = srmosaic('process', str(joined), '--out', str(out), '--no-progress')
    assert run.returncode == 2 and 'failed_run' in run.stderr, run.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert 'error' in json.loads((out / 'failed_run' / 'report.json').read_text())
    assert len(read_frames_csv(out / 'failed_run' / 'frames.csv')) == 12
    assert not [p.name for p in out.iterdir() if p.name.startswith('.')]


def test_a_second_writer_of_the_same_out_is_refused(tmp_path):
    from srmosaic_ros.io.output_dir import OutputTransaction

    out = tmp_path / 'out'
    (out / '.staging-99999999').mkdir(parents=True)  # what a run killed with kill -9 leaves
    with OutputTransaction(out):  # held by this process: the run must be another
        run = srmosaic_process('process', str(ROOT / 'bags' / 'demo'), '--out', str(out), '--no-progress')
    assert run.returncode == 2, run.stderr
    assert f'another srmosaic process (pid {os.getpid()}) is writing' in run.stderr
    assert sorted(p.name for p in out.iterdir()) == []


def test_evaluate_rereads_a_video_with_the_camera_its_run_was_given(flight_video, tmp_path):
    """`evaluate` compares the frames as the run saw them: undistorted with the --camera it recorded."""
    from srmosaic_ros.app.evaluate_real import evaluate_real

    _, video, _ = flight_video
    cam = tmp_path / 'cam.yaml'
    cam.write_text(json.dumps({'image_width': 320, 'image_height': 240, 'distortion_model': 'plumb_bob',
                               'camera_matrix': {'rows': 3, 'cols': 3, 'data': [277, 0, 159.5, 0, 277, 119.5, 0, 0, 1]},
                               'distortion_coefficients': {'rows': 1, 'cols': 5, 'data': [-0.3, 0.0, 0, 0, 0]}}))
    out = tmp_path / 'out'
    run = srmosaic('process', str(video), '--out', str(out), '--select', 'every:2', '--camera', str(cam), '--no-progress')
    assert run.returncode == 0, run.stderr
    report = json.loads((out / 'report.json').read_text())
    assert report['video']['camera'] == str(cam.resolve()) and report['config']['undistort'] is True
    recorded = evaluate_real(out, progress=False)
    given = evaluate_real(out, progress=False, camera_yaml=cam)
    assert recorded['ncc_median'] == pytest.approx(given['ncc_median'])
    raw = evaluate_real(out, progress=False, undistort=False)   # the frames as decoded: not what was painted
    assert recorded['ncc_median'] > raw['ncc_median'] + 0.02, (recorded['ncc_median'], raw['ncc_median'])
    cam.rename(tmp_path / 'moved.yaml')
    with pytest.raises(InputError, match='--camera'):
        evaluate_real(out, progress=False)
    ev = srmosaic('evaluate', str(out), '--camera', str(tmp_path / 'moved.yaml'), '--json', '--no-progress')
    assert ev.returncode == 0, ev.stderr
    assert json.loads(ev.stdout)['ncc_median'] == pytest.approx(recorded['ncc_median'])
