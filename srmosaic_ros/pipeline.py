"""The one place where the stages meet: frames and telemetry in, registrations and mosaic out.

    pipeline = Pipeline(config)
    for item in source:                  # Frame | GeoFix | ImuSample | CameraAttitude, in time order
        for record in pipeline.feed(item):
            ...                          # FrameRecord: registered (or not) and painted
    result = pipeline.finish()           # segments; the largest is the main mosaic

Nodes and the CLI drive this class; it knows nothing of ROS, bags or files.

Each frame is registered to the last placed one: by photometric tracking from the previous pair's
motion when the frames are consecutive video frames and tracking is accepted (`registration.track_frames`,
core/registration/tracking.py), otherwise by features (keypoints are detected only then).

Telemetry and frames are associated by time (approximate-time synchronisation): a frame waits
until telemetry at or after its stamp has been seen (or until `SYNC_HOLD_FRAMES` more frames
arrived with no telemetry at all), so the georeferencing filter always has the fixes and IMU
samples that precede it. With fixes and camera intrinsics, segments live on one north-up UTM
raster (the Georeferencer's), frames are placed by their fused pose, and chained homographies are
pulled toward the pose-predicted placement (drift control); without them, a segment's plane is
the pixel plane of its first frame.

Settling (georeferenced segments, `mosaic.settle_s`, `mosaic.settle_max_frames`): the first frame
of a segment is placed by its pose when the filter knows least, and drift control then pulls the
next frames toward better poses; painted at once, the first frames would not line up with the
later ones (a seam the registrations, good to hundredths of a pixel, do not have). So a
segment's first frames are held, unpainted, until settle_s seconds of them (or settle_max_frames
frames) have been placed; then they are placed back from the newest one through their own
registrations (H_k = H_(k+1) inv(prev_H_cur_(k+1))) and painted. Their records are decided then,
that much later (the poses are ready at once: take_fused()).

Poses without a measured attitude (no Imu orientation, no CameraAttitude: the filter's camera is
only the configured mount, nadir by default): when the first georeferenced segment settles, its
drift-control innovations say whether that assumption fits the footage (core/georef/pose_check.py).
When it does not (an oblique or forward-looking camera), the held frames are placed back in the
first frame's pixel plane through their registrations, no later segment is placed by its pose,
and the mosaic is chained as without intrinsics (georeferenced afterwards by its geotags where
they can place it: app/georeference.py refuses a chain whose frames look obliquely);
``pose_check`` says so, with a warning.

Revisit spreading (`mosaic.revisit_spread_frames` N > 0): every frame is placed at once but painted
N frames later. When a keyframe's registration to the mosaic moves it (a revisit of old ground),
the frames placed since the last fixed placement and not painted yet take their share of that
correction (core/mosaic/revisit.py) before they are painted; their records are decided when they
are painted, N frames later (``FrameRecord.corrected_px`` says how far each was moved).
"""
from __future__ import annotations

import collections
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .config import PipelineConfig
from .malloc_tuning import HeapTrimmer, settle_allocator
from .core.homography import corner_depth_ratio, project_points
from .core.image_ops import to_float01
from .core.mosaic.canvas import CanvasError
from .core.mosaic.segments import Segment
from .core.time_sync import SYNC_HOLD_FRAMES, telemetry_ready
from .core.mosaic.best_view import clip_depth, clipped_polygon
from .core.mosaic.keyframe import KeyframeResult, corner_shift_px, render_view
from .core.mosaic.minify import area_factor, area_reduce, finest_stretch
from .core.mosaic.revisit import footprint_pose, spread_correction
from .core.mosaic.thinning import PaintThinning
from .core.mosaic.scratch import scratch
from .core.registration import Features, Registration, make_registrar
from .core.registration.pyramid import PyramidRegistrar
from .core.registration.tracking import MotionTracker
from .core.georef.georeferencer import FramePose, Georeferencer, sees_the_ground
from .core.georef.chain_mount import MountEstimate, horizon_words, mount_from_chain
from .core.georef.pose_check import PoseCheck, check_measured_attitude, check_pose_placement
from .core.serial_worker import SerialWorker
from .core.stage_clock import StageClock
from .core.undistort import Undistorter
from .core.types import CameraAttitude, CameraIntrinsics, Frame, GeoFix, ImuSample

__all__ = ['FrameRecord', 'Pipeline', 'PipelineResult', 'SYNC_HOLD_FRAMES']

_LOG = logging.getLogger(__name__)

#: Frames kept waiting for telemetry when none has been seen after them (then they go on alone).
#: Before the first GNSS fix, frames wait for one (at most this many, and at most
#: georef.telemetry_buffer_s of them), so that a flight whose first fixes are late or unusable
#: still starts its mosaic on the map (the filter starts from the nearest fix, see Georeferencer).
FIRST_FIX_HOLD_FRAMES = 32


@dataclass
class FrameRecord:
    """What happened to one input frame.

    segment: index of the segment the frame was painted into, or -1 (not painted).
    seg_H_frame: (3, 3) frame pixels -> segment plane pixels, or None.
    registration: the registration that placed it (None for the first frame of a segment).
    camera: the intrinsics the frame was taken with (a zoom changes them frame to frame), or None.
    """

    index: int
    stamp_ns: int
    size: tuple[int, int]
    segment: int = -1
    seg_H_frame: np.ndarray | None = None
    registration: Registration | None = None
    reason: str = ''
    time_s: float = 0.0
    pose: FramePose | None = None
    keyframe: KeyframeResult | None = None
    camera: CameraIntrinsics | None = None
    corrected_px: float = 0.0  # largest corner move (px) of this frame by a later keyframe's correction spread back

    @property
    def painted(self) -> bool:
        return self.segment >= 0


@dataclass
class PipelineResult:
    records: list[FrameRecord]
    segments: list[Segment]
    fixes: list[GeoFix] = field(default_factory=list)
    imus: list[ImuSample] = field(default_factory=list)
    georef: Georeferencer | None = None
    attitudes: list[CameraAttitude] = field(default_factory=list)
    georef_note: str = ''  # why the offline fallback (the fit to geotags) did not place the mosaic
    pose_check: PoseCheck | None = None  # whether the poses of an unmeasured attitude placed the mosaic
    attitude_check: dict[str, Any] | None = None  # the measured attitude against the frames' (pose_check.py)
    frames_thinned: int = 0  # placed frames whose pixels were left to their neighbours' (mosaic.paint_stride)
    frames_painted_in_part: int = 0  # ... but for the tiles where they reach beyond them

    @property
    def main_segment(self) -> Segment | None:
        """The segment with the most frames (ties: the earliest)."""
        if not self.segments:
            return None
        return max(self.segments, key=lambda s: (len(s.frames), -s.index))


@dataclass
class _Held:
    """A frame kept for registration and painting: its features, record, camera and ``raw``, the
    input image (converted for the canvas when it is painted: _paint_input)."""

    features: Features
    record: FrameRecord
    camera: CameraIntrinsics | None
    raw: np.ndarray


#: Version of :meth:`Pipeline.state`: a checkpoint of another is refused (the run starts again).
STATE_VERSION = 4

#: A frame turned by more than this (degrees) from the frames centred near it views their ground
#: from another direction: a new pass over it (Pipeline._revisits).
PASS_TURN_DEG = 45.0

#: The attributes a resumed run needs (Pipeline.state); everything else is rebuilt from the config.
_STATE = ('records', 'segments', 'fixes', 'imus', 'attitudes', 'georef', 'camera', 'clock', '_geo_canvas', '_active',
          '_last_good', '_orphan', '_channels', '_waiting', '_first_fix_wait_over', '_latest_telemetry_ns',
          '_settling', '_settling_seg', '_settled', '_fused', 'pose_check', '_settling_nis', '_unpainted', '_anchor',
          '_tracker', '_thin', 'attitude_check')

#: A frame is left to its painted neighbours (mosaic.paint_stride) only when the depths of its
#: corners differ by at most this ratio: a view within about 7 deg of nadir for a 60 deg lens.
THIN_MAX_DEPTH_RATIO = 1.15

#: attributes of _STATE a state of the same version may lack (written before they existed)
_STATE_NEWER = ('_thin', 'attitude_check')


class Pipeline:
    """Offline and live pipeline over frames and telemetry (see module docstring)."""

    def __init__(self, config: PipelineConfig | None = None, *, paint_thread: bool = False) -> None:
        """paint_thread: paint into the mosaic on a background thread while the next frames are
        registered (offline runs; the canvas may then be read only after :meth:`sync`)."""
        self.config = config or PipelineConfig()
        self._painter: SerialWorker | None = SerialWorker(name='srmosaic-paint') if paint_thread else None
        registrar = make_registrar(self.config.registration, self.config.device)
        max_width = self.config.registration.max_width
        self.registrar = PyramidRegistrar(registrar, max_width) if max_width > 0 else registrar
        # consecutive frames registered by photometric tracking (core/registration/tracking.py)
        self._tracker = MotionTracker(self.config.registration.track_frames)
        self.records: list[FrameRecord] = []
        self.segments: list[Segment] = []
        self.fixes: list[GeoFix] = []
        self.imus: list[ImuSample] = []
        self.attitudes: list[CameraAttitude] = []
        self.georef: Georeferencer | None = None
        self._geo_canvas: Segment | None = None  # the first georeferenced segment: owner of the shared canvas
        self._active: Segment | None = None
        self._last_good: _Held | None = None
        self._orphan: _Held | None = None
        self._channels: int | None = None
        self._waiting: list[Frame] = []
        self._first_fix_wait_over = False
        self.camera: CameraIntrinsics | None = None
        self.undistorter = Undistorter(self.config.undistort)
        self._latest_telemetry_ns: int | None = None
        self._heap = HeapTrimmer()  # long runs: return freed heap pages (malloc_tuning.py)
        settle_allocator()  # the first seconds without a page-fault storm (malloc_tuning.py)
        # segment -> (x, y, heading rad) of its painted frames' centres (_revisits; rebuilt from the
        # segments on resume, so not in the state)
        self._footprints: dict[int, list[np.ndarray]] = {}
        self._settling: list[_Held] = []  # the first frames of the active segment, placed, not painted yet
        self._settling_seg: Segment | None = None
        self._settled: list[FrameRecord] = []  # records decided by the last settle (returned by _process)
        self._fused: collections.deque[FrameRecord] = collections.deque(maxlen=1000)
        self.pose_check: PoseCheck | None = None  # decided when the first georeferenced segment settles
        self.attitude_check: dict[str, Any] | None = None  # ... or, with a measured attitude, this
        self._settling_nis: list[float] = []  # drift-control NIS of the settling frames (pose_check.py)
        # placed, painted later (revisit spreading): segment, frame (its image reduced to the mosaic's
        # sampling: raw is then that image), frame_H_image (the reduction: painted at seg_H_frame @ it)
        self._unpainted: collections.deque[tuple[Segment, _Held, np.ndarray]] = collections.deque()
        self._anchor = -1  # record index of the last keyframe the mosaic placed: corrections spread back to it
        # the moving-object vote needs every frame's colours: no thinning with it
        self._thin = PaintThinning(self.config.mosaic.paint_stride if not self.config.mosaic.moving > 0 else 1,
                                   self.config.mosaic.paint_shift_px, self.config.mosaic.tile_size)
        self.clock = StageClock()  # seconds per stage per input frame (the driver calls clock.end_frame())

    # -- input -------------------------------------------------------------------------------
    def feed(self, item: Frame | GeoFix | ImuSample | CameraIntrinsics) -> list[FrameRecord]:
        """Feed one input; return the frame records decided by it (none, one or several).

        A CameraIntrinsics (live: from CameraInfo) becomes the camera of frames that carry none.
        """
        if isinstance(item, CameraIntrinsics):
            self.camera = item
            return []
        if isinstance(item, Frame):
            self._waiting.append(item)
            return self._drain()
        if isinstance(item, GeoFix):
            self.fixes.append(item)
            if self.georef is None and self.config.georef_enabled:
                self.georef = Georeferencer(self.config.georef)
                # the attitudes seen before the first fix (the filter starts from the nearest one)
                since = item.stamp_ns - int(self.config.georef.telemetry_buffer_s * 1e9)
                for earlier in sorted((t for t in (*self.imus, *self.attitudes) if t.stamp_ns >= since),
                                      key=lambda t: t.stamp_ns):
                    if isinstance(earlier, ImuSample):
                        self.georef.feed_imu(earlier)
                    else:
                        self.georef.feed_camera_attitude(earlier)
            if self.georef is not None:
                with self.clock.stage('fuse'):
                    self.georef.feed_fix(item)
        elif isinstance(item, ImuSample):
            self.imus.append(item)
            if self.georef is not None:
                with self.clock.stage('fuse'):
                    self.georef.feed_imu(item)
        elif isinstance(item, CameraAttitude):
            self.attitudes.append(item)
            if self.georef is not None:
                with self.clock.stage('fuse'):
                    self.georef.feed_camera_attitude(item)
        else:
            msg = f'Pipeline.feed takes Frame, GeoFix, ImuSample or CameraAttitude, not {type(item).__name__}.'
            raise TypeError(msg)
        self._latest_telemetry_ns = max(self._latest_telemetry_ns or item.stamp_ns, item.stamp_ns)
        return self._drain()

    def _awaiting_first_fix(self) -> bool:
        """True while the frames waiting should go on waiting for the flight's first fix."""
        if self._first_fix_wait_over:
            return False
        if self.georef is not None or not self.config.georef_enabled or not self._waiting:
            self._first_fix_wait_over = self.georef is not None or not self.config.georef_enabled
            return False
        span_ns = self._waiting[-1].stamp_ns - self._waiting[0].stamp_ns
        if len(self._waiting) > FIRST_FIX_HOLD_FRAMES or span_ns > self.config.georef.telemetry_buffer_s * 1e9:
            self._first_fix_wait_over = True  # no fix in time: the flight goes on without (a later one still joins)
            return False
        return True

    def feed_frame(self, frame: Frame) -> list[FrameRecord]:
        """Process a frame now, without waiting for telemetry (e.g. inputs without any)."""
        return self._process(frame)

    def _drain(self, *, all_frames: bool = False) -> list[FrameRecord]:
        """Process the waiting frames whose telemetry has arrived (approximate-time association)."""
        decided: list[FrameRecord] = []
        if not all_frames and self._awaiting_first_fix():
            return decided
        while self._waiting:
            frame = self._waiting[0]
            if not (all_frames or telemetry_ready(frame.stamp_ns, self._latest_telemetry_ns, len(self._waiting))):
                break
            decided += self._process(self._waiting.pop(0))
        return decided

    def _paint_input(self, raw: np.ndarray, seg_H_frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(image, seg_H_image) to paint for a frame: a frame much finer than the mosaic is averaged
        down to the mosaic's sampling first, on its integer pixels (minify.area_reduce). float32,
        or uint8 as it came when its channels are the canvas's (the canvas warps integers faster)."""
        k = self._area_factor(raw, seg_H_frame)
        if k == 1:
            return self._as_paintable(raw), seg_H_frame
        if raw.dtype == np.uint8:
            small, seg_H_small = area_reduce(raw, seg_H_frame, k)
            return self._as_paintable(small), seg_H_small
        small, seg_H_small = area_reduce(self._as_canvas_image(raw), seg_H_frame, k)
        return np.ascontiguousarray(small, dtype=np.float32), seg_H_small

    def _area_factor(self, image: np.ndarray, seg_H_frame: np.ndarray) -> int:
        """The block size (minify.area_factor) a frame at seg_H_frame is averaged down by before it is painted."""
        h, w = image.shape[:2]
        return area_factor(finest_stretch(seg_H_frame, w, h, clip_depth(seg_H_frame, w, h, self.config.mosaic.max_stretch)))

    def _as_paintable(self, image: np.ndarray) -> np.ndarray:
        """A uint8 image with the canvas's channel count as it is, else :meth:`_as_canvas_image`."""
        if image.dtype == np.uint8 and (image.shape[2] if image.ndim == 3 else 1) == (self._channels or 0):
            return image
        return self._as_canvas_image(image)

    def _as_canvas_image(self, image: np.ndarray) -> np.ndarray:
        """Edge image -> float32 (H, W, C) in [0, 1] with the channel count of the first frame. A uint8
        image is converted into this thread's scratch array 'frame' (core.mosaic.scratch): valid until
        the next conversion on the thread, so only for the canvas's paint, which keeps no reference."""
        if image.dtype == np.uint8:  # to_float01's values, without a fresh full-frame array per frame
            f = np.multiply(image, np.float32(1.0 / 255.0), out=scratch('frame', image.shape), dtype=np.float32)
        else:
            f = to_float01(image)
        if f.ndim == 2:
            f = f[:, :, None]
        if self._channels is None:
            self._channels = f.shape[2]
        if f.shape[2] != self._channels:
            f = np.repeat(f, 3, axis=2) if f.shape[2] == 1 else f.mean(axis=2, keepdims=True)
        return np.ascontiguousarray(f, dtype=np.float32)

    # -- placement -------------------------------------------------------------------------------
    def _georeferenced_start(self, held: _Held) -> np.ndarray | None:
        """seg_H_frame on the shared raster for the first frame of a segment, when its pose is valid."""
        pose, camera = held.record.pose, held.camera
        if self.georef is None or pose is None or not pose.valid or camera is None:
            return None
        if self.pose_check is not None and not self.pose_check.used:  # the assumed attitude was refused
            return None
        if self.georef.raster is None:
            self.georef.make_raster(pose, camera, coarsen=1.0 / self._plane_scale(held.record.size[0]))
        self.georef.reset_drift()
        # the first drift-control call of a chain anchors it (returned unchanged) with this frame's pose
        return self.georef.correct(self.georef.raster_H_frame(pose, camera), pose, camera)

    def _start_segment(self, held: _Held) -> Segment:
        self._settle()  # the previous segment's first frames, if still held
        start = self._georeferenced_start(held)
        shared = self._geo_canvas.canvas if (start is not None and self._geo_canvas is not None) else None
        seg = Segment.create(len(self.segments), self._channels or 1, self.config.mosaic, canvas=shared)
        seg.georeferenced = start is not None
        if seg.georeferenced and self._geo_canvas is None:
            self._geo_canvas = seg
        self.segments.append(seg)
        if seg.georeferenced and self.config.mosaic.settle_s > 0 and self.config.mosaic.settle_max_frames > 1:
            self._settling_seg = seg
            self._place(seg, held, start)
        else:
            if start is None:  # the segment's plane: its first frame's pixels, scaled to mosaic.max_width
                s = self._plane_scale(held.record.size[0])
                start = np.diag([s, s, 1.0])
            self._paint(seg, held, start)
        return seg

    def _plane_scale(self, width: int) -> float:
        """Mosaic pixels per frame pixel of a segment's first frame, ``width`` px wide (mosaic.max_width)."""
        max_width = self.config.mosaic.max_width
        return 1.0 if max_width <= 0 or width <= max_width else max_width / width

    def _chained(self, seg: Segment, prev_seg_H_frame: np.ndarray, reg: Registration, held: _Held) -> np.ndarray:
        """seg_H_frame of a registered frame: the chain (4.6), with drift control on the raster."""
        chained = prev_seg_H_frame @ reg.prev_H_cur
        pose = held.record.pose
        if not seg.georeferenced or self.georef is None or pose is None or not pose.valid or held.camera is None:
            return chained
        with self.clock.stage('fuse'):
            corrected = self._drift_corrected(chained, reg, pose, held)
        if seg is self._settling_seg and seg is self._geo_canvas and self.pose_check is None:
            self._settling_nis.append(self.georef.drift_nis)  # evidence for _poses_refused
        return corrected

    def _drift_corrected(self, chained: np.ndarray, reg: Registration, pose: FramePose, held: _Held) -> np.ndarray:
        """The chained seg_H_frame pulled toward the pose-predicted placement (drift control)."""
        assert self.georef is not None and held.camera is not None
        if reg.covariance is not None:
            sigma = self.georef.corner_sigma_px(reg.prev_H_cur, reg.covariance)
        else:
            # Without a covariance: least-squares corner error from the inlier residuals, about
            # rms * sqrt(8 / inliers) (8 parameters) times 2 for the extrapolation to the corners.
            sigma = 2.0 * reg.rms_px * math.sqrt(8.0 / max(reg.inliers, 8))
        return self.georef.correct(chained, pose, held.camera, chain_sigma_px=sigma)

    def _keyframe(self, seg: Segment, held: _Held, seg_H_frame: np.ndarray) -> np.ndarray:
        """seg_H_frame, corrected by registering the frame to the mosaic when it is a keyframe (keyframe.py)."""
        cfg = self.config.mosaic
        if cfg.keyframe_interval <= 0 or len(seg.frames) % cfg.keyframe_interval != 0:
            return seg_H_frame
        w, h = held.record.size
        if cfg.keyframe_revisit_frames > 0 and not self._revisits(seg, seg_H_frame, w, h):
            return seg_H_frame
        with self.clock.stage('register'):
            result = self._register_to_mosaic(seg, held, seg_H_frame)
        held.record.keyframe = result
        if result.seg_H_frame is None:
            return seg_H_frame
        self._spread_back(seg, held, seg_H_frame, result.seg_H_frame)
        return result.seg_H_frame

    def _spread_back(self, seg: Segment, held: _Held, predicted: np.ndarray, corrected: np.ndarray) -> None:
        """The frames of ``seg`` placed after the last anchor and not painted yet take their share of
        the keyframe's correction (revisit.py); the keyframe becomes the anchor."""
        back = [h for s, h, _ in self._unpainted if s is seg and h.record.index > self._anchor
                and h.record.seg_H_frame is not None]
        self._anchor = held.record.index
        if not back:
            return
        moved, shifts = spread_correction([h.record.seg_H_frame for h in back], [h.record.size for h in back],
                                          predicted, corrected)
        for h, m, shift in zip(back, moved, shifts, strict=True):
            h.record.seg_H_frame = m
            h.record.corrected_px = float(shift)
            seg.seg_H_frames[h.record.index] = m
        known = self._footprints.get(seg.index)
        if known:  # _revisits' footprints of the moved frames: computed again
            del known[seg.frames.index(back[0].record.index):]

    def _register_to_mosaic(self, seg: Segment, held: _Held, seg_H_frame: np.ndarray) -> KeyframeResult:
        """The keyframe's registration to the mosaic rendered where the chain puts it."""
        cfg = self.config.mosaic
        w, h = held.record.size
        self.sync()
        view, covered = render_view(seg.canvas, seg_H_frame, w, h, gray=True)
        coverage = float(covered.mean())
        if coverage < cfg.keyframe_min_coverage:
            result = KeyframeResult(None, coverage, float('nan'), f'mosaic covers {coverage:.0%} of the view')
        else:
            # Optional refinement: no OpenCV second opinion (its SIFT on both images would cost a
            # live node several frame periods, and a failed keyframe changes nothing).
            extra = {'second_opinion': False} if getattr(self.registrar, 'has_second_opinion', False) else {}
            reg = self.registrar.register(self.registrar.describe(view), held.features, **extra)
            if not reg.ok:
                result = KeyframeResult(None, coverage, float('nan'), f'registration to the mosaic failed: {reg.reason}')
            else:
                refined = seg_H_frame @ reg.prev_H_cur
                shift = corner_shift_px(seg_H_frame, refined, w, h)
                if shift > cfg.keyframe_max_correction_px:
                    result = KeyframeResult(None, coverage, shift, f'correction of {shift:.1f} px refused')
                elif shift < cfg.keyframe_min_correction_px:  # within the noise of the rendered reference
                    result = KeyframeResult(None, coverage, shift, f'correction of {shift:.1f} px below the minimum')
                else:
                    result = KeyframeResult(refined / refined[2, 2], coverage, shift)
        return result

    def _revisits(self, seg: Segment, seg_H_frame: np.ndarray, w: int, h: int) -> bool:
        """Whether the frame flies over ground an earlier pass painted: its predicted centre lies within
        half its smaller side of the centre of a frame painted at least mosaic.keyframe_revisit_frames
        frames earlier that is not part of the current pass (the unbroken run just before it of
        frames centred nearby and facing the same way, within PASS_TURN_DEG). At a high frame rate a
        straight pass keeps overlapping frames many frames back; those are not a revisit, and
        registering to the mosaic there costs a live node a frame period for nothing the chain does
        not already have. An orbit looking at its centre keeps every footprint there and turns: once
        it has turned, the frames before the turn are an earlier pass over the same ground."""
        n = len(seg.frames)
        gap = self.config.mosaic.keyframe_revisit_frames
        if n <= gap:
            return False
        now = footprint_pose(seg_H_frame, w, h)
        # Footprints of the segment's painted frames, computed once each (long flights: O(1) per frame).
        known = self._footprints.setdefault(seg.index, [])
        known.extend(footprint_pose(seg.seg_H_frames[i], w, h) for i in seg.frames[len(known):])
        done = np.asarray(known)
        near = np.linalg.norm(done[:, :2] - now[:2], axis=1) < 0.5 * min(w, h)
        turn = np.abs(np.angle(np.exp(1j * (done[:, 2] - now[2]))))
        same_pass = near & (turn < math.radians(PASS_TURN_DEG))
        run = n
        while run > 0 and same_pass[run - 1]:
            run -= 1
        return bool(near[:min(run, n - gap)].any())

    def _paint(self, seg: Segment, held: _Held, seg_H_frame: np.ndarray) -> bool:
        """Place the frame in ``seg`` at seg_H_frame and paint it: now, on the painter thread, or
        mosaic.revisit_spread_frames frames later. False when the placement is refused (the record says why)."""
        record = held.record
        if self._painter is None and self.config.mosaic.revisit_spread_frames == 0 and self._thin.stride == 1:
            with self.clock.stage('paint'):
                try:
                    seg.canvas.check_placement(seg_H_frame, *record.size)
                    seg.canvas.paint(*self._paint_input(held.raw, seg_H_frame), finite=held.raw.dtype == np.uint8)
                except CanvasError as exc:  # absurd footprint: refuse, never allocate a giant canvas
                    record.reason = f'not painted: {exc}'
                    return False
                seg.place(record.index, seg_H_frame)
            record.segment = seg.index
            record.seg_H_frame = seg_H_frame
            return True
        try:  # placed now, painted later: the placement is checked and recorded now
            seg.canvas.check_placement(seg_H_frame, *record.size)
        except CanvasError as exc:
            record.reason = f'not painted: {exc}'
            return False
        seg.place(record.index, seg_H_frame)
        record.segment = seg.index
        record.seg_H_frame = seg_H_frame
        if self.config.mosaic.revisit_spread_frames == 0:
            self._paint_pixels(seg, held)
        else:  # held at the mosaic's sampling: N frames of a 4K stream would take gigabytes as they came
            frame_H_image = np.eye(3)
            k = self._area_factor(held.raw, seg_H_frame) if held.raw.dtype == np.uint8 else 1
            if k > 1:
                held.raw, frame_H_image = area_reduce(held.raw, frame_H_image, k)
            self._unpainted.append((seg, held, frame_H_image))
            self._paint_unpainted(keep=self.config.mosaic.revisit_spread_frames)
        return True

    def _paint_unpainted(self, keep: int = 0) -> None:
        """Paint the oldest frames held by revisit spreading until ``keep`` remain; their records are decided."""
        while len(self._unpainted) > keep:
            seg, held, frame_H_image = self._unpainted.popleft()
            if held.record.seg_H_frame is not None:
                self._paint_pixels(seg, held, frame_H_image)
            self._settled.append(held.record)

    def _paint_pixels(self, seg: Segment, held: _Held, frame_H_image: np.ndarray | None = None) -> None:
        """Paint a placed frame (its raw image, at its record's seg_H_frame @ frame_H_image), on the
        painter thread when there is one, unless the paint thinning holds it back (core/mosaic/thinning.py:
        then it is painted later where it sees what its painted neighbours do not, or whole at the end
        of its segment). A paint refused after all (the canvas grew meanwhile) unplaces it, as if never
        placed."""
        if self._thin.stride == 1:
            self._paint_now(seg, held, frame_H_image)
            return
        m, (w, h) = held.record.seg_H_frame, held.record.size
        u = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
        corners, _ = project_points(m, u)
        footprint, _ = project_points(m, clipped_polygon(m, u, clip_depth(m, w, h, self.config.mosaic.max_stretch)))
        # only a near-nadir view is left to its neighbours: an oblique one sees relief and the far
        # field from its own angle (the karma clip thinned throughout: consistency p10 0.83 -> 0.81)
        oblique = corner_depth_ratio(m, w, h) > THIN_MAX_DEPTH_RATIO
        for (s, hd, f_H_i), tiles in self._thin.offer(seg.index, (seg, held, frame_H_image), corners, footprint,
                                                      force=oblique):
            self._paint_now(s, hd, f_H_i, tiles)

    def _paint_held_back(self) -> None:
        """Paint the frames the paint thinning holds back (the last of each segment)."""
        for (seg, held, frame_H_image), tiles in self._thin.release():
            self._paint_now(seg, held, frame_H_image, tiles)

    def _paint_now(self, seg: Segment, held: _Held, frame_H_image: np.ndarray | None = None,
                   tiles: dict[tuple[int, int], tuple[int, int, int, int]] | None = None) -> None:
        record, raw = held.record, held.raw
        seg_H_frame = record.seg_H_frame if frame_H_image is None else record.seg_H_frame @ frame_H_image

        def paint() -> None:
            with self.clock.stage('paint'):
                try:
                    seg.canvas.paint(*self._paint_input(raw, seg_H_frame), finite=raw.dtype == np.uint8,  # from uint8: finite
                                     tiles=tiles)
                except CanvasError as exc:
                    seg.unplace(record.index)
                    record.segment, record.seg_H_frame = -1, None
                    record.reason = f'not painted: {exc}'

        if self._painter is not None:
            self._painter.submit(paint)
        else:
            paint()

    def sync(self) -> None:
        """Wait for the frames being painted on the painter thread (paint_thread=True): the canvases
        are complete after this. Raises the error of a paint that failed."""
        if self._painter is not None:
            self._painter.wait()  # (the painter counts its own time)

    # -- one frame -----------------------------------------------------------------------------
    def _fuse(self, held: _Held, reg: Registration | None, ref: _Held | None) -> None:
        """Feed the georeferencing filter with this frame (and its registration when it placed it)."""
        if self.georef is None:
            return
        use = reg is not None and reg.ok and ref is not None
        self._fused.append(held.record)
        with self.clock.stage('fuse'):
            held.record.pose = self.georef.feed_frame(
            held.record.stamp_ns, reg.prev_H_cur if use else None, reg.covariance if use else None,
                rms_px=reg.rms_px if use else float('nan'), inliers=reg.inliers if use else 0, camera=held.camera,
                ref_stamp_ns=ref.record.stamp_ns if use else None)

    def _process(self, frame: Frame) -> list[FrameRecord]:
        t0 = time.perf_counter()
        # a camera with lens distortion: from here on the frame is that of its pinhole camera
        # (core/undistort.py); an unusable distortion model raises InputError before any record
        with self.clock.stage('undistort'):
            frame = self.undistorter.frame(frame, self.camera)
        h, w = frame.image.shape[:2]
        record = FrameRecord(len(self.records), frame.stamp_ns, (w, h))
        self.records.append(record)
        if h < 8 or w < 8:
            record.reason = f'frame of {w}x{h} pixels is too small to register'
            record.time_s = time.perf_counter() - t0
            return [record]
        with self.clock.stage('describe'):
            # keypoints only when a registration needs them (frames that are tracked need none)
            features = self.registrar.describe(frame.image, keypoints=False) if self._tracking() else \
                self.registrar.describe(frame.image)
        if self._channels is None:  # the canvas's, from the first frame (later ones are converted to it)
            self._channels = 1 if frame.image.ndim == 2 else frame.image.shape[2]
        held = _Held(features, record, frame.camera or self.camera, frame.image)
        record.camera = held.camera
        decided = [record]
        if self._last_good is not None and self._last_good.record.seg_H_frame is None:
            # its placement was refused after it became the chain's base (painted when its segment
            # settled, or on the painter thread, into a canvas grown meanwhile): start anew
            self._last_good = None
        if self._last_good is None:
            self._fuse(held, None, None)
            self._active = self._start_segment(held)
            if record.seg_H_frame is not None:  # placed (its placement refused: the next frame starts anew)
                self._last_good = held
        else:
            last = self._last_good
            with self.clock.stage('register'):
                reg = self._register_next(last, held)
            record.registration = reg
            self._fuse(held, reg, last)
            if reg.ok and self._place(self._active, held, self._keyframe(
                    self._active, held, self._chained(self._active, last.record.seg_H_frame, reg, held))):
                self._tracker.placed(reg, last.record.index, last.record.stamp_ns, record.index, record.stamp_ns)
                self._last_good = held
                self._orphan = None
            elif self._orphan is not None and self._try_new_segment(held):
                decided.insert(0, self._orphan.record)
                self._orphan = None
            else:
                self._tracker.lost()
                record.reason = record.reason or reg.reason
                self._orphan = held
        record.time_s = time.perf_counter() - t0
        self._heap.tick()
        settled = self._take_settled()
        later = {id(r) for r in settled} | {id(h.record) for h in self._settling} | {id(h.record) for _, h, _ in self._unpainted}
        return settled + [r for r in decided if id(r) not in later]

    def _try_new_segment(self, held: _Held) -> bool:
        """Register `held` to the orphan; on success the orphan starts a new segment holding both."""
        orphan = self._orphan
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
        if not self._place(seg, held, self._chained(seg, orphan.record.seg_H_frame, reg, held)):
            return False
        self._active = seg
        self._last_good = held
        self._tracker.placed(reg, orphan.record.index, orphan.record.stamp_ns, held.record.index, held.record.stamp_ns)
        return True

    def _tracking(self) -> bool:
        """Whether frames may be registered by tracking: the setting, and a registrar that tracks
        (the opencv backend does not; tests may put their own registrar in place)."""
        return self._tracker.frames > 1 and getattr(self.registrar, 'tracks', False)

    def _register_next(self, last: _Held, held: _Held) -> Registration:
        """``held`` registered to the last placed frame: tracked from the previous pair's motion when
        the tracker predicts it and the tracking is accepted, otherwise by features
        (extras['track_refused'] = 1 when tracking was tried first)."""
        predicted = self._tracker.prediction(last.record.index, last.record.stamp_ns, held.record.index,
                                             held.record.stamp_ns) if self._tracking() else None
        if predicted is not None:
            tracked = self.registrar.track(last.features, held.features, predicted, max_rms=self._tracker.max_rms())
            if tracked.ok:
                return tracked
        reg = self.registrar.register(last.features, held.features)
        if predicted is not None:
            reg.extras['track_refused'] = 1.0
        return reg

    def flush(self, *, paint_held: bool = True) -> list[FrameRecord]:
        """Process every frame still waiting for telemetry (live: when telemetry stopped coming) and
        paint the frames held for settling: every frame held back is decided. ``paint_held`` False
        keeps the frames held for revisit corrections (a live input's short pause)."""
        decided = self._drain(all_frames=True)
        self._settle()
        if paint_held:
            self._paint_unpainted()
            self._paint_held_back()
        self.sync()
        return decided + self._take_settled()

    @property
    def waiting(self) -> int:
        """Frames waiting for telemetry at or after their stamp."""
        return len(self._waiting)

    @property
    def held_back(self) -> int:
        """Frames not decided yet: waiting for telemetry, placed and held for settling, or placed and
        not painted yet (revisit spreading)."""
        return len(self._waiting) + len(self._settling) + len(self._unpainted)

    @property
    def max_decision_lag_frames(self) -> int:
        """How many frames later than its own a frame's record may be returned, at most."""
        cfg = self.config.mosaic
        first_fix = FIRST_FIX_HOLD_FRAMES if self.config.georef_enabled else 0
        return (max(SYNC_HOLD_FRAMES, first_fix) + 3 + (cfg.settle_max_frames if cfg.settle_s > 0 else 0)
                + cfg.revisit_spread_frames)

    def take_fused(self) -> list[FrameRecord]:
        """Records whose fused pose (record.pose) was computed since the last call, in order; a frame
        held for settling is decided later, but its pose is ready now (live: publish it at once)."""
        out = list(self._fused)
        self._fused.clear()
        return out

    def finish(self) -> PipelineResult:
        """Process the frames still waiting for telemetry, paint those held for settling, and return everything."""
        self.flush()
        return PipelineResult(self.records, self.segments, self.fixes, self.imus, self.georef, self.attitudes,
                              pose_check=self.pose_check, attitude_check=self.attitude_check,
                              frames_thinned=self._thin.thinned,
                              frames_painted_in_part=self._thin.in_part)

    # -- settling --------------------------------------------------------------------------------
    def _place(self, seg: Segment, held: _Held, seg_H_frame: np.ndarray) -> bool:
        """Paint the frame now, or hold it while its segment settles (module docstring)."""
        if seg is not self._settling_seg:
            return self._paint(seg, held, seg_H_frame)
        try:  # refused now, as painting it would be: an absurd placement must not become the chain's base
            seg.canvas.check_placement(seg_H_frame, *held.record.size)
        except CanvasError as exc:
            held.record.reason = f'not painted: {exc}'
            return False
        held.record.seg_H_frame = seg_H_frame  # provisional: drift control chains the next frame from it
        self._settling.append(held)
        cfg = self.config.mosaic
        span_s = (held.record.stamp_ns - self._settling[0].record.stamp_ns) * 1e-9
        if span_s >= cfg.settle_s or len(self._settling) >= cfg.settle_max_frames:
            self._settle()
        return True

    def _settle(self) -> None:
        """Place the held frames back from the newest through their registrations, and paint them."""
        held, seg = self._settling, self._settling_seg
        self._settling, self._settling_seg = [], None
        if not held or seg is None:
            return
        chained = self._chained_from_first(held)  # the frames' mount shows in it; their placement if refused
        if self._poses_refused(seg, held, chained):
            placed = chained
        else:
            placed = [held[-1].record.seg_H_frame]
            for k in range(len(held) - 2, -1, -1):
                rel = held[k + 1].record.registration.prev_H_cur  # frame k+1 -> frame k (its last good frame)
                h = placed[-1] @ np.linalg.inv(rel)
                placed.append(h / h[2, 2])
            placed.reverse()
        for h_k, frame in zip(placed, held, strict=True):
            if not self._paint(seg, frame, h_k):
                frame.record.seg_H_frame = None
            if not any(h is frame for _, h, _ in self._unpainted):  # else decided when painted
                self._settled.append(frame.record)

    def _poses_refused(self, seg: Segment, held: list[_Held], chained: list[np.ndarray]) -> bool:
        """Decide pose_check when ``seg``, the first georeferenced segment, settles with ``held`` its
        frames, ``chained`` their _chained_from_first (module docstring); True when its frames must not be placed by their poses: then the
        segment, not painted yet, becomes an ordinary one in its first frame's plane and no later one
        is georeferenced. With a measured attitude nothing is decided; it is compared with the
        frames' instead (_check_attitude)."""
        nis, self._settling_nis = self._settling_nis, []
        if seg is not self._geo_canvas or self.pose_check is not None or self.attitude_check is not None:
            return False
        if self._attitude_measured():
            self._check_attitude(held, chained)
            return False
        g = self.config.georef
        self.pose_check = check_pose_placement(nis, g.gate_probability, (g.gimbal_azimuth_deg, g.gimbal_elevation_deg),
                                               self._mount_shown(held, chained), len(self.attitudes))
        if self.pose_check is None or self.pose_check.used:
            return False
        if held[0].camera is not None:
            self.pose_check = self.pose_check.with_mount_to_try(held[0].camera.K)
        mount = self.pose_check.mount_to_try
        _LOG.warning('the frames are not placed by the filter\'s poses: %s. They are chained in the first frame\'s plane '
                     'as without intrinsics, and the mosaic is georeferenced afterwards by its geotags if they can place '
                     'it (not when its frames look obliquely). To place them '
                     'on the map through the filter, give the camera attitude (an Imu orientation, gimbal angles) or '
                     'the mount it is fixed at (%s).', self.pose_check.reason,
                     f'the frames\' own: georef.gimbal_elevation_deg: {mount[1]:g}, georef.gimbal_azimuth_deg: {mount[0]:g}'
                     if mount is not None else 'georef.gimbal_elevation_deg, georef.gimbal_azimuth_deg')
        seg.georeferenced = False
        self._geo_canvas = None
        self.georef.drop_raster()
        return True

    @staticmethod
    def _mount_shown(held: list[_Held], chained: list[np.ndarray]) -> MountEstimate | None:
        """The camera mount the held frames' chain (``chained``, in the first one's plane) shows
        (chain_mount.py), None when it cannot tell."""
        if any(frame.camera is None for frame in held):
            return None
        first_from_plane = np.linalg.inv(chained[0])
        return mount_from_chain([first_from_plane @ h for h in chained], [frame.camera.K for frame in held])

    def _check_attitude(self, held: list[_Held], chained: list[np.ndarray]) -> None:
        """Compare the camera elevation the held frames show with the measured camera attitudes of
        their time (pose_check.check_measured_attitude); warn when they disagree. The poses still
        place the frames: the measurement is not overruled by the frames' estimate."""
        t0, t1 = held[0].record.stamp_ns - 1_000_000_000, held[-1].record.stamp_ns + 1_000_000_000
        measured = [math.degrees(math.asin(float(np.clip(a.R_enu_from_cam[2, 2], -1.0, 1.0))))
                    for a in self.attitudes if t0 <= a.stamp_ns <= t1 and sees_the_ground(a.R_enu_from_cam)]
        self.attitude_check = check_measured_attitude(self._mount_shown(held, chained), measured)
        check = self.attitude_check
        if check is not None and not check['agrees']:
            _LOG.warning('the frames show the camera looking %s where its measured attitude says %s (%g deg apart, '
                         'report.json attitude_check): check the attitude source and its convention (angles relative to '
                         'the body, not to the horizon; a sign; another axis order); the frames are placed by the '
                         'measured attitude.', horizon_words(check['frames_elevation_deg']),
                         horizon_words(check['measured_elevation_deg']), check['difference_deg'])

    def _attitude_measured(self) -> bool:
        """Whether the input measured the camera's attitude (an Imu orientation, or a camera attitude
        the filter can use, not one at the horizon, so far): then the filter's orientation is not only
        the assumed mount."""
        return any(sees_the_ground(a.R_enu_from_cam) for a in self.attitudes) or \
            any(imu.orientation_xyzw is not None for imu in self.imus)

    def _chained_from_first(self, held: list[_Held]) -> list[np.ndarray]:
        """seg_H_frame of each held frame in the first one's pixel plane (scaled to mosaic.max_width),
        through their registrations: what a segment without georeferencing gives (_start_segment)."""
        s = self._plane_scale(held[0].record.size[0])
        placed = [np.diag([s, s, 1.0])]
        for frame in held[1:]:
            placed.append(placed[-1] @ frame.record.registration.prev_H_cur)  # frame k -> frame k-1
        return placed

    def _take_settled(self) -> list[FrameRecord]:
        out = self._settled
        self._settled = []
        return out

    def close(self) -> None:
        """Finish the paints in flight and stop the painter thread (the pipeline stays usable, painting
        in the caller's thread)."""
        if self._painter is not None:
            painter, self._painter = self._painter, None
            painter.close()

    def state(self) -> dict[str, Any]:
        """What a resumed run needs (checkpoints: app/checkpoint.py), by name: STATE_VERSION, the
        config, and the attributes of _STATE (records, segments with their canvases, telemetry, the
        filter, the frames held for registration, for telemetry and while their segment settles,
        the stage clock). The registrar, undistorter and painter thread are rebuilt from the config
        (they hold nothing between frames). Paints in flight are finished first."""
        self.sync()
        return {'version': STATE_VERSION, 'config': self.config, **{name: getattr(self, name) for name in _STATE}}

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
        pipe = cls(state['config'], paint_thread=paint_thread)
        for name in _STATE:
            if name in state:  # a state written before _STATE_NEWER's attributes keeps their fresh values
                setattr(pipe, name, state[name])
        return pipe
