"""The SR node's tile stream and the mosaic node's frame intake, without a graph."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from srmosaic_ros.errors import SrMosaicError
from srmosaic_ros.live.frame_intake import FrameIntake, RateLimiter
from srmosaic_ros.live.map_tiles import parse_whole_map
from srmosaic_ros.live.sr import SRTilePlacement
from srmosaic_ros.live.sr_tile_stream import SRTileStream, encode_sr_tile


def tile(seed: int, side: int = 64) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (side, side, 3), dtype=np.uint8)


def frame_id(x0: int) -> str:
    return SRTilePlacement(0, x0, 0, 32, 32, 2).frame_id()


def test_sr_tiles_go_oldest_first_within_the_budget_in_their_newest_version() -> None:
    images = {x0: tile(x0) for x0 in (0, 32, 64)}
    size = len(encode_sr_tile(images[0]))
    stream = SRTileStream(bytes_per_s=size, burst_s=1.0)  # about one tile a second
    for x0, image in images.items():
        stream.offer(frame_id(x0), image, now_s=0.0)
    newer = tile(99)
    stream.offer(frame_id(32), newer, now_s=0.1)  # made again while it waits: keeps its place, newest pixels
    sent, t = [], 0.0
    while stream.pending and t < 20:
        sent += [(t, f, d) for f, d in stream.take(int(t * 1e9), t)]
        t += 0.25
    assert [f for _, f, _ in sent] == [frame_id(0), frame_id(32), frame_id(64)]  # none lost, oldest first
    assert sent[1][0] > sent[0][0]  # the budget held the second back
    for t0 in np.arange(0.0, t, 0.25):
        in_window = sum(len(d) for ts, _, d in sent if t0 <= ts < t0 + 2.0)
        assert in_window <= size * (2.0 + 1.0) + max(len(d) for *_, d in sent)
    decoded = cv2.imdecode(np.frombuffer(sent[1][2], np.uint8), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
    np.testing.assert_array_equal(decoded, newer)
    summary = json.loads(stream.summary())
    assert summary['pending'] == 0 and summary['tile_px'] == 64 and summary['bytes_sent'] == sum(len(d) for *_, d in sent)
    assert sorted(f for f, _ in summary['tiles']) == sorted(frame_id(x) for x in images)
    whole = {f: d for f, _, d in parse_whole_map(stream.whole_map())}
    assert whole[frame_id(32)] == sent[1][2]


def test_sr_tiles_without_a_budget_go_at_once_and_bad_ones_are_refused() -> None:
    stream = SRTileStream(0)
    for x0 in (0, 32, 64):
        stream.offer(frame_id(x0), tile(x0)[:, :, 0], now_s=0.0)  # grey
    assert len(stream.take(0, 0.0)) == 3 and stream.pending == 0
    with pytest.raises(SrMosaicError, match='not an SR tile placement'):
        stream.offer('srmosaic_segment_0;x0=0;y0=0;width=32;height=32', tile(1), now_s=0.0)
    with pytest.raises(SrMosaicError, match='RGB or grey uint8'):
        stream.offer(frame_id(0), np.zeros((8, 8, 3), np.float32), now_s=0.0)


class _Warn:
    def __init__(self) -> None:
        self.notes: list[str] = []

    def note(self, kind: str, text: str) -> None:
        self.notes.append(kind)


class _InOrder:
    def accept(self, stream: str, stamp_ns: int) -> bool:
        return True


def test_the_intake_drops_the_oldest_frame_when_full_and_the_rate_limiter_keeps_a_steady_rate() -> None:
    warn = _Warn()
    intake = FrameIntake(2, 0.0, _InOrder(), warn)
    for k in range(3):
        intake.put_frame(k)  # (the queue holds whatever the callbacks give it)
    assert list(intake.frames) == [1, 2] and warn.notes == ['dropped_frames']
    assert intake.next(0.01) == (1, False)
    intake.stop()
    assert intake.next(0.01) == (2, False) and intake.next(0.01) is None  # drained, then the worker ends
    rate = RateLimiter(20.0)  # 30 fps at 20 Hz: two of three
    taken = [rate.due(int(k * 1e9 / 30)) for k in range(30)]
    assert sum(taken) == 20
    assert all(RateLimiter(0.0).due(k) for k in range(5))
