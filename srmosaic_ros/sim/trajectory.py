"""Flight paths and the vehicle's state along them, as smooth functions of time.

A path is a planar curve of straight and circular segments parametrised by arc length; the vehicle
flies it at constant speed and constant altitude above the ground plane (z = 0). On top of that:

- yaw follows the path tangent (counter-clockwise from east, REP 103);
- roll banks into turns like a coordinated turn, ``roll = -atan(v^2 kappa / g)`` (kappa positive
  for a left turn; positive roll is right wing down), with the curvature eased over 1 s of flight
  (convolved with a Gaussian) so that the bank rolls in and out;
- gusts: seeded smooth random processes (sums of sinusoids, 0.02 to 0.15 Hz) added to roll, pitch
  and yaw (each with RMS ``gust_deg``) and to east, north, up (each with RMS ``gust_pos_m``).

Everything is analytic in time, so the camera, GNSS and IMU can be sampled at any stamps.
Angular velocity and specific force come from central differences of these functions
(h = 2 ms; truncation error far below any sensor noise).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.georef.frames import R_enu_from_body, rotvec_from_matrix

__all__ = ['GRAVITY_M_S2', 'Segment', 'Path2D', 'SmoothNoise', 'Trajectory', 'BodyState', 'line_path',
           'lawnmower_path', 'orbit_path']

GRAVITY_M_S2 = 9.80665
_BANK_EASE_S = 1.0
_FD_STEP_S = 2e-3


@dataclass(frozen=True)
class Segment:
    """A straight segment (radius 0) or a circular arc.

    start: (2,) ENU (east, north) of the start point; heading_rad: tangent direction at the start;
    length_m: arc length; turn: +1 left (counter-clockwise), -1 right, 0 straight; radius_m.
    """

    start: tuple[float, float]
    heading_rad: float
    length_m: float
    turn: int = 0
    radius_m: float = 0.0

    @property
    def curvature(self) -> float:
        """Signed curvature, 1/m, positive for a left turn."""
        return 0.0 if self.turn == 0 else self.turn / self.radius_m

    def at(self, s: float) -> tuple[np.ndarray, float]:
        """(position (2,), heading) at arc length s from the segment start (extrapolates)."""
        x0 = np.asarray(self.start, dtype=np.float64)
        h0 = self.heading_rad
        if self.turn == 0:
            return x0 + s * np.array([math.cos(h0), math.sin(h0)]), h0
        k = self.curvature
        h = h0 + k * s
        # integral of (cos h, sin h) ds with h linear in s
        pos = x0 + np.array([math.sin(h) - math.sin(h0), math.cos(h0) - math.cos(h)]) / k
        return pos, h

    @property
    def end(self) -> tuple[np.ndarray, float]:
        return self.at(self.length_m)


class Path2D:
    """Chain of segments by arc length; beyond either end the end tangent is extended."""

    def __init__(self, segments: list[Segment]) -> None:
        self.segments = list(segments)
        self.starts = np.cumsum([0.0] + [seg.length_m for seg in self.segments[:-1]])
        self.length_m = float(sum(seg.length_m for seg in self.segments))

    def _locate(self, s: float) -> tuple[Segment, float]:
        if s <= 0.0:
            seg = self.segments[0]
            if seg.turn == 0:
                return seg, s
            pos, h = seg.at(0.0)
            return Segment((float(pos[0]), float(pos[1])), h, 0.0), s
        i = int(np.searchsorted(self.starts, s, side='right')) - 1
        seg = self.segments[i]
        local = s - float(self.starts[i])
        if i == len(self.segments) - 1 and local > seg.length_m and seg.turn != 0:
            pos, h = seg.end
            return Segment((float(pos[0]), float(pos[1])), h, 0.0), local - seg.length_m
        return seg, local

    def at(self, s: float) -> tuple[np.ndarray, float]:
        """(position (2,), heading rad) at arc length s."""
        seg, local = self._locate(s)
        return seg.at(local)

    def eased_curvature(self, s: float, ease_m: float) -> float:
        """Curvature convolved with a Gaussian of std ``ease_m`` (metres of arc length)."""
        total = 0.0
        for start, seg in zip(self.starts, self.segments):
            if seg.turn == 0:
                continue
            a, b = float(start), float(start) + seg.length_m
            if ease_m <= 0.0:
                total += seg.curvature if a <= s < b else 0.0
            else:
                phi_a = 0.5 * (1.0 + math.erf((s - a) / (ease_m * math.sqrt(2.0))))
                phi_b = 0.5 * (1.0 + math.erf((s - b) / (ease_m * math.sqrt(2.0))))
                total += seg.curvature * (phi_a - phi_b)
        return total

    def bbox(self, step_m: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """(min (2,), max (2,)) of the path's points."""
        n = max(2, int(math.ceil(self.length_m / step_m)) + 1)
        pts = np.array([self.at(s)[0] for s in np.linspace(0.0, self.length_m, n)])
        return pts.min(axis=0), pts.max(axis=0)

    def translated(self, offset: np.ndarray) -> Path2D:
        return Path2D([Segment((seg.start[0] + float(offset[0]), seg.start[1] + float(offset[1])),
                               seg.heading_rad, seg.length_m, seg.turn, seg.radius_m) for seg in self.segments])


def line_path(start: tuple[float, float], heading_rad: float, length_m: float) -> Path2D:
    """A straight line of ``length_m`` from ``start`` along ``heading_rad``."""
    return Path2D([Segment((float(start[0]), float(start[1])), float(heading_rad), float(length_m))])


def lawnmower_path(start: tuple[float, float], heading_rad: float, legs: int, leg_length_m: float,
                   leg_spacing_m: float) -> Path2D:
    """Parallel legs joined by half-circle turns; each leg is ``leg_spacing_m`` right of the previous.

    The first leg starts at ``start`` along ``heading_rad``; legs alternate direction; turns have
    radius ``leg_spacing_m / 2`` (right, left, right, ...).
    """
    segments: list[Segment] = []
    pos = np.asarray(start, dtype=np.float64)
    heading = float(heading_rad)
    radius = leg_spacing_m / 2.0
    for i in range(legs):
        leg = Segment((float(pos[0]), float(pos[1])), heading, float(leg_length_m))
        segments.append(leg)
        pos, heading = leg.end
        if i < legs - 1:
            turn = Segment((float(pos[0]), float(pos[1])), heading, math.pi * radius, -1 if i % 2 == 0 else 1, radius)
            segments.append(turn)
            pos, heading = turn.end
            heading = math.atan2(math.sin(heading), math.cos(heading))
    return Path2D(segments)


def orbit_path(centre: tuple[float, float], radius_m: float, laps: float, heading_rad: float) -> Path2D:
    """A counter-clockwise circle of ``radius_m`` about ``centre``, ``laps`` times round, starting with
    the tangent ``heading_rad`` (the centre then lies to the left of the nose)."""
    start = (float(centre[0]) + radius_m * math.sin(heading_rad), float(centre[1]) - radius_m * math.cos(heading_rad))
    return Path2D([Segment(start, float(heading_rad), 2.0 * math.pi * radius_m * laps, 1, float(radius_m))])


class SmoothNoise:
    """A seeded smooth random process: a sum of sinusoids with RMS ``rms`` per channel.

    ``n_channels`` independent channels; frequencies log-uniform in [f_min_hz, f_max_hz], random
    phases and amplitudes, scaled so that each channel's RMS over time is ``rms``.
    """

    def __init__(self, rng: np.random.Generator, n_channels: int, rms: float, *, n_terms: int = 6,
                 f_min_hz: float = 0.02, f_max_hz: float = 0.15) -> None:
        self.freq_hz = np.exp(rng.uniform(math.log(f_min_hz), math.log(f_max_hz), (n_channels, n_terms)))
        self.phase = rng.uniform(0.0, 2.0 * math.pi, (n_channels, n_terms))
        amp = rng.uniform(0.5, 1.0, (n_channels, n_terms))
        # RMS of a sum of sinusoids with distinct frequencies: sqrt(sum a^2 / 2)
        self.amp = amp * (rms / np.sqrt(0.5 * np.sum(amp**2, axis=1, keepdims=True)))

    def __call__(self, t_s: float) -> np.ndarray:
        """(n_channels,) values at time t_s."""
        return np.sum(self.amp * np.sin(2.0 * math.pi * self.freq_hz * t_s + self.phase), axis=1)


@dataclass(frozen=True)
class BodyState:
    """True state at one instant: ENU position (m) of the body origin and attitude (rad, REP 103)."""

    t_s: float
    position_enu_m: np.ndarray
    roll_rad: float
    pitch_rad: float
    yaw_rad: float

    @property
    def R_enu_from_body(self) -> np.ndarray:
        return R_enu_from_body(self.roll_rad, self.pitch_rad, self.yaw_rad)


class Trajectory:
    """The vehicle's state as a function of time t_s (seconds from the first frame)."""

    def __init__(self, path: Path2D, *, speed_m_s: float, altitude_m: float, rng: np.random.Generator,
                 gust_deg: float = 0.0, gust_pos_m: float = 0.0, turn_bank: bool = True) -> None:
        self.path = path
        self.speed_m_s = float(speed_m_s)
        self.altitude_m = float(altitude_m)
        self.turn_bank = bool(turn_bank)
        self.attitude_noise = SmoothNoise(rng, 3, math.radians(gust_deg))
        self.position_noise = SmoothNoise(rng, 3, gust_pos_m)

    def state(self, t_s: float) -> BodyState:
        s = self.speed_m_s * t_s
        xy, heading = self.path.at(s)
        d_att = self.attitude_noise(t_s)
        d_pos = self.position_noise(t_s)
        bank = 0.0
        if self.turn_bank:
            kappa = self.path.eased_curvature(s, self.speed_m_s * _BANK_EASE_S)
            bank = -math.atan(self.speed_m_s**2 * kappa / GRAVITY_M_S2)
        position = np.array([xy[0] + d_pos[0], xy[1] + d_pos[1], self.altitude_m + d_pos[2]])
        yaw = heading + d_att[2]
        yaw = math.atan2(math.sin(yaw), math.cos(yaw))
        return BodyState(t_s, position, bank + float(d_att[0]), float(d_att[1]), yaw)

    def angular_velocity_body(self, t_s: float) -> np.ndarray:
        """(3,) rad/s in the body frame: log(R(t-h)^T R(t+h)) / 2h."""
        h = _FD_STEP_S
        r0 = self.state(t_s - h).R_enu_from_body
        r1 = self.state(t_s + h).R_enu_from_body
        return rotvec_from_matrix(r0.T @ r1) / (2.0 * h)

    def acceleration_enu(self, t_s: float) -> np.ndarray:
        """(3,) m/s^2 in ENU, second central difference of the position."""
        h = _FD_STEP_S
        p0 = self.state(t_s - h).position_enu_m
        p1 = self.state(t_s).position_enu_m
        p2 = self.state(t_s + h).position_enu_m
        return (p0 - 2.0 * p1 + p2) / h**2

    def specific_force_body(self, t_s: float) -> np.ndarray:
        """(3,) accelerometer reading (m/s^2, body frame): R^T (a + g e_z); +9.81 on z when level at rest."""
        a = self.acceleration_enu(t_s) + np.array([0.0, 0.0, GRAVITY_M_S2])
        return self.state(t_s).R_enu_from_body.T @ a
