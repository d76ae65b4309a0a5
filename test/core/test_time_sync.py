"""core/time_sync: when a frame's telemetry is all in, with streams that lag each other."""
from __future__ import annotations

from srmosaic_ros.core.time_sync import TelemetryStreams

MS = 1_000_000


def feed(streams: TelemetryStreams, stream: str, period_ms: int, until_ms: int, arrival_s: float) -> None:
    for t in range(0, until_ms + 1, period_ms):
        streams.seen(stream, t * MS, arrival_s)


def test_a_frame_waits_for_the_slowest_stream_not_the_newest_stamp():
    """A 5 Hz fix stream ahead of a 50 Hz Imu backlog (as the middleware drains them under load):
    the frame at 2.25 s is not covered until the Imu has come to it."""
    streams = TelemetryStreams(quiet_s=1.0)
    feed(streams, 'fix', 200, 2400, 10.0)
    feed(streams, 'imu', 20, 2100, 10.0)
    assert not streams.covers(2250 * MS)
    feed(streams, 'imu', 20, 2220, 10.0)  # the next sample, at 2.24 s, is still to come
    assert not streams.covers(2250 * MS)
    feed(streams, 'imu', 20, 2240, 10.0)  # the next one will be stamped after the frame
    assert streams.covers(2250 * MS)


def test_a_slow_stream_is_not_waited_for_between_its_messages():
    """A 1 Hz GPS: a frame 0.7 s after the last fix needs no further fix (the next is stamped after it);
    0.9 s after it, the next fix may still be stamped before the frame (20 % jitter allowed)."""
    streams = TelemetryStreams(quiet_s=1.0)
    feed(streams, 'fix', 1000, 3000, 5.0)
    feed(streams, 'imu', 20, 4000, 5.0)
    assert streams.covers(3700 * MS)
    assert not streams.covers(3900 * MS)


def test_a_stream_that_stopped_while_others_go_on_holds_nothing():
    streams = TelemetryStreams(quiet_s=1.0)
    feed(streams, 'fix', 200, 2000, 10.0)
    feed(streams, 'imu', 20, 2000, 10.0)
    assert not streams.covers(5000 * MS)
    feed(streams, 'imu', 20, 5000, 11.0)  # the GPS silent for 1 s while the Imu went on: still waited for
    assert not streams.covers(5000 * MS)
    feed(streams, 'imu', 20, 5200, 11.5)  # silent 1.5 s > 1 s + two periods: dead
    assert streams.covers(5000 * MS)


def test_nothing_is_covered_before_any_telemetry():
    assert not TelemetryStreams(quiet_s=1.0).covers(0)
