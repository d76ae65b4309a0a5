"""GeorefSync: the standalone georef node's fusion, telemetry and registrations merged by stamp (no ROS).

    sync = GeorefSync(georef_config, warn, publish_pose)
    sync.telemetry('fix', fix, now_s)        # a fix or IMU sample in stamp order
    sync.registration(reg)                   # a decoded /srmosaic/registration (nodes.common.RegistrationMsg)
    sync.tick(now_s)                         # every TICK_S: the timeout of the registrations waiting
    sync.flush()                             # at cleanup: fuse the registrations still waiting

The inputs are merged by stamp, as `srmosaic process` reads a bag. Telemetry waits until a
registration at or after its stamp is fused (registrations come mosaic.revisit_spread_frames
frames late by design: fed at once, the telemetry would run past the filter's telemetry_buffer_s
and the filter would bridge a camera dropout that is not one), or until it is TELEMETRY_HOLD_S older
than the newest. A registration waits until every telemetry stream still coming has delivered what
it stamps up to the registration's (core/time_sync.TelemetryStreams), or until it waited
SYNC_TIMEOUT_S of the node's own running time (RunningClock: a process stopped by the scheduler
does not time out the telemetry waiting in its queues), or REGISTRATION_HOLD registrations wait.
``publish_pose(stamp_ns, pose) -> bool`` publishes each fused pose (True: it went out).
"""
from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any

from ..core.georef.georeferencer import Georeferencer
from ..core.time_sync import TelemetryStreams

__all__ = ['REGISTRATION_HOLD', 'SYNC_TIMEOUT_S', 'TELEMETRY_HOLD_S', 'TICK_S', 'GeorefSync', 'RunningClock']

#: Seconds (of the node running) a registration waits for its telemetry before it is fused without.
SYNC_TIMEOUT_S = 1.0
#: Registrations that may wait; one more and the oldest is fused without its telemetry (memory bound:
#: they come in bursts, up to mosaic.revisit_spread_frames at once, so the offline SYNC_HOLD_FRAMES is too few).
REGISTRATION_HOLD = 200
#: Seconds of telemetry (by stamp) the node holds for registrations still to come; older telemetry
#: goes to the filter (which bridges frames that never came). Above revisit_spread_frames frame periods.
TELEMETRY_HOLD_S = 60.0
#: Period of the timer that applies the timeout (s); a longer gap between its calls is time the
#: process did not run.
TICK_S = 0.2


class RunningClock:
    """Seconds the process has been running, from ticks every TICK_S: a gap of more than two ticks
    counts as two (the process was not scheduled, a loaded machine; that time is not waiting)."""

    def __init__(self, now_s: float) -> None:
        self.running_s = 0.0
        self._last_s = now_s

    def tick(self, now_s: float) -> float:
        self.running_s += min(now_s - self._last_s, 2 * TICK_S)
        self._last_s = now_s
        return self.running_s


class GeorefSync:
    """The filter and what waits for it (module docstring). ``config``: the georef.* settings;
    ``warn``: the node's WarnOnce. Not thread-safe: the node feeds it from one callback group."""

    def __init__(self, config: Any, warn: Any, publish_pose: Callable[[int, Any], bool], now_s: float) -> None:
        self.georef: Georeferencer | None = None
        self.camera: Any = None  # the pinhole camera of the registrations (undistorted)
        self.pending: list[tuple[float, Any]] = []  # (arrival on the running clock s, registration)
        self.last_pose: Any = None
        self.clock = RunningClock(now_s)
        self._config = config
        self._warn = warn
        self._publish_pose = publish_pose
        self._streams = TelemetryStreams(quiet_s=SYNC_TIMEOUT_S)
        self._held: dict[str, collections.deque[Any]] = {}  # kind -> telemetry not fed yet, by stamp
        self._ref_stamp: int | None = None  # the last painted frame fed: what prev_H_cur maps into

    def _filter(self) -> Georeferencer:
        """The filter, made at its first input (with the camera known by then)."""
        if self.georef is None:
            self.georef = Georeferencer(self._config, self.camera)
        return self.georef

    def telemetry(self, kind: str, item: Any, now_s: float) -> None:
        """A fix ('fix') or IMU sample ('imu') in stamp order; arrival time ``now_s`` (monotonic)."""
        self._held.setdefault(kind, collections.deque()).append(item)
        self._streams.seen(kind, item.stamp_ns, now_s)
        self.drain()

    def registration(self, reg: Any) -> None:
        self.pending.append((self.clock.running_s, reg))
        self.drain()

    def tick(self, now_s: float) -> None:
        self.clock.tick(now_s)
        self.drain(timeout=True)

    def flush(self) -> None:
        """Fuse the registrations still waiting, with the telemetry up to each."""
        while self.pending:
            reg = self.pending.pop(0)[1]
            self._feed_telemetry(reg.stamp_ns)
            self._fuse(reg)

    def drain(self, *, timeout: bool = False) -> None:
        """Fuse the waiting registrations whose telemetry has arrived (approximate-time association)."""
        while self.pending:
            arrived, reg = self.pending[0]
            late = timeout and self.clock.running_s - arrived > SYNC_TIMEOUT_S
            if not (self._streams.covers(reg.stamp_ns) or late or len(self.pending) > REGISTRATION_HOLD):
                break
            self.pending.pop(0)
            self._feed_telemetry(reg.stamp_ns)
            self._fuse(reg)
        newest = max((held[-1].stamp_ns for held in self._held.values() if held), default=None)
        if newest is not None:
            self._feed_telemetry(newest - int(TELEMETRY_HOLD_S * 1e9))

    def _feed_telemetry(self, through_ns: int) -> None:
        """Feed the filter the held telemetry stamped up to ``through_ns``, in stamp order."""
        items = []
        for kind, held in self._held.items():
            while held and held[0].stamp_ns <= through_ns:
                items.append((kind, held.popleft()))
        for kind, item in sorted(items, key=lambda ki: ki[1].stamp_ns):
            georef = self._filter()
            (georef.feed_fix if kind == 'fix' else georef.feed_imu)(item)

    def _fuse(self, reg: Any) -> None:
        georef = self._filter()
        use = reg.ok and reg.reg_ok and reg.prev_H_cur is not None and self._ref_stamp is not None
        try:
            pose = georef.feed_frame(
                reg.stamp_ns, reg.prev_H_cur if use else None, reg.covariance if use else None,
                rms_px=reg.rms_px if use else float('nan'), inliers=reg.inliers if use else 0, camera=self.camera,
                ref_stamp_ns=self._ref_stamp if use else None)
        except Exception as exc:  # noqa: BLE001 - a bad frame must not stop the filter node
            self._warn(f'georef: {type(exc).__name__}', f'frame at {reg.stamp_ns} not fused: {exc!r}')
            return
        if reg.ok:
            self._ref_stamp = reg.stamp_ns
        self._warn.count('frames_fused')
        if self._publish_pose(reg.stamp_ns, pose):
            self._warn.count('poses_published')
            self.last_pose = pose
