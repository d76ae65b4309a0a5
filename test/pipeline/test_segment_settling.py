"""Settling of a georeferenced segment's first frames (mosaic.settle_s, pipeline/settler.py): on the bundled
demo flight the first frames are placed back from the settled one through their registrations, so
they line up with the later ones (the figures: docs/results.md); records come late, each exactly once."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from srmosaic_ros.config import PipelineConfig
from srmosaic_ros.core.metrics import mosaic_corner_errors
from srmosaic_ros.core.mosaic.config import MosaicConfig
from srmosaic_ros.core.types import Frame
from srmosaic_ros.io.bags import read_flight
from srmosaic_ros.pipeline import SYNC_HOLD_FRAMES, Pipeline
from srmosaic_ros.sim.truth import load_truth
from repo_paths import REPO

DEMO = REPO / 'bags' / 'demo'


@pytest.fixture(scope='module')
def flight() -> list:
    return list(read_flight(DEMO))


def _run(items: list, **mosaic: object) -> tuple[Pipeline, list[tuple[int, int]]]:
    """Feed the flight; returns the pipeline and (index of the frame fed last, record index) per
    decided record, in the order they were returned. Settling alone: frames are painted as soon as
    they are placed or settled (revisit spreading off) unless ``mosaic`` says otherwise."""
    mosaic.setdefault('revisit_spread_frames', 0)
    config = PipelineConfig()
    config = replace(config, mosaic=replace(config.mosaic, **mosaic))
    pipe = Pipeline(config)
    decided, fed = [], -1
    for item in items:
        if isinstance(item, Frame):
            fed += 1
        decided += [(fed, r.index) for r in pipe.feed(item)]
    decided += [(fed, r.index) for r in pipe.flush()]
    pipe.finish()
    return pipe, decided


def _errors(pipe: Pipeline) -> np.ndarray:
    truth = load_truth(DEMO / 'ground_truth.json')
    by_stamp = {f.stamp_ns: f for f in truth.frames}
    recs = [r for r in pipe.records if r.painted]
    err, _ = mosaic_corner_errors([r.seg_H_frame for r in recs], [by_stamp[r.stamp_ns].world_px_H_frame for r in recs],
                                  truth.camera.width, truth.camera.height)
    return err


def test_settled_start_has_no_seam_and_records_come_once_and_late(flight):
    settled, decided = _run(flight)                       # defaults: settle_s 3 (12 frames at 4 Hz)
    at_once, decided0 = _run(flight, settle_s=0.0)
    err, err0 = _errors(settled), _errors(at_once)
    assert len(err) == len(err0) == 60
    # without settling: the first frame off the others by the anchor's pose error left in it
    assert err0.max() > 1.0 and err0[0] > 1.0
    assert err.max() < 0.15 and err[:12].max() < 0.1, np.round(err[:14], 3)
    assert err.mean() < 0.6 * err0.mean()
    # every record exactly once; the first 12 come together when the 13th frame (3 s) is placed
    assert sorted(i for _, i in decided) == list(range(60)) == sorted(i for _, i in decided0)
    assert all(fed - i <= Pipeline(PipelineConfig()).max_decision_lag_frames for fed, i in decided)
    first = [fed for fed, i in decided if i < 12]
    assert len(set(first)) == 1 and first[0] >= 12, decided[:14]
    assert all(fed - i <= SYNC_HOLD_FRAMES + 1 for fed, i in decided0)   # at once: only the telemetry wait
    # with revisit spreading too (the default), each record once, within the pipeline's stated lag
    spread, decided30 = _run(flight, revisit_spread_frames=30)
    assert sorted(i for _, i in decided30) == list(range(60))
    assert max(fed - i for fed, i in decided30) >= 30
    assert all(fed - i <= spread.max_decision_lag_frames for fed, i in decided30)
    np.testing.assert_allclose(_errors(spread), err, atol=1e-9)  # no revisit here: the same placements


def test_take_fused_gives_every_pose_once_in_order(flight):
    pipe = Pipeline(PipelineConfig())
    fused = []
    for item in flight:
        pipe.feed(item)
        fused += pipe.take_fused()
    pipe.finish()
    fused += pipe.take_fused()
    assert [r.index for r in fused] == list(range(60))
    assert sum(r.pose is not None and r.pose.valid for r in fused) >= 50


def test_settle_frames_cap_and_bad_values(flight):
    pipe, decided = _run(flight[:200], settle_max_frames=4)
    first = [fed for fed, i in decided if i < 4]
    assert len(set(first)) == 1 and first[0] == 3   # the 4th frame completes the hold
    for bad in ({'settle_s': -1.0}, {'settle_max_frames': 0}, {'settle_max_frames': 2.5}):
        with pytest.raises(ValueError, match='settle'):
            MosaicConfig(**bad)


def test_a_bad_frame_inside_the_settle_window_is_skipped_and_the_rest_settles(flight):
    frames = [i for i, item in enumerate(flight) if isinstance(item, Frame)]
    bad = frames[5]
    item = flight[bad]
    items = list(flight)
    items[bad] = Frame(item.stamp_ns, np.full_like(item.image, 128), item.camera, item.frame_id)  # lens cap
    pipe, decided = _run(items)
    assert sorted(i for _, i in decided) == list(range(60))
    rec = pipe.records[5]
    assert not rec.painted and rec.reason
    assert all(r.painted for r in pipe.records if r.index != 5)
    err = _errors(pipe)
    assert len(err) == 59 and err.max() < 0.15, np.round(err[:14], 3)


def test_a_base_frame_refused_after_the_fact_starts_a_new_segment(flight: list) -> None:
    """A frame becomes the chain's base when it is placed; its paint may still be refused later (when
    its segment settles, or on the painter thread into a canvas grown meanwhile), which sets its
    seg_H_frame to None. The next frame must not chain from it (karma.mp4 with a camera crashed
    here: None @ prev_H_cur) but start a new segment."""
    config = PipelineConfig()
    pipe = Pipeline(replace(config, mosaic=replace(config.mosaic, settle_s=0.0)))
    items = iter(flight)
    refused = None
    for item in items:
        pipe.feed(item)
        if pipe.placer.last_good is not None and pipe.placer.last_good.record.index >= 5:
            refused = pipe.placer.last_good.record
            refused.segment, refused.seg_H_frame = -1, None  # what a refused paint leaves (Painter._paint_now)
            break
    fed = 0
    for item in items:
        pipe.feed(item)
        fed += isinstance(item, Frame)
        if fed == 10:
            break
    result = pipe.finish()
    later = [r for r in result.records if r.index > refused.index]
    assert later and all(r.painted for r in later)
    assert later[0].segment == len(result.segments) - 1 >= 1  # a new segment starts after the refused base
