"""Keyframe-to-mosaic registration: the view rendering, and an out-and-back flight whose chain
drifts (a registrar biased by 0.3 px per pair) closes on the return leg only with keyframes."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.mosaic.canvas import TiledCanvas
from srmosaic_ros.core.mosaic.config import MosaicConfig
from srmosaic_ros.core.mosaic.keyframe import corner_shift_px, render_view
from srmosaic_ros.core.types import Frame
from srmosaic_ros.pipeline import Pipeline

from imagery import translation, view

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
                {'keyframe_revisit_frames': 1.5}):
        with pytest.raises(ValueError, match='keyframe'):
            MosaicConfig(**bad)


class DriftingRegistrar:
    """The pipeline's registrar with a bias of `bias_px` per frame pair (cur -> prev shifted in x),
    as chained registration errors add up; registrations to the rendered mosaic (float32 views,
    not uint8 frames) are left unbiased, so keyframes see the truth of the mosaic."""

    def __init__(self, inner, bias_px: float) -> None:
        self.inner, self.bias = inner, translation(bias_px, 0.0)
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


def _out_and_back(keyframes: bool) -> tuple[list[np.ndarray], list]:
    """20 frames east at 15 px/frame, 20 back (10 px south of the way out); returns the true
    world_H_frame and the records."""
    cfg = pipeline_config({'device': 'cpu', 'georef.enabled': False, 'mosaic.keyframe_interval': 5 if keyframes else 0,
                           'mosaic.keyframe_revisit_frames': 10})
    pipe = Pipeline(cfg)
    pipe.registrar = DriftingRegistrar(pipe.registrar, 0.3)
    xs = [15.0 * k for k in range(21)] + [15.0 * (20 - k) for k in range(1, 21)]
    truths = [translation(300 + x, 250 + (10.0 if k > 20 else 0.0)) for k, x in enumerate(xs)]
    for k, t in enumerate(truths):
        pipe.feed(Frame(k * 100_000_000, view(t, W, H, noise=2, seed=k)))
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
