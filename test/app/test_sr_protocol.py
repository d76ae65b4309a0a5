"""The real-video SR protocol (app/sr_protocol.py) on a small simulated H.264 video with traffic.

The simulator knows where the cars are, so the static-pixel mask can be checked; the leave-one-out
is checked by spoiling the truth frame in the LR input; a sub-pixel shift planted in an SR tile must
show in the protocol's shift figure and its PSNR.
"""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from srmosaic_ros.app import sr_protocol
from srmosaic_ros.app.evaluate import tile_grid_H
from srmosaic_ros.app.process import process_input
from srmosaic_ros.app.sr_protocol import MOVING_THRESHOLD, halve_video, luma255, score_sr_run
from srmosaic_ros.cli import main
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.io.mosaic_files import read_frames_csv
from srmosaic_ros.io.video import VideoReader, write_video
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.ortho_error import ortho_in_plane
from srmosaic_ros.sim.traffic import vehicle_mask

SIM = SimConfig(rate_hz=25.0, speed_m_s=3.0, frames=12, altitude_m=80.0, seed=0, vehicles=6, width=256, height=192)


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    """(flight, original video, run dir, protocol result, tile images): the flight encoded at CRF 18,
    halved by the protocol, processed with --sr on 32-px tiles, scored."""
    work = tmp_path_factory.mktemp('protocol')
    flight = simulate(SIM)
    original = work / 'flight.mp4'
    write_video(original, (f.image for f in flight.frames), fps=SIM.rate_hz, crf=18)
    halved = work / 'halved.mp4'
    assert halve_video(original, halved) == SIM.frames
    out = work / 'run'
    process_input(halved, out, pipeline_config({'sr_tiles.tile_size': 32}), sr_factor=2, progress=False)
    images: dict = {}
    result = score_sr_run(out, original, images_out=images)
    return flight, original, out, result, images


def test_every_tile_is_scored_three_ways_on_static_pixels(run) -> None:
    _, _, out, result, _ = run
    tiles = json.loads((out / 'sr' / 'tiles.json').read_text())
    assert result['tiles'] == len(tiles) >= 6
    for key in ('mosaic', 'frame', 'loo', 'loo_sr_only'):
        s = result['summary'][key]
        assert s['tiles'] == len(tiles) and 20 < s['psnr'] < 60 and 0 < s['ssim'] <= 1 and 0 < s['ssim_baseline'] <= 1
    # SR beats the bicubic of the mosaic (which painted the frames through one more resampling)
    assert result['summary']['mosaic']['gain_db'] > 0
    for t in result['per_tile']:
        assert t['truth_frame'] in t['frames'] and t['truth_frame'] not in t['frames_without_truth']
        assert t['other_frame'] == t['frames_without_truth'][0] and 0 <= t['masked_fraction'] < 0.6
    on_disk = json.loads((out / 'sr' / 'protocol.json').read_text())
    assert on_disk['summary'] == result['summary']
    sheet = cv2.imread(str(out / result['compare']))
    assert sheet is not None and sheet.shape[0] > 4 * 64 and sheet.std() > 10


def test_the_leave_one_out_never_reads_the_truth_frame(run, monkeypatch) -> None:
    """The truth frame of each tile spoiled (noise) in the LR input: the tiles solved without it are
    unchanged to the bit, while the baseline (b) that reads it changes."""
    _, original, out, result, images = run
    first = result['per_tile'][:2]
    halved = str(json.loads((out / 'report.json').read_text())['input'])
    spoil = {t['truth_frame'] for t in first}
    read = sr_protocol._read_frames

    def spoiled(path, wanted):
        frames = read(path, wanted)
        if str(path) == halved:
            rng = np.random.default_rng(0)
            for k in spoil & set(frames):
                frames[k] = rng.integers(0, 256, frames[k].shape, dtype=np.uint8)
        return frames

    monkeypatch.setattr(sr_protocol, '_read_frames', spoiled)
    again: dict = {}
    score_sr_run(out, original, images_out=again, max_tiles=2, compare=False)
    for t in first:
        before, after = images[t['file']], again[t['file']]
        np.testing.assert_array_equal(after['loo_sr'], before['loo_sr'])
        np.testing.assert_array_equal(after['other_bicubic'], before['other_bicubic'])
        assert np.abs(after['frame_bicubic'] - before['frame_bicubic']).mean() > 20


def test_the_moving_mask_covers_the_simulated_cars(run) -> None:
    """Where the simulator put a car in a tile's truth frame and it shows (it differs from the ground
    without cars by more than twice the mask's threshold: a grey car on a grey road does not), the
    mask is set; and it leaves most of the tiles to the score."""
    flight, _, out, result, images = run
    truth = flight.truth
    rows = read_frames_csv(out / 'frames.csv')
    entries = {e['file']: e for e in json.loads((out / 'sr' / 'tiles.json').read_text())}
    hr_H_lr = np.array([[2.0, 0, 0.5], [0, 2.0, 0.5], [0, 0, 1]])
    car_px = covered = 0
    for t in result['per_tile']:
        k = t['truth_frame']
        cars = vehicle_mask(truth.vehicles, truth.time_s(k), truth.frames[k].world_px_H_frame, (SIM.width, SIM.height))
        ground = 255.0 * luma255(ortho_in_plane(flight.world.image, truth.frames[k].world_px_H_frame, (SIM.width, SIM.height)))
        cars &= np.abs(luma255(flight.frames[k].image) - ground) > 2 * MOVING_THRESHOLD
        frame_H_grid = hr_H_lr @ np.linalg.inv(rows[k]['mosaic_H_frame']) @ tile_grid_H(entries[t['file']])
        shape = images[t['file']]['truth'].shape
        on_tile = cv2.warpPerspective(cars.astype(np.uint8), frame_H_grid, shape[::-1],
                                      flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP) > 0
        car_px += int(on_tile.sum())
        covered += int((on_tile & images[t['file']]['moving']).sum())
    assert car_px > 150, 'no car shows in a tile: the test flight lost its traffic'
    assert covered >= 0.9 * car_px
    assert result['masked_fraction'] < 0.3


def test_a_planted_subpixel_shift_is_caught(run, tmp_path) -> None:
    """An SR tile shifted by half an HR pixel: the protocol's shift figure moves by that much and its PSNR drops."""
    _, original, out, result, _ = run
    copy = tmp_path / 'run'
    shutil.copytree(out, copy)
    first = result['per_tile'][0]
    path = copy / 'sr' / first['file']
    tile = cv2.imread(str(path), cv2.IMREAD_COLOR)
    shifted = cv2.warpAffine(tile, np.float32([[1, 0, 0.5], [0, 1, 0]]), tile.shape[1::-1], flags=cv2.INTER_CUBIC,
                             borderMode=cv2.BORDER_REPLICATE)
    cv2.imwrite(str(path), shifted)
    again = score_sr_run(copy, original, loo=False, compare=False, max_tiles=1)['per_tile'][0]
    assert again['sr_shift_px'][0] - first['sr_shift_px'][0] == pytest.approx(0.5, abs=0.15)
    assert abs(again['sr_shift_px'][1] - first['sr_shift_px'][1]) < 0.1
    assert again['sse_sr'] > 1.1 * first['sse_sr']


def test_evaluate_original_refuses_a_video_that_is_not_the_original(run, capsys) -> None:
    _, original, out, _, _ = run
    halved = json.loads((out / 'report.json').read_text())['input']
    assert main(['evaluate', str(out), '--original', str(halved)]) == 2
    err = capsys.readouterr().err
    assert 'not its halved copy' in err and 'pass the video the input was halved from' in err
    assert VideoReader(original).width == 2 * VideoReader(halved).width
