"""`srmosaic evaluate` on a run with sr/: SR figures against the true ground, and the comparison figure.

A tiny raw flight whose camera sees 0.33 m per pixel of the 0.1 m/px world (16 frames of 160x120,
noise sigma 2/255) is simulated, processed with --sr (32-pixel tiles) and evaluated; SR must beat
the bicubic upsampling of mosaic.png on the true ground. Also unit checks of the quality figures.
"""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.sr.quality import edge_mask, overshoot, psnr, side_by_side, ssim


def test_psnr_ssim_known_values():
    rng = np.random.default_rng(3)
    a = rng.uniform(0.2, 0.8, (40, 50, 3))
    assert psnr(a, a + 0.01) == pytest.approx(40.0, abs=1e-6)        # MSE 1e-4
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-9)
    noisy = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    assert ssim(a, noisy) < ssim(a, np.clip(a + rng.normal(0, 0.01, a.shape), 0, 1)) < 1.0
    u8 = (a * 255 + 0.5).astype(np.uint8)
    assert psnr(u8, a) > 50.0   # uint8 is read as /255


def test_overshoot_sees_ringing_at_edges_only():
    step = np.zeros((32, 32))
    step[:, 16:] = 1.0
    ringing = step.copy()
    ringing[:, 14] = -0.1      # undershoot before the edge
    ringing[:, 17] = 1.1       # overshoot after it
    edges = edge_mask(step)
    assert overshoot(step, step) == 0.0
    assert overshoot(ringing, step, mask=edges) > overshoot(ringing, step) > 0.0
    assert overshoot(np.clip(ringing, 0, 1), step) == 0.0


def test_side_by_side_layout():
    imgs = [np.zeros((10, 12)), np.ones((10, 12, 3)), np.full((10, 12, 1), 0.5)]
    out = side_by_side(imgs, ['a', 'b', 'c'], zoom=2, gap=4, header=20)
    assert out.shape == (20 + 20, 3 * 24 + 2 * 4, 3) and out.dtype == np.uint8
    assert out[25, 30, 0] == 255 and out[25, 5, 0] == 0
    with pytest.raises(ValueError, match='one size'):
        side_by_side([np.zeros((4, 4)), np.zeros((5, 4))], ['a', 'b'])


@pytest.fixture(scope='module')
def sr_run(tmp_path_factory):
    from srmosaic_ros.config import pipeline_config
    from srmosaic_ros.app.process import process_input
    from srmosaic_ros.sim import SimConfig
    from srmosaic_ros.sim.flight import simulate
    from srmosaic_ros.sim.record import write_flight

    root = tmp_path_factory.mktemp('sr_eval')
    cfg = SimConfig(trajectory='line', frames=16, width=160, height=120, hfov_deg=30.0, heading_deg=90.0,
                    start_east_m=-130.0, start_north_m=-85.0, noise_sigma=2.0, seed=5)
    bag = write_flight(simulate(cfg), root / 'bag', transport='raw')
    out = root / 'out'
    config = pipeline_config({'sr_tiles.tile_size': 32, 'device': 'cpu', 'sr.device': 'cpu'})
    process_input(bag, out, config, sr_factor=2, progress=False)
    return out, bag


def test_evaluate_reports_sr_gain_over_bicubic(sr_run):
    from srmosaic_ros.app.evaluate import evaluate_dir

    out, bag = sr_run
    tiles = json.loads((out / 'sr' / 'tiles.json').read_text())
    assert len(tiles) >= 3
    fig = evaluate_dir(out, bag / 'ground_truth.json')
    sr = fig['sr']
    assert sr['tiles'] == len(tiles) and sr['factor'] == 2
    for t in sr['per_tile']:
        assert all(math.isfinite(t[k]) for k in ('psnr_sr', 'psnr_bicubic', 'ssim_sr', 'ssim_bicubic'))
        # the truth really lies under the tile: the baseline is close to it, not a misaligned guess
        assert t['psnr_bicubic'] > 30.0
    # the camera samples the ground 3.3x coarser than the world: SR recovers detail bicubic cannot
    assert sr['gain_db'] > 1.0, sr
    assert sr['gain_db_median'] > 0.5 and sr['ssim_sr'] > sr['ssim_bicubic']
    assert sr['gain_db'] == pytest.approx(sr['psnr_sr'] - sr['psnr_bicubic'])
    # the PSF chosen from the frames (sr.psf_ladder, by predicting held-out frames) beside the
    # simulated camera's, sqrt(0.7^2 + 1/12) px: the rung nearest it
    assert sr['psf_sigma_px'] == 0.7
    assert sr['psf_sigma_true_px'] == pytest.approx(0.757, abs=1e-3)
    report = json.loads((out / 'report.json').read_text())['sr']
    selection = report['psf_selection']
    assert selection['method'] == 'held_out_frames' and selection['predictions'] >= 3
    rms = dict(zip(selection['ladder'], selection['held_out_rms'], strict=True))
    assert min(rms, key=rms.get) == 0.7 and rms[0.2] > rms[0.7]
    # the report's iteration counts are the solver's (one history record per iteration)
    for t in report['per_tile']:
        cap = report['iterations_cap']
        assert 1 <= t['iterations'] <= cap
        assert (t['iterations'] == cap) == t['stop_reason'].startswith('iteration cap'), t


def test_evaluate_truth_misplaced_by_a_pixel_costs_psnr(sr_run):
    """The figures depend on where the truth is placed: shifting the true homographies by 1 world
    pixel must lower both PSNRs (guards against figures that ignore the geometry)."""
    from srmosaic_ros.app.evaluate import sr_figures
    from srmosaic_ros.io.mosaic_files import read_frames_csv
    from srmosaic_ros.sim import load_truth

    out, bag = sr_run
    truth = load_truth(bag / 'ground_truth.json')
    ok = [r for r in read_frames_csv(out / 'frames.csv') if r['ok']]
    by_stamp = {f.stamp_ns: f for f in truth.frames}
    good = sr_figures(out, truth, ok, by_stamp, compare=False)
    shift = np.array([[1.0, 0.0, 1.5], [0.0, 1.0, 1.5], [0.0, 0.0, 1.0]])
    moved = {k: type(f)(**{**f.__dict__, 'world_px_H_frame': shift @ f.world_px_H_frame}) for k, f in by_stamp.items()}
    bad = sr_figures(out, truth, ok, moved, compare=False)
    assert bad['psnr_bicubic'] < good['psnr_bicubic'] - 1.0
    assert bad['psnr_sr'] < good['psnr_sr'] - 1.0


def test_compare_figure_written(sr_run):
    from srmosaic_ros.app.evaluate import evaluate_dir

    out, bag = sr_run
    fig = evaluate_dir(out, bag / 'ground_truth.json')
    path = out / fig['sr']['compare']['file']
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    tile = next(t for t in json.loads((out / 'sr' / 'tiles.json').read_text())
                if t['file'] == fig['sr']['compare']['tile'])
    side = tile['width'] * tile['factor']
    zoom = max(1, round(384 / side))
    assert img is not None and img.shape[1] >= 3 * side * zoom and img.shape[0] > side * zoom
    # three panels of real content: none is blank
    body = img[img.shape[0] - side * zoom:]
    for i in range(3):
        panel = body[:, i * (side * zoom + 6):i * (side * zoom + 6) + side * zoom]
        assert panel.std() > 3.0
