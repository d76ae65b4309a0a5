"""The one place where the stages meet: frames and telemetry in, registrations and mosaic out.

    pipeline = Pipeline(config)
    for item in source:                  # Frame | GeoFix | ImuSample | CameraAttitude, in time order
        for record in pipeline.feed(item):
            ...                          # FrameRecord: registered (or not) and painted
    result = pipeline.finish()           # segments; the largest is the main mosaic

Nodes and the CLI drive this class; it knows nothing of ROS, bags or files. It conducts named
collaborators, each with its own module and its own part of the checkpoint state:

- TelemetrySync (telemetry_sync.py): telemetry kept and fed to the georeferencing filter, frames
  queued until their telemetry has arrived (approximate-time synchronisation);
- SegmentPlacer (placer.py): registration to the last placed frame (or tracking), the chain (4.6),
  drift control, new segments; SegmentBook (segment_book.py) holds the segments;
- Settler (settler.py): a segment's first frames held until the poses settle and the canvas's
  sampling is decided (canvas_resolution.py), and the pose and attitude checks made then;
- RevisitCorrector (revisits.py): keyframes registered to the mosaic on revisits, their corrections
  spread back over the frames not painted yet;
- Painter (painter.py, paint_input.py): thinning, revisit spreading's delay, the paint thread.

A frame's record is returned when it is decided: at once, or later when the frame waits for
telemetry, for its segment to settle, or for its paint (revisit spreading).
"""
from __future__ import annotations

import time
from typing import Any

from ..config import PipelineConfig
from ..core.georef.georeferencer import Georeferencer
from ..core.georef.pose_check import PoseCheck
from ..core.mosaic.segments import Segment
from ..core.stage_clock import StageClock
from ..core.time_sync import SYNC_HOLD_FRAMES
from ..core.types import CameraAttitude, CameraIntrinsics, Frame, GeoFix, ImuSample
from ..core.undistort import Undistorter
from ..malloc_tuning import HeapTrimmer, settle_allocator
from .checkpointed import Checkpointed
from .paint_input import PaintInput
from .painter import Painter
from .placer import SegmentPlacer
from .records import FrameRecord, Held, PipelineResult
from .revisits import RevisitCorrector
from .segment_book import SegmentBook
from .settler import Settler
from .telemetry_sync import FIRST_FIX_HOLD_FRAMES, TelemetrySync

__all__ = ['STATE_VERSION', 'Pipeline']

#: Version of :meth:`Pipeline.state`: a checkpoint of another is refused (the run starts again).
STATE_VERSION = 4

#: The collaborators' classes, whose STATE keys make up the checkpoint with the conductor's own.
_PARTS: tuple[type[Checkpointed], ...] = (TelemetrySync, SegmentBook, SegmentPlacer, Settler, RevisitCorrector, Painter,
                                          PaintInput)
#: The keys of a checkpoint (Pipeline.state) besides 'version' and 'config'.
_STATE = ('records', 'clock', *(key for part in _PARTS for key, _ in part.STATE))
#: keys of _STATE a state of the same version may lack (written before they existed)
_STATE_NEWER = frozenset().union(*(part.NEWER for part in _PARTS))


class Pipeline:
    """Offline and live pipeline over frames and telemetry (see module docstring)."""

    def __init__(self, config: PipelineConfig | None = None, *, paint_thread: bool = False,
                 clock: StageClock | None = None) -> None:
        """paint_thread: paint into the mosaic on a background thread while the next frames are
        registered (offline runs; the canvas may then be read only after :meth:`sync`). clock: the
        stage clock to count into (a resumed run's), else a new one."""
        self.config = config or PipelineConfig()
        self.clock = clock or StageClock()  # seconds per stage per input frame (the driver calls clock.end_frame())
        self.undistorter = Undistorter(self.config.undistort)
        self.records: list[FrameRecord] = []
        self._heap = HeapTrimmer()  # long runs: return freed heap pages (malloc_tuning.py)
        settle_allocator()  # the first seconds without a page-fault storm (malloc_tuning.py)
        self.telemetry = TelemetrySync(self.config, self.clock)
        self.book = SegmentBook(self.config)
        self.painter = Painter(self.config, self.clock, paint_thread=paint_thread)
        self.revisits = RevisitCorrector(self.config, self.clock, self.painter)
        self.settler = Settler(self.config, self.telemetry, self.book, self.painter)
        self.placer = SegmentPlacer(self.config, self.clock, self.telemetry, self.book, self.settler, self.revisits,
                                    self.painter)

    # -- input -------------------------------------------------------------------------------
    def feed(self, item: Frame | GeoFix | ImuSample | CameraAttitude | CameraIntrinsics) -> list[FrameRecord]:
        """Feed one input; return the frame records decided by it (none, one or several).

        A CameraIntrinsics (live: from CameraInfo) becomes the camera of frames that carry none.
        """
        self.telemetry.feed(item)
        if isinstance(item, CameraIntrinsics):
            return []
        return self._drain()

    def feed_frame(self, frame: Frame) -> list[FrameRecord]:
        """Process a frame now, without waiting for telemetry (e.g. inputs without any)."""
        return self._process(frame)

    def _drain(self, *, all_frames: bool = False) -> list[FrameRecord]:
        """Process the waiting frames whose telemetry has arrived (approximate-time association)."""
        decided: list[FrameRecord] = []
        for frame in self.telemetry.ready(all_frames=all_frames):
            decided += self._process(frame)
        return decided

    def _process(self, frame: Frame) -> list[FrameRecord]:
        """Undistort, describe and place one frame; the records decided meanwhile, in order."""
        t0 = time.perf_counter()
        # a camera with lens distortion: from here on the frame is that of its pinhole camera
        # (core/undistort.py); an unusable distortion model raises InputError before any record
        with self.clock.stage('undistort'):
            frame = self.undistorter.frame(frame, self.telemetry.camera)
        h, w = frame.image.shape[:2]
        record = FrameRecord(len(self.records), frame.stamp_ns, (w, h))
        self.records.append(record)
        if h < 8 or w < 8:
            record.reason = f'frame of {w}x{h} pixels is too small to register'
            record.time_s = time.perf_counter() - t0
            return [record]
        with self.clock.stage('describe'):
            features = self.placer.describe(frame.image)
        self.painter.input.note_first(frame.image)  # the canvas's channels, from the first frame
        held = Held(features, record, frame.camera or self.telemetry.camera, frame.image)
        record.camera = held.camera
        decided = self.placer.add(held)
        record.time_s = time.perf_counter() - t0
        self._heap.tick()
        settled = self.painter.take_decided()
        later = {id(r) for r in settled} | {id(h.record) for h in self.settler.settling} | \
            {id(h.record) for _, h, _ in self.painter.unpainted}
        return settled + [r for r in decided if id(r) not in later]

    # -- output ------------------------------------------------------------------------------
    def flush(self, *, paint_held: bool = True) -> list[FrameRecord]:
        """Process every frame still waiting for telemetry (live: when telemetry stopped coming) and
        paint the frames held for settling: every frame held back is decided. ``paint_held`` False
        keeps the frames held for revisit corrections (a live input's short pause)."""
        decided = self._drain(all_frames=True)
        self.settler.settle()
        if paint_held:
            self.painter.paint_unpainted()
            self.painter.paint_held_back()
        self.sync()
        return decided + self.painter.take_decided()

    def take_fused(self) -> list[FrameRecord]:
        """Records whose fused pose (record.pose) was computed since the last call, in order; a frame
        held for settling is decided later, but its pose is ready now (live: publish it at once)."""
        return self.telemetry.take_fused()

    def finish(self) -> PipelineResult:
        """Process the frames still waiting for telemetry, paint those held for settling, and return everything."""
        self.flush()
        return PipelineResult(self.records, self.segments, self.fixes, self.imus, self.georef, self.attitudes,
                              pose_check=self.pose_check, attitude_check=self.attitude_check,
                              frames_thinned=self.painter.thin.thinned, frames_painted_in_part=self.painter.thin.in_part)

    def sync(self) -> None:
        """Wait for the frames being painted on the painter thread (paint_thread=True): the canvases
        are complete after this. Raises the error of a paint that failed."""
        self.painter.sync()

    def close(self) -> None:
        """Finish the paints in flight and stop the painter thread (the pipeline stays usable, painting
        in the caller's thread)."""
        self.painter.close()

    # -- what the collaborators know -------------------------------------------------------------
    @property
    def registrar(self) -> Any:
        """The frame registrar (tests may put their own in place)."""
        return self.placer.registrar

    @registrar.setter
    def registrar(self, registrar: Any) -> None:
        self.placer.registrar = registrar

    @property
    def georef(self) -> Georeferencer | None:
        """The georeferencing filter, from the first fix (None before one, or without georeferencing)."""
        return self.telemetry.georef

    @property
    def camera(self) -> CameraIntrinsics | None:
        return self.telemetry.camera

    @property
    def fixes(self) -> list[GeoFix]:
        return self.telemetry.fixes

    @property
    def imus(self) -> list[ImuSample]:
        return self.telemetry.imus

    @property
    def attitudes(self) -> list[CameraAttitude]:
        return self.telemetry.attitudes

    @property
    def segments(self) -> list[Segment]:
        return self.book.segments

    @property
    def pose_check(self) -> PoseCheck | None:
        """Whether the poses of an unmeasured attitude place the frames (decided when the first
        georeferenced segment settles)."""
        return self.settler.pose_check

    @property
    def attitude_check(self) -> dict[str, Any] | None:
        """The measured attitude against the frames' (pose_check.check_measured_attitude), or None."""
        return self.settler.attitude_check

    @property
    def waiting(self) -> int:
        """Frames waiting for telemetry at or after their stamp."""
        return len(self.telemetry.waiting)

    @property
    def held_back(self) -> int:
        """Frames not decided yet: waiting for telemetry, placed and held for settling, or placed and
        not painted yet (revisit spreading)."""
        return len(self.telemetry.waiting) + len(self.settler.settling) + len(self.painter.unpainted)

    @property
    def max_decision_lag_frames(self) -> int:
        """How many frames later than its own a frame's record may be returned, at most."""
        cfg = self.config.mosaic
        first_fix = FIRST_FIX_HOLD_FRAMES if self.config.georef_enabled else 0
        return (max(SYNC_HOLD_FRAMES, first_fix) + 3 + (cfg.settle_max_frames if cfg.settle_s > 0 else 0)
                + cfg.revisit_spread_frames)

    # -- checkpoints -----------------------------------------------------------------------------
    def _parts(self) -> tuple[Checkpointed, ...]:
        return (self.telemetry, self.book, self.placer, self.settler, self.revisits, self.painter)

    def state(self) -> dict[str, Any]:
        """What a resumed run needs (checkpoints: app/checkpoint.py), by name: STATE_VERSION, the
        config, the records, the stage clock and each collaborator's part (Checkpointed.STATE: the
        segments with their canvases, telemetry, the filter, the frames held for registration, for
        telemetry, while their segment settles and for their paint). The registrar, undistorter and
        painter thread are rebuilt from the config (they hold nothing between frames). Paints in
        flight are finished first."""
        self.sync()
        out: dict[str, Any] = {'version': STATE_VERSION, 'config': self.config, 'records': self.records, 'clock': self.clock}
        for part in self._parts():
            out.update(part.state())
        return out

    @classmethod
    def from_state(cls, state: dict[str, Any], *, paint_thread: bool = False) -> Pipeline:
        """The pipeline whose :meth:`state` this is; ValueError naming the problem when it is a state
        of another version (or not one)."""
        if not isinstance(state, dict) or state.get('version') != STATE_VERSION:
            version = state.get('version') if isinstance(state, dict) else type(state).__name__
            msg = f'pipeline state of version {version!r}; this version reads version {STATE_VERSION}.'
            raise ValueError(msg)
        if missing := [name for name in ('config', *_STATE) if name not in state and name not in _STATE_NEWER]:
            msg = f'pipeline state without {missing}.'
            raise ValueError(msg)
        pipe = cls(state['config'], paint_thread=paint_thread, clock=state['clock'])
        pipe.records = state['records']
        for part in pipe._parts():
            part.restore(state)
        return pipe
