"""Where the time goes: seconds per pipeline stage, per input frame.

    clock = StageClock()
    with clock.stage('describe'):
        ...
    clock.end_frame()          # after each input frame: its stages become one sample each
    clock.summary()            # {stage: {'median_ms', 'p95_ms', 'mean_ms', 'total_s', 'frames'}}

A frame's sample holds the work done between its arrival and the next frame's, whichever frame
that work was for (a frame held for telemetry or settling is painted during a later one), so the
per-stage totals are exact and the per-frame figures are what a user waiting on the stream sees.
Stages may run on other threads (an offline run paints on a painter thread): their time is
counted all the same, so the stages of a frame may add up to more than the wall time between
frames (what the overlap gained).
"""
from __future__ import annotations

import collections
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

__all__ = ['STAGES', 'StageClock']

#: The stages, in pipeline order: reading and decoding the input, lens undistortion, feature
#: description, registration (frame to frame and keyframe to mosaic), georeferencing filter updates
#: (telemetry and frames), painting into the mosaic, and writing the outputs (once per run).
STAGES = ('decode', 'undistort', 'describe', 'register', 'fuse', 'paint', 'outputs')

#: Samples kept per stage (live nodes run for hours: the figures are those of the latest frames).
KEEP_FRAMES = 100_000


class StageClock:
    """Seconds per stage (STAGES) per input frame; stages may nest only if they differ (the outer
    one then counts the inner one's time too, so the pipeline does not nest them)."""

    def __init__(self) -> None:
        self._current: dict[str, float] = dict.fromkeys(STAGES, 0.0)
        self._samples: dict[str, collections.deque[float]] = {s: collections.deque(maxlen=KEEP_FRAMES) for s in STAGES}
        self._total: dict[str, float] = dict.fromkeys(STAGES, 0.0)
        self._lock = threading.Lock()
        self.frames = 0

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Count the time spent in the with-block to stage ``name`` (one of STAGES)."""
        if name not in self._current:
            msg = f'unknown stage {name!r}; stages: {", ".join(STAGES)}'
            raise ValueError(msg)
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - t0)

    def add(self, name: str, seconds: float) -> None:
        """Count ``seconds`` to stage ``name`` of the current frame (from any thread)."""
        with self._lock:
            self._current[name] += seconds
            self._total[name] += seconds

    def end_frame(self) -> None:
        """Close the current input frame: each stage's time since the last call is one sample."""
        with self._lock:
            for name, seconds in self._current.items():
                self._samples[name].append(seconds)
                self._current[name] = 0.0
            self.frames += 1

    def per_frame_ms(self, name: str) -> np.ndarray:
        """(frames,) float ms of stage ``name`` per input frame, oldest first (the latest KEEP_FRAMES)."""
        with self._lock:
            return np.asarray(self._samples[name], dtype=float) * 1e3

    def __getstate__(self) -> dict:
        """Picklable (checkpoints): the lock is rebuilt."""
        return {k: v for k, v in self.__dict__.items() if k != '_lock'}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    def summary(self) -> dict[str, dict[str, float | int]]:
        """{stage: {'median_ms', 'p95_ms', 'mean_ms' (per input frame), 'total_s', 'frames'}} plus
        'total' (the sum of the stages per frame); stages that never ran are left out. 'outputs' runs
        once per run: its total counts, its per-frame figures are its total spread over the frames.
        A stage on another thread (the painter) lands on the frame during which it ended: its mean
        is its share of each frame, its median and p95 say little."""
        out: dict[str, dict[str, float | int]] = {}
        per_frame = np.zeros(len(self._samples['decode']))
        for name in STAGES:
            total = self._total[name]
            if total <= 0.0:
                continue
            samples = np.asarray(self._samples[name], dtype=float)
            if name == 'outputs' or samples.size == 0:
                samples = np.full(max(self.frames, 1), total / max(self.frames, 1))
            if samples.size == per_frame.size:
                per_frame += samples
            out[name] = _figures(samples, total, self.frames)
        if out:
            out['total'] = _figures(per_frame, sum(self._total.values()), self.frames)
        return out


def _figures(samples: np.ndarray, total: float, frames: int) -> dict[str, float | int]:
    return {'median_ms': round(float(np.median(samples)) * 1e3, 3),
            'p95_ms': round(float(np.percentile(samples, 95)) * 1e3, 3),
            'mean_ms': round(total / max(frames, 1) * 1e3, 3),
            'total_s': round(total, 3), 'frames': frames}
