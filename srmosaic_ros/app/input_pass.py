"""The pipeline fed with a run's input, in one pass or two.

A run without a measured camera attitude may learn from its first frames that the camera does not
look as its mount says (pose_check.py). It then makes a second pass, from the first item, with the
mount the frames show, so that the filter places every frame with it: the first pass is stopped
there, its pipeline closed, and :func:`second_pass_mount` says what changed. A run resumed after
that switch has its mount in the checkpoint and makes no other pass.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import PipelineConfig
from ..core.image_ops import to_float01
from ..core.stage_clock import StageClock
from ..core.types import Frame
from ..errors import SrMosaicError
from ..io.mosaic_video import MosaicVideoRecorder
from ..io.prefetch import prefetched
from ..pipeline import Pipeline

_LOG = logging.getLogger(__name__)

__all__ = ['READ_AHEAD', 'InputPass', 'feed_input', 'second_pass_mount', 'with_mount']

#: Input items read ahead by a background thread while the pipeline works (io/prefetch.py).
READ_AHEAD = 8


@dataclass
class InputPass:
    """One pass's pipeline, and what the mosaic video and the checkpoints need of it.

    consumed / frames_done: input items and frames fed so far (frames_done counts from the pass's
    first frame, checkpointed ones included); skip_items: items already in a resumed state;
    recent: stamp_ns -> image of the frames not yet decided (for the mosaic video); error: what
    stopped the input early; mount_to_try: (azimuth, elevation) in deg when the pass stopped for a
    second one with that mount.
    """

    pipeline: Pipeline
    recorder: MosaicVideoRecorder | None = None
    recent: dict[int, np.ndarray] = field(default_factory=dict)
    consumed: int = 0
    frames_done: int = 0
    skip_items: int = 0
    error: SrMosaicError | None = None
    mount_to_try: tuple[float, float] | None = None

    @classmethod
    def fresh(cls, config: PipelineConfig, *, overlap: bool, mosaic_video: bool) -> InputPass:
        return cls(Pipeline(config, paint_thread=overlap), MosaicVideoRecorder() if mosaic_video else None)

    def record(self, records: list[Any]) -> None:
        """The frames the pipeline just painted, into the mosaic video."""
        if self.recorder is None:
            return
        for rec in records:
            if rec.painted and rec.stamp_ns in self.recent:
                self.recorder.add(rec.segment, to_float01(self.recent[rec.stamp_ns]), rec.seg_H_frame)


def feed_input(items: Iterable[Any], run: InputPass, *, try_mount: bool, overlap: bool, checkpoint_every: int,
               save: Callable[[InputPass], None], on_frame: Callable[[InputPass], None]) -> None:
    """Feed ``items`` to ``run.pipeline`` until they end, the input breaks (``run.error``) or, with
    ``try_mount``, the frames show another camera mount (``run.mount_to_try``: the caller makes a
    second pass). ``save`` checkpoints the pass every ``checkpoint_every`` frames (0: never);
    ``on_frame`` is told of each frame fed (the progress bar)."""
    pipeline = run.pipeline
    clock = pipeline.clock
    stream = _timed(prefetched(items, READ_AHEAD if overlap else 0), clock)
    try:
        for item in stream:
            run.consumed += 1
            if run.consumed <= run.skip_items:  # already in the checkpointed state
                continue
            records = pipeline.feed(item)
            if try_mount and pipeline.pose_check is not None and pipeline.pose_check.mount_to_try is not None:
                run.mount_to_try = pipeline.pose_check.mount_to_try
                return
            if isinstance(item, Frame):
                clock.end_frame()
                run.frames_done += 1
                on_frame(run)
                if run.recorder is not None:
                    run.recent[item.stamp_ns] = item.image
                    while len(run.recent) > pipeline.max_decision_lag_frames:  # frames are decided at most this late
                        run.recent.pop(next(iter(run.recent)))
            run.record(records)
            if checkpoint_every and isinstance(item, Frame) and run.frames_done % checkpoint_every == 0:
                with clock.stage('outputs'):
                    save(run)
    except SrMosaicError as exc:
        run.error = exc
    finally:
        stream.close()  # the reader thread stops


def second_pass_mount(first: InputPass) -> dict[str, Any]:
    """report.json's mount_from_frames for a first pass stopped on the frames' mount; closes its pipeline.

    The run starts again from the first item with that mount, so that the filter places the frames
    (only the first frames were processed; the run's fingerprint stays the user's settings, the
    checkpoints hold the new ones)."""
    check = first.pipeline.pose_check
    first.pipeline.close()
    azimuth, elevation = first.mount_to_try
    _LOG.warning('no camera attitude was measured and the frames show the camera looking %g deg below the '
                 'horizon, %g deg from the direction of travel, not as the mount says (%s); starting '
                 'again with that mount (georef.gimbal_elevation_deg: %g, georef.gimbal_azimuth_deg: %g; '
                 'georef.mount_from_frames: false keeps the configured one).', -elevation, azimuth,
                 check.reason, elevation, azimuth)
    return {'azimuth_deg': azimuth, 'elevation_deg': elevation, 'after_frames': first.frames_done,
            'first_check': check.as_dict()}


def with_mount(config: PipelineConfig, restart: dict[str, Any]) -> PipelineConfig:
    """``config`` with the camera mount of a second pass (second_pass_mount's entry)."""
    return dataclasses.replace(config, georef=dataclasses.replace(
        config.georef, gimbal_azimuth_deg=restart['azimuth_deg'], gimbal_elevation_deg=restart['elevation_deg']))


def _timed(items: Iterable[Any], clock: StageClock) -> Iterator[Any]:
    """The items, the time spent reading and decoding each counted to the clock's 'decode' stage."""
    it = iter(items)
    while True:
        t0 = time.perf_counter()
        try:
            item = next(it)
        except StopIteration:
            return
        finally:
            clock.add('decode', time.perf_counter() - t0)
        yield item
