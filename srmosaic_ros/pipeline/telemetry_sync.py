"""Frames and telemetry associated by time, and the georeferencing filter they feed.

Approximate-time synchronisation (core/time_sync.py): a frame waits until telemetry at or after its
stamp has been seen (or until SYNC_HOLD_FRAMES more frames arrived with no telemetry at all), so the
filter always has the fixes and IMU samples that precede it. Before the flight's first GNSS fix,
frames wait for one (at most FIRST_FIX_HOLD_FRAMES of them, spanning at most
georef.telemetry_buffer_s), so that a flight whose first fixes are late still starts its mosaic on
the map. The Georeferencer (with georef.enabled) exists from the start and is fed every telemetry
message as it comes; until a valid fix gives it an origin it keeps the IMU samples and camera
attitudes of the last telemetry_buffer_s (the filter starts from the nearest one), and frames are
fused only once the flight's first fix has arrived.
"""
from __future__ import annotations

import collections
import math
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from ..config import PipelineConfig
from ..core.georef.georeferencer import Georeferencer, sees_the_ground
from ..core.registration import Registration
from ..core.stage_clock import StageClock
from ..core.time_sync import telemetry_ready
from ..core.types import CameraAttitude, CameraIntrinsics, Frame, GeoFix, ImuSample
from .checkpointed import Checkpointed
from .records import FrameRecord, Held

__all__ = ['FIRST_FIX_HOLD_FRAMES', 'TelemetrySync']

#: Frames kept waiting for the flight's first GNSS fix, at most (module docstring).
FIRST_FIX_HOLD_FRAMES = 32


class TelemetrySync(Checkpointed):
    """Telemetry kept and fed to the filter; frames queued until their telemetry has arrived."""

    STATE = (('fixes', 'fixes'), ('imus', 'imus'), ('attitudes', 'attitudes'), ('georef', 'georef'),
             ('camera', 'camera'), ('_waiting', 'waiting'), ('_first_fix_wait_over', 'first_fix_wait_over'),
             ('_latest_telemetry_ns', 'latest_telemetry_ns'), ('_fused', 'fused'))

    def __init__(self, config: PipelineConfig, clock: StageClock) -> None:
        self.config = config
        self.clock = clock
        self.fixes: list[GeoFix] = []
        self.imus: list[ImuSample] = []
        self.attitudes: list[CameraAttitude] = []
        self.georef = Georeferencer(config.georef) if config.georef_enabled else None  # no origin until a valid fix
        self.camera: CameraIntrinsics | None = None  # live: from CameraInfo, for frames that carry none
        self.waiting: list[Frame] = []
        self.first_fix_wait_over = False
        self.latest_telemetry_ns: int | None = None
        self.fused: collections.deque[FrameRecord] = collections.deque(maxlen=1000)  # poses not taken yet

    def feed(self, item: Frame | GeoFix | ImuSample | CameraAttitude | CameraIntrinsics) -> None:
        """Keep one input: a frame joins the queue, telemetry goes to the filter; TypeError for others."""
        if isinstance(item, CameraIntrinsics):
            self.camera = item
            return
        if isinstance(item, Frame):
            self.waiting.append(item)
            return
        if isinstance(item, GeoFix):
            self.fixes.append(item)
            self._to_filter(Georeferencer.feed_fix, item)
        elif isinstance(item, ImuSample):
            self.imus.append(item)
            self._to_filter(Georeferencer.feed_imu, item)
        elif isinstance(item, CameraAttitude):
            self.attitudes.append(item)
            self._to_filter(Georeferencer.feed_camera_attitude, item)
        else:
            msg = f'Pipeline.feed takes Frame, GeoFix, ImuSample or CameraAttitude, not {type(item).__name__}.'
            raise TypeError(msg)
        self.latest_telemetry_ns = max(self.latest_telemetry_ns or item.stamp_ns, item.stamp_ns)

    def _to_filter(self, update: Callable[[Georeferencer, Any], object], item: GeoFix | ImuSample | CameraAttitude) -> None:
        if self.georef is not None:
            with self.clock.stage('fuse'):
                update(self.georef, item)

    def ready(self, *, all_frames: bool = False) -> Iterator[Frame]:
        """The waiting frames whose telemetry has arrived (every one with ``all_frames``), oldest first,
        each taken off the queue as it is yielded."""
        if not all_frames and self._awaiting_first_fix():
            return
        while self.waiting:
            frame = self.waiting[0]
            if not (all_frames or telemetry_ready(frame.stamp_ns, self.latest_telemetry_ns, len(self.waiting))):
                return
            yield self.waiting.pop(0)

    def _awaiting_first_fix(self) -> bool:
        """True while the frames waiting should go on waiting for the flight's first fix."""
        if self.first_fix_wait_over:
            return False
        if self.fixes or not self.config.georef_enabled or not self.waiting:
            self.first_fix_wait_over = bool(self.fixes) or not self.config.georef_enabled
            return False
        span_ns = self.waiting[-1].stamp_ns - self.waiting[0].stamp_ns
        if len(self.waiting) > FIRST_FIX_HOLD_FRAMES or span_ns > self.config.georef.telemetry_buffer_s * 1e9:
            self.first_fix_wait_over = True  # no fix in time: the flight goes on without (a later one still joins)
            return False
        return True

    def fuse(self, held: Held, reg: Registration | None, ref: Held | None) -> None:
        """Feed the filter with this frame (and its registration to ``ref`` when it placed it); its
        fused pose becomes ``held.record.pose`` and is queued for take_fused. Frames before the flight's
        first fix message are not fed (no pose, as without georeferencing)."""
        if self.georef is None or not self.fixes:
            return
        use = reg is not None and reg.ok and ref is not None
        self.fused.append(held.record)
        with self.clock.stage('fuse'):
            held.record.pose = self.georef.feed_frame(
                held.record.stamp_ns, reg.prev_H_cur if use else None, reg.covariance if use else None,
                rms_px=reg.rms_px if use else float('nan'), inliers=reg.inliers if use else 0, camera=held.camera,
                ref_stamp_ns=ref.record.stamp_ns if use else None)

    def take_fused(self) -> list[FrameRecord]:
        """Records whose fused pose was computed since the last call, in order."""
        out = list(self.fused)
        self.fused.clear()
        return out

    def attitude_measured(self) -> bool:
        """Whether the input measured the camera's attitude (an Imu orientation, or a camera attitude
        the filter can use, not one at the horizon, so far): then the filter's orientation is not only
        the assumed mount."""
        return any(sees_the_ground(a.R_enu_from_cam) for a in self.attitudes) or \
            any(imu.orientation_xyzw is not None for imu in self.imus)

    def measured_elevations_deg(self, t0_ns: int, t1_ns: int) -> list[float]:
        """Camera elevations (deg, negative below the horizon: asin of the optical axis's up component)
        of the measured attitudes stamped in [t0_ns, t1_ns] that see the ground."""
        return [math.degrees(math.asin(float(np.clip(a.R_enu_from_cam[2, 2], -1.0, 1.0))))
                for a in self.attitudes if t0_ns <= a.stamp_ns <= t1_ns and sees_the_ground(a.R_enu_from_cam)]
