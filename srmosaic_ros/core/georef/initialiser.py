"""Where the pose filter starts: the first frame's pose from the telemetry buffered before it (the nearest
fix, the nearest Imu orientation, else a level attitude and the yaw of the course over ground).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .georef_config import GeorefConfig
    from .skip_log import SkipLog

__all__ = ['TURN_SIGNIFICANCE', 'InitialState', 'course_velocity', 'initial_state']

#: A turn is taken from the fixes before the first frame when their track's quadratic term stands
#: this many standard errors above its noise.
TURN_SIGNIFICANCE = 3.0


def course_velocity(t_s: np.ndarray, xy_m: np.ndarray) -> np.ndarray:
    """(2,) horizontal velocity (m/s) at t = 0 of a track of fixes at times ``t_s`` (n,) <= 0 and
    positions ``xy_m`` (n, 2), n >= 6: from a quadratic fit when the track turns significantly
    (its quadratic term above TURN_SIGNIFICANCE standard errors, the noise taken from the fit's
    residuals), else from a straight-line fit. A chord or a line over the window lags a turn by
    half of it (an orbit at 11 deg/s: 30 deg over 5 s); a quadratic's end slope is noisier on a
    straight track (an oblique line's corners 0.26 -> 0.43 px)."""
    A = np.stack([t_s**2, t_s, np.ones_like(t_s)], axis=1)
    coef, *_ = np.linalg.lstsq(A, xy_m, rcond=None)
    dof = len(t_s) - 3
    var = float(np.sum((xy_m - A @ coef) ** 2)) / (2 * dof)  # per coordinate
    sd_quadratic = math.sqrt(var * float(np.linalg.inv(A.T @ A)[0, 0]))
    # |c2| / sd is chi with 2 dof on a straight track: above 3 by chance 1.1 % of the time
    if np.linalg.norm(coef[0]) > TURN_SIGNIFICANCE * max(sd_quadratic, 1e-12):
        return coef[1]
    return np.polyfit(t_s, xy_m, 1)[0]


@dataclass(frozen=True)
class InitialState:
    """The first frame's body pose (6,) (east, north, up m; roll, pitch, yaw rad), its covariance (6, 6),
    the ground height's variance (m^2), and the fix (and Imu orientation) it was taken from."""

    pose: np.ndarray
    covariance: np.ndarray
    ground_var_m2: float
    fix_stamp_ns: int
    fix_covariance: np.ndarray
    imu_stamp_ns: int | None
    imu_covariance: np.ndarray | None


def initial_state(pending: list[tuple[int, int, str, np.ndarray, np.ndarray]], stamp_ns: int, config: GeorefConfig,
                  log: SkipLog) -> InitialState | None:
    """The filter's start at the frame ``stamp_ns`` from the buffered telemetry ``pending`` ((stamp, seq,
    kind, z, R) of 'fix' (ENU position) and 'imu' (roll, pitch, yaw)), or None: no fix yet, or none within
    ``telemetry_buffer_s`` of the frame (a still without its time waits for a nearer one)."""
    fixes = [p for p in pending if p[2] == 'fix']
    if not fixes:
        return None
    cfg = config
    before = [p for p in fixes if p[0] <= stamp_ns]
    fix = before[-1] if before else min(fixes, key=lambda p: abs(p[0] - stamp_ns))
    gap_s = abs(fix[0] - stamp_ns) * 1e-9
    if gap_s > cfg.telemetry_buffer_s:  # a frame far from any fix (a still without its time): wait for a nearer one
        log.skip('no_fix_near_frame', f'no GNSS fix within telemetry_buffer_s ({cfg.telemetry_buffer_s:g} s) of '
                   f'the frame at {stamp_ns} ns: the filter starts at a later frame')
        return None
    cov = np.zeros((6, 6))
    pose = np.zeros(6)
    pose[:3] = fix[3]
    cov[:3, :3] = fix[4] + (cfg.initial_speed_sigma_m_s * gap_s) ** 2 * np.eye(3)
    imus = [p for p in pending if p[2] == 'imu']

    def course_yaw() -> tuple[float, float]:
        recent = [p for p in fixes if p[0] >= fix[0] - 5_000_000_000 and p[0] <= fix[0]]
        d = recent[-1][3][:2] - recent[0][3][:2]
        if np.hypot(*d) <= 3.0 * math.sqrt(fix[4][0, 0]):
            return 0.0, math.radians(90.0)
        t = np.array([(p[0] - fix[0]) * 1e-9 for p in recent])
        if len(recent) < 6 or np.ptp(t) < 2.0:
            return math.atan2(d[1], d[0]), math.radians(20.0)
        v = course_velocity(t, np.array([p[3][:2] for p in recent]))
        return math.atan2(v[1], v[0]), math.radians(20.0)

    if imus:
        imu = min(imus, key=lambda p: abs(p[0] - stamp_ns))
        gap_s = abs(imu[0] - stamp_ns) * 1e-9
        pose[3:] = imu[3]
        cov[3:, 3:] = imu[4] + (math.radians(cfg.initial_rate_sigma_deg_s) * gap_s) ** 2 * np.eye(3)
    else:
        yaw, yaw_sigma = course_yaw()
        log.skip('no_attitude', 'no Imu orientation before the first frame: level attitude and yaw from the '
                   'course over ground assumed; the first homographies may be gated')
        pose[3:] = (0.0, 0.0, yaw)
        cov[3:, 3:] = np.diag([math.radians(5.0) ** 2, math.radians(5.0) ** 2, yaw_sigma**2])
    if math.isfinite(cfg.ground_altitude_m):
        ground_var = cfg.ground_altitude_sigma_m**2
    else:
        ground_var = cfg.nominal_agl_sigma_m**2 + float(fix[4][2, 2])
    return InitialState(pose, cov, ground_var, fix[0], fix[4], imu[0] if imus else None, imu[4] if imus else None)
