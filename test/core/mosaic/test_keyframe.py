"""Keyframe-to-mosaic registration: the view rendering, and an out-and-back flight whose chain
drifts (a registrar biased by 0.3 px per pair) closes on the return leg only with keyframes."""
from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from srmosaic_ros.app.process import keyframe_report
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.mosaic.canvas import TiledCanvas
from srmosaic_ros.core.mosaic.config import MosaicConfig
from srmosaic_ros.core.mosaic.keyframe import corner_shift_px, render_view
from srmosaic_ros.core.types import Frame
from srmosaic_ros.pipeline import Pipeline

from imagery import similarity, translation, view

W, H = 320, 240


def test_render_view_reproduces_a_painted_frame():
    img = view(translation(100, 80), W, H).astype(np.float32) / 255.0
    place = np.array([[0.98, -0.05, 40.0], [0.05, 0.98, -25.0], [1e-5, 0.0, 1.0]])
    canvas = TiledCanvas(3, tile_size=128)
    canvas.paint(img, place)
    got, covered = render_view(canvas, place, W, H)
    inner = np.zeros((H, W), bool)
    inner[3:-3, 3:-3] = True
    assert covered[inner].all()
    assert np.abs(got[inner] - img[inner]).mean() < 0.01   # bilinear there and back
    # Half the view beyond the painted area: coverage ~ 0.5, the rest filled flat.
    _, half = render_view(canvas, place @ translation(W / 2, 0), W, H)
    assert 0.45 < half.mean() < 0.55


def test_corner_shift():
    assert corner_shift_px(np.eye(3), translation(3, 4), W, H) == pytest.approx(5.0)


def test_config_refuses_bad_keyframe_settings():
    for bad in ({'keyframe_interval': -1}, {'keyframe_min_coverage': 0.0}, {'keyframe_max_correction_px': 0.0},
                {'keyframe_revisit_frames': 1.5}, {'keyframe_min_correction_px': -1.0},
                {'keyframe_min_correction_px': 50.0}):
        with pytest.raises(ValueError, match='keyframe'):
            MosaicConfig(**bad)
    for bad in (-1, 2.5, True, 1001):
        with pytest.raises(ValueError, match='revisit_spread_frames'):
            MosaicConfig(revisit_spread_frames=bad)


class DriftingRegistrar:
    """The pipeline's registrar with a bias per frame pair (cur -> prev shifted by `bias_px` in x, or
    the homography `bias`), as chained registration errors add up; registrations to the rendered
    mosaic (float32 views, not uint8 frames) are left unbiased, so keyframes see the truth of the mosaic."""

    def __init__(self, inner, bias_px: float = 0.0, bias: np.ndarray | None = None) -> None:
        self.inner, self.bias = inner, translation(bias_px, 0.0) if bias is None else bias
        self.frame_features: set[int] = set()

    def describe(self, image: np.ndarray):
        f = self.inner.describe(image)
        if image.dtype == np.uint8:
            self.frame_features.add(id(f))
        return f

    def register(self, prev, cur):
        reg = self.inner.register(prev, cur)
        if reg.ok and id(prev) in self.frame_features:
            reg = dataclasses.replace(reg, prev_H_cur=reg.prev_H_cur @ self.bias)
        return reg


def _out_and_back(keyframes: bool, spread: int = 0, decided: list | None = None,
                  **overrides: object) -> tuple[list[np.ndarray], list]:
    """20 frames east at 15 px/frame, 20 back (10 px south of the way out); returns the true
    world_H_frame and the records. ``decided``: (frames fed so far, record) as the pipeline returned them."""
    cfg = pipeline_config({'device': 'cpu', 'georef.enabled': False, 'mosaic.keyframe_interval': 5 if keyframes else 0,
                           'mosaic.keyframe_revisit_frames': 10, 'mosaic.revisit_spread_frames': spread, **overrides})
    pipe = Pipeline(cfg)
    pipe.registrar = DriftingRegistrar(pipe.registrar, 0.3)
    xs = [15.0 * k for k in range(21)] + [15.0 * (20 - k) for k in range(1, 21)]
    truths = [translation(300 + x, 250 + (10.0 if k > 20 else 0.0)) for k, x in enumerate(xs)]
    for k, t in enumerate(truths):
        out = pipe.feed(Frame(k * 100_000_000, view(t, W, H, noise=2, seed=k)))
        if decided is not None:
            decided += [(k + 1, r) for r in out]
    if decided is not None:
        decided += [(len(truths), r) for r in pipe.flush()]
        assert pipe.held_back == 0
    return truths, pipe.finish().records


def test_keyframes_close_an_out_and_back_flight():
    results = {}
    for keyframes in (False, True):
        truths, recs = _out_and_back(keyframes)
        assert all(r.painted and r.segment == 0 for r in recs)
        first = recs[0].seg_H_frame
        # Last frame (over the first one's ground): its placement relative to frame 0.
        est = np.linalg.inv(first) @ recs[-1].seg_H_frame
        true = np.linalg.inv(truths[0]) @ truths[-1]
        results[keyframes] = corner_error_px(est, true, W, H)
        tried = [r.keyframe for r in recs if r.keyframe is not None]
        if keyframes:
            applied = [k for k in tried if k.seg_H_frame is not None]
            assert applied and all(k.coverage >= 0.5 for k in applied)
            # Only on the return leg, where the flight revisits ground painted >= 10 frames before.
            assert min(r.index for r in recs if r.keyframe is not None) > 20
        else:
            assert not tried
    # 40 biased pairs: ~12 px of drift without keyframes; the return leg re-aligned with them.
    assert results[False] > 8.0
    assert results[True] < 0.25 * results[False], results


def _step_at(recs: list, truths: list[np.ndarray], k: int) -> float:
    """Error (px) of frame k's placement relative to frame k-1's, against the truth."""
    est = np.linalg.inv(recs[k - 1].seg_H_frame) @ recs[k].seg_H_frame
    return corner_error_px(est, np.linalg.inv(truths[k - 1]) @ truths[k], W, H)


def test_a_revisit_correction_spread_back_leaves_no_tear():
    """mosaic.revisit_spread_frames: the frames before a keyframe, painted that many frames late, take
    their share of its correction; painted at once, the whole correction is a step between two frames."""
    truths, at_once = _out_and_back(True)
    first = min(r.index for r in at_once if r.keyframe is not None and r.keyframe.seg_H_frame is not None)
    assert at_once[first].keyframe.shift_px > 3.0  # the drift the first revisit finds (0.3 px a pair)
    decided: list = []
    _, spread = _out_and_back(True, spread=5, decided=decided)
    assert spread[first].keyframe is not None and spread[first].keyframe.seg_H_frame is not None
    assert _step_at(at_once, truths, first) > 3.0
    assert _step_at(spread, truths, first) < 0.35 * _step_at(at_once, truths, first)
    # the five frames before it moved by growing shares (the earlier ones stayed where they were)
    moved = [r.corrected_px for r in spread[first - 5:first]]
    assert all(b > a > 0 for a, b in zip(moved, moved[1:], strict=False)), moved
    assert all(r.corrected_px == 0 for r in spread[:first - 5])
    # every record decided once, painted, and no earlier than 5 frames after its own
    assert sorted(r.index for _, r in decided) == list(range(len(truths)))
    assert all(r.painted for r in spread)
    assert all(fed >= min(r.index + 1 + 5, len(truths)) for fed, r in decided)


def test_frames_waiting_to_be_painted_survive_a_checkpoint():
    """The frames placed but not painted yet (revisit spreading) are part of the pipeline's state: a
    run resumed from a pickled state paints the same mosaic as one never interrupted."""
    cfg = pipeline_config({'device': 'cpu', 'georef.enabled': False, 'mosaic.keyframe_interval': 3,
                           'mosaic.keyframe_revisit_frames': 5, 'mosaic.revisit_spread_frames': 4})
    xs = [15.0 * k for k in range(8)] + [15.0 * (7 - k) for k in range(1, 8)]
    frames = [Frame(k * 100_000_000, view(translation(300 + x, 250 + (10.0 if k > 7 else 0.0)), W, H, noise=2, seed=k))
              for k, x in enumerate(xs)]
    whole = Pipeline(cfg)
    for f in frames:
        whole.feed_frame(f)
    expected = whole.finish()
    first = Pipeline(cfg)
    for f in frames[:10]:
        first.feed_frame(f)
    assert first.held_back == 4
    resumed = Pipeline.from_state(pickle.loads(pickle.dumps(first.state())))
    for f in frames[10:]:
        resumed.feed_frame(f)
    got = resumed.finish()
    assert [r.painted for r in got.records] == [True] * len(frames)
    for a, b in zip(got.records, expected.records, strict=True):
        np.testing.assert_allclose(a.seg_H_frame, b.seg_H_frame, atol=1e-9)
    np.testing.assert_array_equal(got.segments[0].canvas.render()[0], expected.segments[0].canvas.render()[0])


def test_frames_waiting_to_be_painted_are_kept_at_the_mosaics_sampling():
    """Frames finer than the mosaic (mosaic.max_width) wait reduced to its sampling, and paint the
    same mosaic as frames painted at once."""
    frames = [Frame(k * 100_000_000, view(translation(300 + 15.0 * k, 250), W, H, noise=2, seed=k)) for k in range(8)]
    canvases = {}
    for spread in (0, 3):
        pipe = Pipeline(pipeline_config({'device': 'cpu', 'georef.enabled': False, 'mosaic.max_width': W // 4,
                                         'mosaic.revisit_spread_frames': spread}))
        for f in frames:
            pipe.feed_frame(f)
        if spread:
            shapes = [held.raw.shape[:2] for _, held, _ in pipe.painter.unpainted]
            assert len(shapes) == 3 and all(h <= H // 3 and w <= W // 3 for h, w in shapes), shapes
            assert pipe.flush(paint_held=False) == [] and pipe.held_back == 3  # a live pause keeps them
        result = pipe.finish()
        assert all(r.painted for r in result.records)
        canvases[spread] = result.segments[0].canvas.render()[0]
    np.testing.assert_array_equal(canvases[3], canvases[0])


def test_corrections_below_the_minimum_are_not_applied_and_reported():
    _, recs = _out_and_back(True, spread=5, **{'mosaic.keyframe_min_correction_px': 30.0})
    report = keyframe_report(recs)
    assert report['tried'] > 0 and report['applied'] == 0 and report['frames_moved_back'] == 0
    assert report['not_applied'] == {'correction of # px below the minimum': report['tried']}
    assert all(r.keyframe is None or r.keyframe.shift_px < 30.0 for r in recs)


def test_a_camera_turning_over_its_ground_closes_the_loop():
    """An orbit looking at its centre keeps every footprint on the same ground and turns with the
    aircraft: the frames before a turn of more than PASS_TURN_DEG are an earlier pass over it, so
    keyframes register to the mosaic there (centre distance alone never ended the pass). Here a
    camera turns 10 degrees a frame about one ground point, 1.1 turns, each pair's rotation biased by
    0.4 degrees: 54 px of chained drift at the corners by the last frame."""
    bias = similarity(0.4, 1.0, 0, 0, W / 2, H / 2)
    cfg = pipeline_config({'device': 'cpu', 'georef.enabled': False, 'mosaic.keyframe_interval': 5,
                           'mosaic.keyframe_revisit_frames': 10, 'mosaic.revisit_spread_frames': 8})
    pipe = Pipeline(cfg)
    pipe.registrar = DriftingRegistrar(pipe.registrar, bias=bias)
    truths = [translation(500, 375) @ similarity(10.0 * k, 1.0, 0, 0) @ translation(-W / 2, -H / 2) for k in range(40)]
    for k, t in enumerate(truths):
        pipe.feed(Frame(k * 100_000_000, view(t, W, H, noise=2, seed=k)))
    recs = pipe.finish().records
    assert all(r.painted and r.segment == 0 for r in recs)
    applied = [r.index for r in recs if r.keyframe is not None and r.keyframe.seg_H_frame is not None]
    # every 5th frame more than 10 frames on (turned over 100 degrees by then) is a revisit
    assert [r.index for r in recs if r.keyframe is not None] == [15, 20, 25, 30, 35]
    assert len(applied) >= 4
    drift = corner_error_px(np.linalg.matrix_power(bias, 39), np.eye(3), W, H)
    est = np.linalg.inv(recs[0].seg_H_frame) @ recs[-1].seg_H_frame
    error = corner_error_px(est, np.linalg.inv(truths[0]) @ truths[-1], W, H)
    assert drift > 50.0
    assert error < 0.3 * drift, (error, drift)
