"""Placing each frame: registered to the last placed one, chained (4.6), pulled toward its pose
(drift control), and a new segment where the chain breaks.

Each frame is registered to the last placed one: by photometric tracking from the previous pair's
motion when the frames are consecutive video frames and tracking is accepted
(registration.track_frames, core/registration/tracking.py), otherwise by features (keypoints are
detected only then). With fixes and camera intrinsics, segments live on one north-up UTM raster (the
Georeferencer's): a segment's first frame is placed by its fused pose, and chained homographies are
pulled toward the pose-predicted placement (drift control, core/georef/drift.py); without them, a
segment's plane is the pixel plane of its first frame. A frame that does not register becomes the
orphan: when the next one registers to it, the two start a new segment.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..config import PipelineConfig
from ..core.georef.georeferencer import FramePose
from ..core.mosaic.resolution import zoom_homography
from ..core.mosaic.segments import Segment
from ..core.registration import Features, Registration, make_registrar
from ..core.registration.pyramid import PyramidRegistrar
from ..core.registration.tracking import MotionTracker
from ..core.stage_clock import StageClock
from .canvas_resolution import decided_at_settle, start_zoom
from .checkpointed import Checkpointed
from .painter import Painter
from .records import FrameRecord, Held
from .revisits import RevisitCorrector
from .segment_book import SegmentBook, first_frame_plane, plane_scale
from .settler import Settler
from .telemetry_sync import TelemetrySync

__all__ = ['SegmentPlacer']


class SegmentPlacer(Checkpointed):
    """last_good: the frame the next one registers to (the chain's base); orphan: a frame that did not
    register, kept to start a new segment with the next; tracker: the previous pair's motion. The
    registrar is rebuilt from the config (tests may put their own in place: Pipeline.registrar)."""

    STATE = (('_last_good', 'last_good'), ('_orphan', 'orphan'), ('_tracker', 'tracker'))

    def __init__(self, config: PipelineConfig, clock: StageClock, telemetry: TelemetrySync, book: SegmentBook,
                 settler: Settler, revisits: RevisitCorrector, painter: Painter) -> None:
        self.config = config
        self.clock = clock
        self.telemetry, self.book, self.settler, self.revisits, self.painter = telemetry, book, settler, revisits, painter
        registrar = make_registrar(config.registration, config.device)
        max_width = config.registration.max_width
        self.registrar: Any = PyramidRegistrar(registrar, max_width) if max_width > 0 else registrar
        self.tracker = MotionTracker(config.registration.track_frames)
        self.last_good: Held | None = None
        self.orphan: Held | None = None

    def describe(self, image: np.ndarray) -> Features:
        """The frame's features: keypoints only when a registration needs them (tracked frames need none)."""
        if self._tracking():
            return self.registrar.describe(image, keypoints=False)
        return self.registrar.describe(image)

    def add(self, held: Held) -> list[FrameRecord]:
        """Fuse, register and place (or hold) one frame; the records it decides: its own, and the
        orphan's before it when the two start a new segment."""
        record = held.record
        if self.last_good is not None and self.last_good.record.seg_H_frame is None:
            # its placement was refused after it became the chain's base (painted when its segment
            # settled, or on the painter thread, into a canvas grown meanwhile): start anew
            self.last_good = None
        if self.last_good is None:
            self.telemetry.fuse(held, None, None)
            self.book.active = self._start_segment(held)
            if record.seg_H_frame is not None:  # placed (its placement refused: the next frame starts anew)
                self.last_good = held
            return [record]
        last, active = self.last_good, self.book.active
        with self.clock.stage('register'):
            reg = self._register_next(last, held)
        record.registration = reg
        self.telemetry.fuse(held, reg, last)
        if reg.ok and self.settler.place(active, held, self.revisits.keyframe(
                active, held, self._chained(active, last.record.seg_H_frame, reg, held), self.registrar)):
            self.tracker.placed(reg, last.record.index, last.record.stamp_ns, record.index, record.stamp_ns)
            self.last_good = held
            self.orphan = None
        elif self.orphan is not None and self._try_new_segment(held):
            orphan, self.orphan = self.orphan, None
            return [orphan.record, record]
        else:
            self.tracker.lost()
            record.reason = record.reason or reg.reason
            self.orphan = held
        return [record]

    def _try_new_segment(self, held: Held) -> bool:
        """Register ``held`` to the orphan; on success the orphan starts a new segment holding both."""
        orphan = self.orphan
        assert orphan is not None
        with self.clock.stage('register'):
            reg = self.registrar.register(orphan.features, held.features)
        if not reg.ok:
            return False
        seg = self._start_segment(orphan)
        if orphan.record.seg_H_frame is None:  # its placement was refused
            return False
        orphan.record.reason = ''
        held.record.registration = reg
        if not self.settler.place(seg, held, self._chained(seg, orphan.record.seg_H_frame, reg, held)):
            return False
        self.book.active = seg
        self.last_good = held
        self.tracker.placed(reg, orphan.record.index, orphan.record.stamp_ns, held.record.index, held.record.stamp_ns)
        return True

    def _tracking(self) -> bool:
        """Whether frames may be registered by tracking: the setting, and a registrar that tracks
        (the opencv backend does not; tests may put their own registrar in place)."""
        return self.tracker.frames > 1 and getattr(self.registrar, 'tracks', False)

    def _register_next(self, last: Held, held: Held) -> Registration:
        """``held`` registered to the last placed frame: tracked from the previous pair's motion when
        the tracker predicts it and the tracking is accepted, otherwise by features
        (extras['track_refused'] = 1 when tracking was tried first)."""
        predicted = self.tracker.prediction(last.record.index, last.record.stamp_ns, held.record.index,
                                            held.record.stamp_ns) if self._tracking() else None
        if predicted is not None:
            tracked = self.registrar.track(last.features, held.features, predicted, max_rms=self.tracker.max_rms())
            if tracked.ok:
                return tracked
        reg = self.registrar.register(last.features, held.features)
        if predicted is not None:
            reg.extras['track_refused'] = 1.0
        return reg

    def _georeferenced_start(self, held: Held) -> np.ndarray | None:
        """seg_H_frame (3, 3) on the shared raster for the first frame of a segment, when its pose is valid."""
        pose, camera, georef = held.record.pose, held.camera, self.telemetry.georef
        if georef is None or pose is None or not pose.valid or camera is None or self.settler.poses_refused:
            return None
        if georef.raster is None:
            georef.make_raster(pose, camera, coarsen=1.0 / plane_scale(self.config.mosaic.max_width, held.record.size[0]))
            if not decided_at_settle(self.config.mosaic):  # mosaic.resolution 'first': refined now (canvas_resolution.py)
                georef.refine_raster(start_zoom(self.config.mosaic, georef.raster_H_frame(pose, camera), *held.record.size))
        georef.reset_drift()
        # the first drift-control call of a chain anchors it (returned unchanged) with this frame's pose
        return georef.correct(georef.raster_H_frame(pose, camera), pose, camera)

    def _start_segment(self, held: Held) -> Segment:
        """A new segment whose first frame is ``held``: on the raster at its pose (held to settle), or
        in its own pixel plane."""
        self.settler.settle()  # the previous segment's first frames, if still held
        start = self._georeferenced_start(held)
        seg = self.book.open(self.painter.input.channels or 1, georeferenced=start is not None)
        cfg = self.config.mosaic
        if start is None:  # the segment's plane: its first frame's pixels, scaled to mosaic.max_width
            start = first_frame_plane(cfg.max_width, held.record.size[0])
            if not decided_at_settle(cfg):  # refined now, else when its first frames settle (canvas_resolution.py)
                start = zoom_homography(start_zoom(cfg, start, *held.record.size)) @ start
        if (seg.georeferenced or decided_at_settle(cfg)) and cfg.settle_s > 0 and cfg.settle_max_frames > 1:
            self.settler.begin(seg)
            self.settler.place(seg, held, start)
        else:
            self.painter.place(seg, held, start)
        return seg

    def _chained(self, seg: Segment, prev_seg_H_frame: np.ndarray, reg: Registration, held: Held) -> np.ndarray:
        """seg_H_frame (3, 3) of a registered frame: the chain (4.6), with drift control on the raster."""
        chained = prev_seg_H_frame @ reg.prev_H_cur
        pose, georef = held.record.pose, self.telemetry.georef
        if not seg.georeferenced or georef is None or pose is None or not pose.valid or held.camera is None:
            return chained
        with self.clock.stage('fuse'):
            corrected = self._drift_corrected(chained, reg, pose, held)
        self.settler.note_drift_nis(seg, georef.drift_nis)  # evidence for the pose check
        return corrected

    def _drift_corrected(self, chained: np.ndarray, reg: Registration, pose: FramePose, held: Held) -> np.ndarray:
        """The chained seg_H_frame pulled toward the pose-predicted placement (drift control)."""
        georef = self.telemetry.georef
        assert georef is not None and held.camera is not None
        if reg.covariance is not None:
            sigma = georef.corner_sigma_px(reg.prev_H_cur, reg.covariance)
        else:
            # Without a covariance: the least-squares corner error from the inlier residuals,
            # rms * sqrt(8 / inliers) (8 parameters), times 2 for the extrapolation to the corners.
            sigma = 2.0 * reg.rms_px * math.sqrt(8.0 / max(reg.inliers, 8))
        return georef.correct(chained, pose, held.camera, chain_sigma_px=sigma)
