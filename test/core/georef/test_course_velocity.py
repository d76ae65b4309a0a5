"""The course over ground at the first frame, from the fixes before it (georeferencer.course_velocity):
a chord or a line through 5 s of an orbit lags the turn by half of it; a quadratic does not, and
is taken only when the track turns beyond its noise."""
from __future__ import annotations

import math

import numpy as np

from srmosaic_ros.core.georef.georeferencer import course_velocity

T = np.arange(-5.0, 0.01, 0.2)  # 5 Hz fixes over the 5 s before the frame


def _heading_deg(v: np.ndarray) -> float:
    return math.degrees(math.atan2(v[1], v[0]))


def test_an_orbit_is_read_at_its_end_not_at_its_middle() -> None:
    """10 m/s on a 50 m circle (11.5 deg/s), GPS noise 2.5 m: the chord's course is 29 deg behind;
    the fit's is within 10 deg (16 of 20) but where the noise hides the turn (its quadratic term under 3
    standard errors: 3 tracks of 20 here, taken as straight, as far behind as the chord)."""
    omega, r = 10.0 / 50.0, 50.0
    angle = omega * T
    track = np.stack([r * np.sin(angle), r * (1.0 - np.cos(angle))], axis=1)  # heading 0 (east) at t = 0
    chord = track[-1] - track[0]
    assert _heading_deg(chord) < -25.0  # lags the turn by about half of it
    errors = []
    for seed in range(20):
        noisy = track + np.random.default_rng(seed).normal(0.0, 2.5, track.shape)
        errors.append(_heading_deg(course_velocity(T, noisy)))
    assert abs(float(np.median(errors))) < 3.0, errors
    assert sum(abs(e) < 10.0 for e in errors) >= 15 and max(abs(e) for e in errors) < 32.0, errors


def test_a_straight_track_is_fitted_by_a_line() -> None:
    """No turn: the straight-line fit, as steady as the chord (within 3 deg at 2.5 m noise over 50 m),
    where a quadratic's end slope wanders about four times as far."""
    track = np.stack([10.0 * T, np.zeros_like(T)], axis=1)
    errors = []
    for seed in range(20):
        noisy = track + np.random.default_rng(seed).normal(0.0, 2.5, track.shape)
        errors.append(_heading_deg(course_velocity(T, noisy)))
    assert float(np.percentile(np.abs(errors), 90)) < 5.0, errors
