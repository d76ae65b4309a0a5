"""The one place where the stages meet: frames and telemetry in, registrations and mosaic out.

    pipeline = Pipeline(config)
    for item in source:                  # Frame | GeoFix | ImuSample, in time order
        for record in pipeline.feed(item):
            ...                          # FrameRecord: registered (or not) and painted
    result = pipeline.finish()           # segments; the largest is the main mosaic

Nodes and the CLI drive this class; it knows nothing of ROS, bags or files.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .config import PipelineConfig
from .core.image_ops import to_float01
from .core.mosaic.segments import Segment
from .core.registration import Features, Registrar, Registration
from .core.types import Frame, GeoFix, ImuSample

__all__ = ['FrameRecord', 'Pipeline', 'PipelineResult']


@dataclass
class FrameRecord:
    """What happened to one input frame.

    segment: index of the segment the frame was painted into, or -1 (not painted).
    seg_H_frame: (3, 3) frame pixels -> segment plane pixels, or None.
    registration: the registration that placed it (None for the first frame of a segment).
    """

    index: int
    stamp_ns: int
    size: tuple[int, int]
    segment: int = -1
    seg_H_frame: np.ndarray | None = None
    registration: Registration | None = None
    reason: str = ''
    time_s: float = 0.0

    @property
    def painted(self) -> bool:
        return self.segment >= 0


@dataclass
class PipelineResult:
    records: list[FrameRecord]
    segments: list[Segment]
    fixes: list[GeoFix] = field(default_factory=list)
    imus: list[ImuSample] = field(default_factory=list)

    @property
    def main_segment(self) -> Segment | None:
        """The segment with the most frames (ties: the earliest)."""
        if not self.segments:
            return None
        return max(self.segments, key=lambda s: (len(s.frames), -s.index))


@dataclass
class _Held:
    """A frame kept for registration: its features, float image and record."""

    features: Features
    image: np.ndarray
    record: FrameRecord


class Pipeline:
    """Offline and live pipeline over frames and telemetry (see module docstring)."""

    def __init__(self, config: PipelineConfig | None = None) -> None:
        self.config = config or PipelineConfig()
        self.registrar = Registrar(self.config.registration)
        self.records: list[FrameRecord] = []
        self.segments: list[Segment] = []
        self.fixes: list[GeoFix] = []
        self.imus: list[ImuSample] = []
        self._active: Segment | None = None
        self._last_good: _Held | None = None
        self._orphan: _Held | None = None
        self._channels: int | None = None

    # -- input -------------------------------------------------------------------------------
    def feed(self, item: Frame | GeoFix | ImuSample) -> list[FrameRecord]:
        """Feed one input; return the frame records that were decided by it (possibly none or two)."""
        if isinstance(item, Frame):
            return self.feed_frame(item)
        if isinstance(item, GeoFix):
            self.fixes.append(item)
        elif isinstance(item, ImuSample):
            self.imus.append(item)
        else:
            msg = f'Pipeline.feed takes Frame, GeoFix or ImuSample, not {type(item).__name__}.'
            raise TypeError(msg)
        return []

    def _as_canvas_image(self, image: np.ndarray) -> np.ndarray:
        """Edge image -> float32 (H, W, C) in [0, 1] with the channel count of the first frame."""
        f = to_float01(image)
        if f.ndim == 2:
            f = f[:, :, None]
        if self._channels is None:
            self._channels = f.shape[2]
        if f.shape[2] != self._channels:
            f = np.repeat(f, 3, axis=2) if f.shape[2] == 1 else f.mean(axis=2, keepdims=True)
        return np.ascontiguousarray(f, dtype=np.float32)

    def _start_segment(self, held: _Held) -> Segment:
        seg = Segment.create(len(self.segments), self._channels or 1, self.config.mosaic)
        self.segments.append(seg)
        self._paint(seg, held, np.eye(3))
        return seg

    def _paint(self, seg: Segment, held: _Held, seg_H_frame: np.ndarray) -> bool:  # noqa: N803
        try:
            seg.add(held.record.index, held.image, seg_H_frame)
        except ValueError as exc:  # absurd footprint: refuse, never allocate a giant canvas
            held.record.reason = f'not painted: {exc}'
            return False
        held.record.segment = seg.index
        held.record.seg_H_frame = seg_H_frame
        return True

    def feed_frame(self, frame: Frame) -> list[FrameRecord]:
        t0 = time.perf_counter()
        h, w = frame.image.shape[:2]
        record = FrameRecord(len(self.records), frame.stamp_ns, (w, h))
        self.records.append(record)
        if h < 8 or w < 8:
            record.reason = f'frame of {w}x{h} pixels is too small to register'
            record.time_s = time.perf_counter() - t0
            return [record]
        held = _Held(self.registrar.describe(frame.image), self._as_canvas_image(frame.image), record)
        decided = [record]
        if self._last_good is None:
            self._active = self._start_segment(held)
            self._last_good = held
        else:
            reg = self.registrar.register(self._last_good.features, held.features)
            record.registration = reg
            if reg.ok and self._paint(self._active, held, self._last_good.record.seg_H_frame @ reg.prev_H_cur):
                self._last_good = held
                self._orphan = None
            elif self._orphan is not None and self._try_new_segment(held):
                decided.insert(0, self._orphan.record)
                self._orphan = None
            else:
                record.reason = record.reason or reg.reason
                self._orphan = held
        record.time_s = time.perf_counter() - t0
        return decided

    def _try_new_segment(self, held: _Held) -> bool:
        """Register `held` to the orphan; on success the orphan starts a new segment holding both."""
        orphan = self._orphan
        assert orphan is not None
        reg = self.registrar.register(orphan.features, held.features)
        if not reg.ok:
            return False
        seg = self._start_segment(orphan)
        orphan.record.reason = ''
        held.record.registration = reg
        if not self._paint(seg, held, reg.prev_H_cur):
            return False
        self._active = seg
        self._last_good = held
        return True

    def finish(self) -> PipelineResult:
        return PipelineResult(self.records, self.segments, self.fixes, self.imus)
