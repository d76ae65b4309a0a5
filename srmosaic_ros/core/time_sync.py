"""Approximate-time association of frames (or their registrations) with telemetry.

A frame stamped t is fused once telemetry stamped after t has arrived (the fixes and attitudes
around it are known), or once more than SYNC_HOLD_FRAMES frames wait behind it (telemetry stopped or
never comes), or, live, once it waited longer than a timeout: the offline pipeline's rule, and the
mosaic node's (telemetry and frames through one queue). The standalone georef node, whose
registrations and telemetry come on separate channels, waits for each stream (TelemetryStreams).
"""
from __future__ import annotations

import collections
import itertools
import statistics

__all__ = ['COVER_JITTER', 'SYNC_HOLD_FRAMES', 'TelemetryStreams', 'telemetry_ready']

#: Frames that may wait for their telemetry; one more and the oldest goes without it.
SYNC_HOLD_FRAMES = 3
#: Share of a telemetry stream's period by which its next stamp may come early (TelemetryStreams).
COVER_JITTER = 0.2


def telemetry_ready(stamp_ns: int, latest_telemetry_ns: int | None, waiting: int, *, late: bool = False) -> bool:
    """Whether the oldest of ``waiting`` queued items, stamped ``stamp_ns``, is to be processed now:
    telemetry newer than it has been seen (``latest_telemetry_ns``, None: none yet), more than
    SYNC_HOLD_FRAMES wait, or it is ``late`` (the caller's timeout)."""
    seen = latest_telemetry_ns is not None and latest_telemetry_ns > stamp_ns
    return seen or late or waiting > SYNC_HOLD_FRAMES


class TelemetryStreams:
    """How far each telemetry stream (fixes, Imu, ...) has been received, for a consumer that gets
    its frames and its telemetry on separate channels that may lag each other (the standalone georef
    node: registrations from the mosaic node, telemetry from the vehicle).

    `telemetry_ready` with the newest stamp of *any* stream is not enough there: under load the
    middleware hands over one message per topic per turn, so a 5 Hz fix stream catches up long before
    a 50 Hz Imu backlog, and a frame fused then misses the gyro samples between it and the previous
    one (and the late samples are gated against the state fused without them).

    A frame stamped t is covered when every stream still coming has delivered all it will stamp up to
    t: its next message, a period after its newest (the median spacing of its recent stamps, less
    COVER_JITTER of it for jitter), would be stamped after t. So a 1 Hz GPS holds a frame only in the
    last fifth of a second before its next fix, and a 50 Hz Imu until it has a sample within 16 ms
    before the frame. A stream silent for ``quiet_s`` plus two of its periods while another one went
    on (a dead GPS) no longer holds frames; silence of all of them is the caller's timeout. Times are
    arrival times in seconds of any monotonic clock.
    """

    def __init__(self, quiet_s: float, history: int = 9) -> None:
        self.quiet_s = float(quiet_s)
        self._stamps: dict[str, collections.deque[int]] = {}
        self._arrival_s: dict[str, float] = {}
        self._history = history

    def seen(self, stream: str, stamp_ns: int, arrival_s: float) -> None:
        """A message of ``stream`` stamped ``stamp_ns`` (increasing per stream) received at ``arrival_s``."""
        stamps = self._stamps.setdefault(stream, collections.deque(maxlen=self._history))
        if not stamps or stamp_ns > stamps[-1]:
            stamps.append(int(stamp_ns))
        self._arrival_s[stream] = float(arrival_s)

    def period_ns(self, stream: str) -> int:
        """Median spacing of the stream's recent stamps (0 with fewer than two)."""
        stamps = self._stamps[stream]
        return int(statistics.median(b - a for a, b in itertools.pairwise(stamps))) if len(stamps) > 1 else 0

    def covers(self, stamp_ns: int) -> bool:
        """Whether every stream still coming has delivered what it stamps up to ``stamp_ns`` (False
        before any telemetry)."""
        if not self._stamps:
            return False
        newest_arrival = max(self._arrival_s.values())
        for stream, stamps in self._stamps.items():
            period = self.period_ns(stream)
            if newest_arrival - self._arrival_s[stream] > self.quiet_s + 2e-9 * period:
                continue  # silent while the others go on: not waited for
            if stamps[-1] + int((1.0 - COVER_JITTER) * period) <= stamp_ns:
                return False
        return True
