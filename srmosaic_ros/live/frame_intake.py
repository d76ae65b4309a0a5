"""FrameIntake: the mosaic node's inputs on their way to the worker, without ROS.

The node's callbacks convert messages and hand them here; the worker thread takes them:

    intake = FrameIntake(queue_size=8, max_rate_hz=0.0, order=stream_order, warn=warn)
    intake.put_frame(frame)            # image callback: bounded, the oldest frame dropped when full
    intake.put_telemetry(fix)          # fix / IMU / camera callbacks: in order with the frames
    frame, idle = intake.next()        # worker: the next frame, or None after a pause (idle)

The frame queue holds at most ``queue_size`` frames (live.queue_size); a frame put into a full queue
drops the oldest, counted as ``dropped_frames`` in ``warn`` (the node's WarnOnce, whose first note
says the way out). ``max_rate_hz`` (live.max_rate_hz) takes at most that many frames per second by
their stamps (:class:`RateLimiter`).
"""
from __future__ import annotations

import collections
import threading
from typing import Any

from ..core.types import Frame

__all__ = ['FALLING_BEHIND', 'RATE_SLACK', 'FrameIntake', 'RateLimiter']

#: live.max_rate_hz: a frame this fraction of the interval before it is due is taken as on time
RATE_SLACK = 0.25

#: said once when the queue first drops a frame (then counted; diagnostics WARN while it goes on)
FALLING_BEHIND = ('frames arrive faster than this node processes them: the oldest queued frame is dropped '
                  '(live.queue_size). Register and paint fewer pixels (params/live_hd.yaml: registration.max_width, '
                  'mosaic.max_width), take fewer frames (live.max_rate_hz), or give the node more CPU; a larger live.queue_size '
                  'only rides out bursts, at the cost of latency')

#: telemetry items (fixes, IMU samples, cameras) waiting for the worker at most
TELEMETRY_KEPT = 10000


class RateLimiter:
    """live.max_rate_hz: which frames are taken, by their stamps (ns). ``max_rate_hz`` 0: all."""

    def __init__(self, max_rate_hz: float) -> None:
        self.interval_ns = int(1e9 / max_rate_hz) if max_rate_hz > 0 else 0
        self._next_due_ns: int | None = None  # stamp from which the next frame is due

    def due(self, stamp_ns: int) -> bool:
        """Whether the frame of this stamp is taken. Frames are due one interval apart on the stamps'
        clock (30 fps at 20 Hz: two of three), a frame within RATE_SLACK of an interval early
        counting as on time (stamp jitter must not skip it); after a gap in the input the schedule
        starts again. Called by the image callback only."""
        interval, due = self.interval_ns, self._next_due_ns
        if not interval:
            return True
        if due is not None and stamp_ns < due - RATE_SLACK * interval:
            return False
        restart = due is None or stamp_ns - due >= interval
        self._next_due_ns = (stamp_ns if restart else due) + interval
        return True


class FrameIntake:
    """The bounded frame queue, the telemetry queue, their stamp order and the worker's wake-up.

    ``order``: the node's StreamOrder (``accept(stream, stamp_ns) -> bool``); ``warn``: its
    WarnOnce (``note(kind, text)``). Thread-safe: the input callbacks run concurrently."""

    def __init__(self, queue_size: int, max_rate_hz: float, order: Any, warn: Any) -> None:
        self.frames: collections.deque[Frame] = collections.deque(maxlen=int(queue_size))
        self.telemetry: collections.deque[Any] = collections.deque(maxlen=TELEMETRY_KEPT)
        self.rate = RateLimiter(max_rate_hz)
        self.camera: Any = None  # the newest CameraInfo's intrinsics (None: none yet)
        self._order = order
        self._warn = warn
        self._order_lock = threading.Lock()  # the callbacks of several groups check stamps at once
        self._wake = threading.Condition()
        self._stopping = False

    def in_order(self, stream: str, stamp_ns: int) -> bool:
        """Whether the stamp is on the clock and after the stream's previous one (else counted)."""
        with self._order_lock:
            return self._order.accept(stream, stamp_ns)

    def put_frame(self, frame: Frame) -> None:
        """Queue a frame for the worker; a full queue drops its oldest (counted as dropped_frames)."""
        with self._wake:
            if len(self.frames) == self.frames.maxlen:
                self._warn.note('dropped_frames', FALLING_BEHIND)
            self.frames.append(frame)
            self._wake.notify()

    def put_telemetry(self, item: Any) -> None:
        """A fix, IMU sample or camera for the worker, fed before the next frame."""
        self.telemetry.append(item)

    def set_camera(self, camera: Any) -> None:
        """A CameraInfo's intrinsics: a new one goes in order with the telemetry (frames without one get it)."""
        if camera != self.camera:
            self.camera = camera
            self.telemetry.append(camera)

    def pop_telemetry(self) -> Any | None:
        """The oldest telemetry item queued (None: none). The worker feeds them until none is left,
        those that arrive meanwhile included, before its frame."""
        try:
            return self.telemetry.popleft()
        except IndexError:
            return None

    def next(self, wait_s: float = 0.5) -> tuple[Frame | None, bool] | None:
        """(frame or None, idle): the next frame, or None with idle True when none came within
        ``wait_s``; None once stopped and the queue is empty (the worker ends)."""
        with self._wake:
            idle = False
            while not self.frames and not self._stopping:
                if not self._wake.wait(wait_s):
                    idle = True
                    break
            if self._stopping and not self.frames:
                return None
            return (self.frames.popleft() if self.frames else None), idle

    def stop(self) -> None:
        """The worker ends once the queue is drained."""
        with self._wake:
            self._stopping = True
            self._wake.notify()
