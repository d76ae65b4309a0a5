"""MosaicWorker: the mosaic node's worker thread, which drives the Pipeline under its lock (no ROS).

    worker = MosaicWorker(Pipeline(config, paint_thread=True), intake, warn, outputs, log_error=print)
    worker.start()
    with worker.lock:                  # the preview / map tiles / diagnostics read the pipeline
        ...
    worker.stop()                      # drains the queue, then ends the thread

Each turn feeds the telemetry queued so far and the next frame (core/pipeline.Pipeline.feed); when
the input pauses it flushes the frames held for telemetry and settling, and after IDLE_PAINT_S
also those held for revisit corrections. What the turn made goes to ``outputs`` (the node's
publishers) outside the lock: ``footprint(stamp_ns, corners)`` of the newest fused frame,
``pose(record)`` of each fused frame, ``registration(record)`` of each processed frame. A frame that
fails is counted in ``warn`` and skipped; the thread outlives it.
"""
from __future__ import annotations

import collections
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from ..errors import SrMosaicError
from ..pipeline import FrameRecord, Pipeline
from .frame_intake import FrameIntake

__all__ = ['IDLE_PAINT_S', 'MosaicOutputs', 'MosaicWorker', 'footprint_of']

#: The input paused this long (s): the frames held for revisit corrections (mosaic.revisit_spread_frames)
#: are painted too; shorter pauses (frames a second apart) only end the waits for telemetry and settling.
IDLE_PAINT_S = 5.0
#: processing times kept for the diagnostics' median and p95
LATENCIES_KEPT = 500


class MosaicOutputs(Protocol):
    """Where the worker's results go (the node's publishers); called outside the pipeline lock."""

    def footprint(self, stamp_ns: int, corners: np.ndarray) -> None: ...
    def pose(self, record: FrameRecord) -> None: ...
    def registration(self, record: FrameRecord) -> None: ...


def footprint_of(pipeline: Pipeline, record: FrameRecord) -> tuple[int, np.ndarray] | None:
    """(stamp, (4, 2) raster pixels) of the ground a fused frame sees, by its pose (the filter's best
    estimate now, whether or not the frame is painted yet); None without one. Under the pipeline lock."""
    georef = pipeline.georef
    if georef is None or georef.raster is None or record.pose is None or not record.pose.valid:
        return None
    w, h = record.size
    corners = np.array([[-0.5, w - 0.5, w - 0.5, -0.5], [-0.5, -0.5, h - 0.5, h - 0.5], [1.0, 1.0, 1.0, 1.0]])
    try:
        p = georef.raster_H_frame(record.pose, record.camera) @ corners
    except (SrMosaicError, ValueError, np.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(p)) or np.any(p[2] <= 0):  # a corner above the horizon
        return None
    return record.stamp_ns, (p[:2] / p[2]).T


class MosaicWorker:
    """The thread that runs ``pipeline`` on the frames of ``intake`` (module docstring).

    ``lock`` guards the pipeline (this thread against the preview and diagnostics); ``latency_ms``
    holds the processing time of the recent turns that produced records; ``last_record`` is the
    newest processed frame's record. ``footprints``: compute the newest fused frame's footprint
    (only when the map tiles are on)."""

    def __init__(self, pipeline: Pipeline, intake: FrameIntake, warn: Any, outputs: MosaicOutputs, *,
                 footprints: bool, log_error: Callable[[str], None]) -> None:
        self.pipeline = pipeline
        self.lock = threading.Lock()
        self.latency_ms: collections.deque[float] = collections.deque(maxlen=LATENCIES_KEPT)
        self.last_record: FrameRecord | None = None
        self._intake = intake
        self._warn = warn
        self._outputs = outputs
        self._footprints = footprints
        self._log_error = log_error
        self._thread = threading.Thread(target=self._work, name='srmosaic-mosaic-worker', daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 60.0) -> None:
        """Drain the queue and end the thread (waits up to ``timeout_s``)."""
        self._intake.stop()
        self._thread.join(timeout=timeout_s)

    def _work(self) -> None:
        idle_since = time.monotonic()
        while (turn := self._intake.next()) is not None:
            frame, idle = turn
            if frame is not None or not idle:
                idle_since = time.monotonic()
            self._turn(frame, idle, time.monotonic() - idle_since)

    def _turn(self, frame: Any, idle: bool, idle_s: float) -> None:
        t0 = time.perf_counter()
        pipeline = self.pipeline
        with self.lock:
            records = []
            while (item := self._intake.pop_telemetry()) is not None:  # those that come meanwhile too
                records += pipeline.feed(item)
            try:
                if frame is not None:
                    records += pipeline.feed(frame)
                    pipeline.clock.end_frame()
                elif idle and pipeline.held_back:  # input paused: do not hold frames forever; those
                    # held for revisit corrections wait IDLE_PAINT_S (frames a second apart keep them)
                    records += pipeline.flush(paint_held=idle_s >= IDLE_PAINT_S)
            except SrMosaicError as exc:
                self._warn(f'pipeline: {type(exc).__name__}', f'frame skipped: {exc}')
                return
            except Exception as exc:  # noqa: BLE001 - the worker must outlive any one frame
                self._warn(f'pipeline bug: {type(exc).__name__}',
                           f'frame skipped after an internal error (please report): {exc!r}')
                self._log_error(traceback.format_exc())
                return
            fused = pipeline.take_fused()
            footprint = footprint_of(pipeline, fused[-1]) if fused and self._footprints else None
        if footprint is not None:
            self._outputs.footprint(*footprint)
        if records:
            self.latency_ms.append((time.perf_counter() - t0) * 1e3)
        self._warn.count('frames_processed', len(records))
        for record in fused:  # poses at once, also of frames held while their segment settles
            self._outputs.pose(record)
        for record in records:
            self._outputs.registration(record)
            self.last_record = record
