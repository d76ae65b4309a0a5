"""TelemetrySync on its own (pipeline/telemetry_sync.py): which frames the conductor may process, and
what the Georeferencer, there from the start, holds of the telemetry before the first fix."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.georef.georeferencer import Georeferencer
from srmosaic_ros.core.stage_clock import StageClock
from srmosaic_ros.core.time_sync import SYNC_HOLD_FRAMES
from srmosaic_ros.core.types import CameraAttitude, Frame, GeoFix, ImuSample
from srmosaic_ros.pipeline import telemetry_sync
from srmosaic_ros.pipeline.telemetry_sync import FIRST_FIX_HOLD_FRAMES, TelemetrySync

S = 1_000_000_000


def _frame(t_s: float) -> Frame:
    return Frame(int(t_s * S), np.zeros((8, 8), np.uint8))


def _imu(t_s: float) -> ImuSample:
    return ImuSample(int(t_s * S), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3), 0.01 * np.eye(3))


def _attitude(t_s: float) -> CameraAttitude:
    down = np.diag([1.0, -1.0, -1.0])  # optical axis (camera z) straight down in ENU
    return CameraAttitude(int(t_s * S), down)


def _fix(t_s: float) -> GeoFix:
    return GeoFix(int(t_s * S), 47.0, 8.0, 500.0, status=0, position_covariance_m2=np.eye(3), covariance_type=2)


class _Recording(Georeferencer):
    """A Georeferencer that notes what it is fed, in order: (kind, stamp s)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.fed: list[tuple[str, float]] = []

    def feed_fix(self, fix: GeoFix) -> None:
        self.fed.append(('fix', fix.stamp_ns / S))
        super().feed_fix(fix)

    def feed_imu(self, imu: ImuSample) -> None:
        self.fed.append(('imu', imu.stamp_ns / S))
        super().feed_imu(imu)

    def feed_camera_attitude(self, attitude: CameraAttitude) -> None:
        self.fed.append(('attitude', attitude.stamp_ns / S))
        super().feed_camera_attitude(attitude)


def test_the_filter_exists_from_the_start_and_holds_the_buffer_before_the_first_fix(monkeypatch):
    monkeypatch.setattr(telemetry_sync, 'Georeferencer', _Recording)
    sync = TelemetrySync(pipeline_config({'georef.telemetry_buffer_s': 3.0}), StageClock())
    assert isinstance(sync.georef, _Recording) and not sync.georef.has_origin  # no origin yet
    for t in range(10):  # IMU on the second, camera attitudes half-way, all before any fix
        sync.feed(_imu(t))
        sync.feed(_attitude(t + 0.5))
    # every message reaches the filter as it comes, in order
    assert sync.georef.fed == [m for t in range(10) for m in (('imu', t), ('attitude', t + 0.5))]
    assert len(sync.imus) == 10 and len(sync.attitudes) == 10 and not sync.georef.has_origin
    held = [p[0] / S for p in sync.georef._pending]  # attitudes waiting for the first frame
    assert held and min(held) >= 9.5 - 3.0  # only the telemetry_buffer_s before the newest
    assert [g[0] / S for g in sync.georef._gyro] == [6.0, 7.0, 8.0, 9.0]
    sync.feed(_fix(10.0))
    sync.feed(_imu(10.0))
    assert sync.georef.has_origin and sync.georef.fed[-2:] == [('fix', 10.0), ('imu', 10.0)]
    # at the first fix: the telemetry_buffer_s (3 s) before it, as the filter created there used to be given
    assert min(p[0] / S for p in sync.georef._pending) >= 7.0
    assert [g[0] / S for g in sync.georef._gyro] == [7.0, 8.0, 9.0, 10.0]
    assert sync.attitude_measured()  # an Imu orientation (and attitudes that see the ground)
    assert sync.measured_elevations_deg(8 * S, 9 * S) == [pytest.approx(-90.0)]
    with pytest.raises(TypeError, match='not str'):
        sync.feed('a fix')  # type: ignore[arg-type]


def test_frames_wait_for_the_first_fix_then_for_telemetry_after_their_stamp():
    sync = TelemetrySync(pipeline_config(), StageClock())
    for k in range(FIRST_FIX_HOLD_FRAMES):  # 0.1 s apart: within telemetry_buffer_s
        sync.feed(_frame(0.1 * k))
        assert list(sync.ready()) == []  # waiting for the first fix
    sync.feed(_fix(0.1 * (FIRST_FIX_HOLD_FRAMES - 2) + 0.05))
    # the fix is newer than every frame but the last: they go, the last waits for newer telemetry
    assert len(list(sync.ready())) == FIRST_FIX_HOLD_FRAMES - 1 and len(sync.waiting) == 1
    sync.feed(_frame(100.0))
    assert list(sync.ready()) == []  # telemetry has not caught up with either
    assert [f.stamp_ns for f in sync.ready(all_frames=True)] == [int(0.1 * (FIRST_FIX_HOLD_FRAMES - 1) * S), 100 * S]


def test_without_a_fix_in_time_the_frames_go_on_alone():
    sync = TelemetrySync(pipeline_config(), StageClock())
    for k in range(FIRST_FIX_HOLD_FRAMES + 1):
        sync.feed(_frame(0.1 * k))
    # one frame more than the first-fix hold: the wait is over, and only SYNC_HOLD_FRAMES stay queued
    assert len(list(sync.ready())) == FIRST_FIX_HOLD_FRAMES + 1 - SYNC_HOLD_FRAMES
    assert sync.first_fix_wait_over and len(sync.waiting) == SYNC_HOLD_FRAMES
    off = TelemetrySync(pipeline_config({'georef.enabled': False}), StageClock())
    for k in range(SYNC_HOLD_FRAMES + 2):
        off.feed(_frame(0.1 * k))
    assert len(list(off.ready())) == 2  # no first fix to wait for without georeferencing


def test_the_georeferencer_has_no_origin_before_a_valid_fix_and_few_attributes():
    georef = Georeferencer()
    assert not georef.has_origin and georef.origin is None
    pose = georef.feed_frame(5 * S)
    assert not pose.valid and pose.reason == 'no GNSS fix yet'
    georef.feed_fix(GeoFix(6 * S, float('nan'), 8.0, 500.0))  # an unusable fix sets no origin
    assert not georef.has_origin
    georef.feed_fix(_fix(7.0))
    assert georef.has_origin
    assert len(vars(georef)) <= 15, sorted(vars(georef))  # one job per collaborator (issue 55: about 15 at most)
