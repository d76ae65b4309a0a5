"""Throughput machinery: per-stage times, the overlapped run (read-ahead, painter thread) giving the
sequential run's outputs, registration on a pyramid level, painting at a coarser mosaic sampling."""
from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest
import torch

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.device import cores_left_for_torch
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.registration import RegistrationConfig, make_registrar
from srmosaic_ros.core.registration.pyramid import PyramidRegistrar, full_from_level, level_for_width, to_full
from srmosaic_ros.core.registration.registrar import Registration
from srmosaic_ros.core.serial_worker import SerialWorker
from srmosaic_ros.core.stage_clock import STAGES, StageClock
from srmosaic_ros.core.types import Frame
from srmosaic_ros.errors import ConfigError
from srmosaic_ros.io.mosaic_files import read_frames_csv
from srmosaic_ros.io.prefetch import prefetched
from srmosaic_ros.app.process import process_input
from srmosaic_ros.pipeline import Pipeline

from imagery import similarity, translation, view, world_rgb
from repo_paths import REPO

ROOT = REPO
DEMO = ROOT / 'bags' / 'demo'


# -- stage clock -------------------------------------------------------------------------------

def test_stage_clock_sums_per_frame_and_spreads_outputs():
    clock = StageClock()
    for ms in (2.0, 4.0, 6.0):
        clock.add('describe', ms / 1e3)
        clock.add('paint', 1e-3)
        clock.end_frame()
    clock.add('outputs', 0.3)
    s = clock.summary()
    assert s['describe']['median_ms'] == pytest.approx(4.0)
    assert s['describe']['total_s'] == pytest.approx(0.012)
    assert s['outputs']['median_ms'] == pytest.approx(100.0)  # 0.3 s over 3 frames
    assert s['total']['median_ms'] == pytest.approx(4.0 + 1.0 + 100.0)
    assert 'register' not in s  # never ran
    assert clock.per_frame_ms('describe') == pytest.approx([2.0, 4.0, 6.0])
    with pytest.raises(ValueError, match='unknown stage'), clock.stage('decoding'):
        pass


# -- overlapped run = sequential run -------------------------------------------------------------

@pytest.fixture
def one_torch_thread():
    """Both runs with one torch thread: reductions over another thread count differ in the last bits."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def test_overlapped_run_writes_the_sequential_outputs(tmp_path, one_torch_thread):
    """Read-ahead and the painter thread change nothing in what is written: frames.csv byte for byte,
    the mosaic pixel for pixel; report.json gains the stage times. Frames are registered on the
    pyramid level 1 and painted at half their sampling (max_width 320 of 640 px frames)."""
    config = pipeline_config({'registration.max_width': 320, 'mosaic.max_width': 320})
    seq = process_input(DEMO, tmp_path / 'seq', config, progress=False, overlap=False)
    ovl = process_input(DEMO, tmp_path / 'ovl', config, progress=False, overlap=True)
    assert (tmp_path / 'seq' / 'frames.csv').read_bytes() == (tmp_path / 'ovl' / 'frames.csv').read_bytes()
    import rasterio

    with rasterio.open(tmp_path / 'seq' / 'mosaic.tif') as a, rasterio.open(tmp_path / 'ovl' / 'mosaic.tif') as b:
        assert a.transform == b.transform
        assert np.array_equal(a.read(), b.read())
    assert seq['frames_registered'] == ovl['frames_registered'] == 60
    # painted at half the frames' sampling: a 640 px frame covers about 320 mosaic pixels
    rows = read_frames_csv(tmp_path / 'ovl' / 'frames.csv')
    h = rows[0]['mosaic_H_frame']
    assert abs(np.linalg.det(h[:2, :2] / h[2, 2])) ** 0.5 == pytest.approx(0.5, rel=0.1)
    stages = json.loads((tmp_path / 'ovl' / 'report.json').read_text())['stage_times']
    for name in ('decode', 'describe', 'register', 'paint', 'outputs', 'total'):
        assert stages[name]['frames'] == 60 and stages[name]['total_s'] > 0
    # the painter's time counts too: the stages add up to the run's time, or more where they overlapped
    assert 0.5 * ovl['wall_s'] <= stages['total']['total_s'] <= 2.5 * ovl['wall_s']
    assert set(stages) <= {*STAGES, 'total'}


def test_prefetched_keeps_order_raises_in_place_and_stops_when_closed():
    assert list(prefetched(range(100), depth=3)) == list(range(100))

    def broken():
        yield 1
        yield 2
        raise OSError('damaged file')

    got = []
    with pytest.raises(OSError, match='damaged file'):
        for item in prefetched(broken(), depth=4):
            got.append(item)
    assert got == [1, 2]

    read = []

    def endless():
        i = 0
        while True:
            read.append(i)
            yield i
            i += 1

    gen = prefetched(endless(), depth=2)
    assert next(gen) == 0
    gen.close()
    n = len(read)
    time.sleep(0.3)
    assert len(read) <= n + 1  # the reader stopped
    assert not any(t.name == 'srmosaic-read-ahead' and t.is_alive() for t in threading.enumerate())


def test_serial_worker_runs_in_order_and_raises_in_the_caller():
    out = []
    worker = SerialWorker(depth=2)
    for i in range(20):
        worker.submit(lambda i=i: out.append(i))
    worker.wait()
    assert out == list(range(20))

    def fail():
        raise RuntimeError('paint failed')

    worker.submit(fail)
    with pytest.raises(RuntimeError, match='paint failed'):
        worker.wait()
    worker.submit(lambda: out.append('after'))
    worker.close()
    assert out[-1] == 'after'


def test_cores_left_for_torch_restores_the_thread_count():
    before = torch.get_num_threads()
    with cores_left_for_torch(1) as n:
        assert 1 <= n <= before
        assert torch.get_num_threads() == n
    assert torch.get_num_threads() == before


# -- registration on a pyramid level -----------------------------------------------------------------

def test_level_for_width():
    assert [level_for_width(w, 1280) for w in (640, 1280, 1920, 2560, 3840, 7680)] == [0, 0, 1, 1, 2, 3]
    assert level_for_width(3840, 0) == 0


def test_to_full_maps_homography_rms_and_covariance():
    """A level-1 registration mapped to full size: H by conjugation, RMS doubled, the covariance by
    the Jacobian (checked against the sample covariance of conjugated random homographies)."""
    rng = np.random.default_rng(3)
    h_level = np.array([[1.01, 0.02, 5.0], [-0.015, 0.99, -3.0], [1e-5, -2e-5, 1.0]])
    cov = np.diag([1e-6, 1e-6, 1e-2, 1e-6, 1e-6, 1e-2, 1e-11, 1e-11])
    reg = to_full(Registration(True, h_level, inliers=50, rms_px=0.2, covariance=cov), 1)
    t = full_from_level(1)
    expect = t @ h_level @ np.linalg.inv(t)
    np.testing.assert_allclose(reg.prev_H_cur, expect / expect[2, 2], rtol=1e-12, atol=1e-12)
    assert reg.rms_px == pytest.approx(0.4)
    samples = []
    for d in rng.multivariate_normal(np.zeros(8), cov, size=20000):
        hs = np.append(h_level.ravel()[:8] + d, 1.0).reshape(3, 3)
        hf = t @ hs @ np.linalg.inv(t)
        samples.append((hf / hf[2, 2]).ravel()[:8])
    sample_cov = np.cov(np.array(samples).T)
    np.testing.assert_allclose(np.sqrt(np.diag(reg.covariance)), np.sqrt(np.diag(sample_cov)), rtol=0.05)


def test_pyramid_registrar_registers_a_1920_frame_pair_on_level_1():
    """1920 x 1080 frames (the orthophoto at full scale) registered on the 960 x 540 level: the full-size
    homography within 0.1 px at the corners, as the full-size registration."""
    world = world_rgb(1.0)
    w, h = 1920, 1080
    a = translation(20, 200)
    b = a @ similarity(2.0, 1.02, 31.0, -17.0, w / 2, h / 2)
    fa, fb = view(a, w, h, noise=2.0, seed=1, image=world), view(b, w, h, noise=2.0, seed=2, image=world)
    truth = np.linalg.inv(a) @ b
    config = RegistrationConfig()
    pyr = PyramidRegistrar(make_registrar(config, 'cpu'), 1280)
    fa_l, fb_l = pyr.describe(fa), pyr.describe(fb)
    assert fa_l.level == 1
    reg = pyr.register(fa_l, fb_l)
    assert reg.ok, reg.reason
    assert corner_error_px(reg.prev_H_cur, truth, w, h) < 0.1
    assert reg.covariance is not None and reg.extras['level'] == 1.0


def test_max_width_settings_are_checked():
    with pytest.raises(ConfigError, match='max_width'):
        pipeline_config({'mosaic.max_width': 10})
    with pytest.raises(ConfigError, match='max_width'):
        pipeline_config({'registration.max_width': 3})


def test_wide_frames_are_painted_at_max_width():
    """Without georeferencing a segment's plane is its first frame's pixels scaled to mosaic.max_width:
    a 1920 px frame covers 1280 mosaic pixels (and 1920 with max_width 0)."""
    world = world_rgb(1.0)
    w, h = 1920, 1080
    frames = [Frame(i * 40_000_000, view(translation(20 + 12 * i, 200), w, h, noise=2.0, seed=i, image=world))
              for i in range(3)]
    for max_width, side in ((1280, 1280), (0, 1920)):
        pipe = Pipeline(pipeline_config({'mosaic.max_width': max_width}))
        for f in frames:
            pipe.feed_frame(f)
        res = pipe.finish()
        assert all(r.painted for r in res.records)
        x0, y0, x1, y1 = res.segments[0].canvas.bounds()
        assert x1 - x0 == pytest.approx(side + 24 * side / w, abs=4)


def test_frames_much_finer_than_the_mosaic_are_averaged_down_first():
    """area_reduce: k x k block means on the integer pixels, the homography following the block
    centres; area_factor: k only where every block still covers a mosaic pixel or more."""
    from srmosaic_ros.core.mosaic.minify import area_factor, area_reduce, finest_stretch

    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (30, 45, 3), dtype=np.uint8)
    small, m = area_reduce(image, np.eye(3), 3)
    assert small.shape == (10, 15, 3)
    block = image[6:9, 12:15].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(small[2, 4], block, atol=0.51)  # rounded to uint8
    np.testing.assert_allclose(m @ [4.0, 2.0, 1.0], [13.0, 7.0, 1.0])  # the block's centre pixel
    assert area_factor(1.0) == area_factor(0.6) == 1 and area_factor(0.5) == 2 and area_factor(1 / 3) == 3
    assert finest_stretch(np.diag([0.25, 0.25, 1.0]), 100, 80) == pytest.approx(0.25)


def test_uint8_frames_convert_for_the_canvas_as_to_float01():
    """_as_canvas_image converts uint8 frames into a reused scratch array: to_float01's values for
    every grey level, the first frame's channel count, a new size taking the place of the old."""
    from srmosaic_ros.core.image_ops import to_float01

    pipe = Pipeline(pipeline_config({}))
    levels = np.arange(256, dtype=np.uint8).reshape(16, 16)
    rgb = np.stack([levels, levels[::-1], levels.T], axis=-1)
    out = pipe.painter.input.as_canvas_image(rgb)
    assert out.dtype == np.float32 and out.shape == (16, 16, 3) and out.flags.c_contiguous
    np.testing.assert_array_equal(out, to_float01(rgb))
    big = np.random.default_rng(0).integers(0, 256, (90, 120, 3), dtype=np.uint8)
    np.testing.assert_array_equal(pipe.painter.input.as_canvas_image(big), to_float01(big))
    np.testing.assert_array_equal(pipe.painter.input.as_canvas_image(levels), np.repeat(to_float01(levels)[..., None], 3, axis=2))
    floats = to_float01(big)
    np.testing.assert_array_equal(pipe.painter.input.as_canvas_image(floats), floats)


def test_canvas_float_conversion_is_the_same_with_or_without_gains():
    """The canvas's uint8 -> float32 conversion (numpy's scalar product without gains, OpenCV's
    per-channel one with them) gives to_float01's values for every grey level, gains of 1 included."""
    from srmosaic_ros.core.image_ops import to_float01
    from srmosaic_ros.core.mosaic.paint_ops import to_float as _to_float

    levels = np.arange(256, dtype=np.uint8).reshape(16, 16)
    rgb = np.stack([levels, levels[::-1], levels.T], axis=-1)
    plain = _to_float(rgb, None)
    np.testing.assert_array_equal(plain, to_float01(rgb))
    np.testing.assert_array_equal(_to_float(rgb, np.ones(3, np.float32)), plain)
    out = np.full(rgb.shape, np.nan, np.float32)
    assert _to_float(rgb, None, out) is out and np.array_equal(out, plain)


# -- paint thinning ----------------------------------------------------------------------------------

def test_thinned_painting_keeps_the_records_and_the_mosaic(tmp_path, one_torch_thread):
    """mosaic.paint_stride 3 (the default) against 1 on the demo flight (60 frames), every frame
    within paint_shift_px 64 of the last painted (the demo's frames move 10 to 20 px: with the
    default 16 few are held back): the same frames.csv; two frames in three held back (with the
    demo's gusts most then painted where they reach beyond their neighbours); the same coverage but for
    slivers at the swath's very edge (the count: docs/lab-notes.md, paint thinning),
    and nearly the same pixels (a best view from a frame or two away)."""
    import cv2

    every = process_input(DEMO, tmp_path / 'every', pipeline_config({'mosaic.paint_stride': 1}), progress=False)
    thin = process_input(DEMO, tmp_path / 'thin', pipeline_config({'mosaic.paint_shift_px': 64.0}), progress=False)
    assert (tmp_path / 'every' / 'frames.csv').read_bytes() == (tmp_path / 'thin' / 'frames.csv').read_bytes()
    assert every['frames_thinned'] == every['frames_painted_in_part'] == 0
    assert thin['frames_thinned'] + thin['frames_painted_in_part'] >= 35
    a = cv2.imread(str(tmp_path / 'every' / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    b = cv2.imread(str(tmp_path / 'thin' / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    assert a.shape == b.shape
    cov_a, cov_b = a[..., 3] > 0, b[..., 3] > 0
    lost = cov_a & ~cov_b
    depth = cv2.distanceTransform(cov_a.view(np.uint8), cv2.DIST_L2, 5)
    assert (depth[lost] <= 4.5).all()  # nothing lost but slivers at the swath's very edge
    assert lost.sum() < 0.0005 * cov_a.sum() and not (cov_b & ~cov_a).any()
    inner = depth > 4.5
    diff = np.abs(a[..., :3].astype(float) - b[..., :3])[inner]
    assert 10 * np.log10(255.0**2 / np.mean(diff**2)) > 35.0


def test_paint_thinning_settings_are_checked():
    with pytest.raises(ConfigError, match='paint_stride'):
        pipeline_config({'mosaic.paint_stride': 0})
    with pytest.raises(ConfigError, match='paint_shift_px'):
        pipeline_config({'mosaic.paint_shift_px': -1.0})
