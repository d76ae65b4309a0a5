"""Ground control in the global solve of a survey (core/survey/global_align.py): a strip of stills
without GPS whose registrations drift (each pair's scale and turn off by a little, as chained
registrations do), surveyed targets planted on the ground and seen in the stills; the control
takes the survey to the ground and bends the drift out, the check points say by how much, and a
target given wrong coordinates is caught."""
from __future__ import annotations

import math

import numpy as np
import pytest

from srmosaic_ros.core.survey.global_align import (GroundControl, SurveyPriors, control_residuals, pair_constraint,
                                                   solve_survey)

W, H, F = 1000, 750, 800.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])
AGL = 60.0
GSD = AGL / F  # metres per pixel


def _strip(frames: int = 16, spacing: float = 15.0) -> np.ndarray:
    """True ground homographies (normalised -> metres, UTM-like east/north) of a strip flown east."""
    Gs = []
    rng = np.random.default_rng(5)
    for k in range(frames):
        a = -math.pi / 2 + rng.normal(0.0, 0.02)
        c, s = math.cos(a), math.sin(a)
        agl = AGL * (1 + rng.normal(0.0, 0.02))
        Gs.append(np.array([[agl * c, agl * s, 500.0 + k * spacing], [agl * s, -agl * c, 200.0],
                            [rng.normal(0, 0.01), rng.normal(0, 0.01), 1.0]]))
    return np.array(Gs)


def _drifting_pairs(Gs: np.ndarray, rng: np.random.Generator) -> list:
    """Pairs (k, k+1) and (k, k+2), each registered with its scale off by 1 % and its turn by 0.3 deg
    (sd): chained, the survey's scale wanders along the strip."""
    out = []
    for i in range(len(Gs)):
        for j in (i + 1, i + 2):
            if j >= len(Gs):
                continue
            i_H_j = K @ np.linalg.inv(Gs[i]) @ Gs[j] @ np.linalg.inv(K)
            s, a = 1.0 + rng.normal(0.0, 0.01), rng.normal(0.0, math.radians(0.3))
            c = np.array([(W - 1) / 2, (H - 1) / 2])
            R = np.array([[s * math.cos(a), -s * math.sin(a), 0], [s * math.sin(a), s * math.cos(a), 0], [0, 0, 1.0]])
            T = np.array([[1, 0, c[0]], [0, 1, c[1]], [0, 0, 1.0]])
            i_H_j = T @ R @ np.linalg.inv(T) @ i_H_j
            cov = np.diag([1e-6, 1e-6, 0.09, 1e-6, 1e-6, 0.09, 1e-12, 1e-12])
            p = pair_constraint(i, j, i_H_j / i_H_j[2, 2], cov, K, K, (W, H), (W, H), inliers=200)
            if p is not None:
                out.append(p)
    return out


def _targets(Gs: np.ndarray, rng: np.random.Generator, pick_px: float = 1.0):
    """Targets every 12 m along the strip, 8 m either side of its axis, with each still that sees
    them (inside a 20 px margin): (names, ground (T, 2), observations [(target index, frame, point_n)])."""
    xs = np.arange(500.0, 500.0 + 15.0 * (len(Gs) - 1) + 1, 12.0)
    ground = np.array([[x, 200.0 + (8.0 if t % 2 else -8.0)] for t, x in enumerate(xs)])
    names = [f't{t:02d}' for t in range(len(ground))]
    obs = []
    for t, X in enumerate(ground):
        for k, G in enumerate(Gs):
            q = K @ np.linalg.inv(G) @ np.array([X[0], X[1], 1.0])
            u = q[:2] / q[2]
            if 20 <= u[0] <= W - 21 and 20 <= u[1] <= H - 21:
                u = u + rng.normal(0.0, pick_px, 2)
                obs.append((t, k, (u - K[:2, 2]) / F))
    return names, ground, obs


def _control(names, ground, obs, *, check: set[str], moved: dict[str, tuple[float, float]] | None = None) -> GroundControl:
    moved = moved or {}
    g = np.array([ground[t] + np.array(moved.get(names[t], (0.0, 0.0))) for t, _, _ in obs])
    return GroundControl(frame=np.array([k for _, k, _ in obs]), point_n=np.array([x for _, _, x in obs]),
                         ground_m=g, sigma_n=np.full(len(obs), 2.0 / F), target=tuple(names[t] for t, _, _ in obs),
                         use=np.array([names[t] not in check for t, _, _ in obs]))


def _no_gps(n: int) -> SurveyPriors:
    return SurveyPriors(np.full((n, 2), np.nan), np.full(n, np.nan), 1.0, None)


def _target_rms_m(sol, control: GroundControl, ground: np.ndarray, names: list[str], which: set[str]) -> float:
    """RMS over the targets in ``which`` of the distance between the mean of their observations' ground
    points and their true position."""
    r = control_residuals(sol.ground_H_frame, control) + control.ground_m
    errs = []
    for name in which:
        m = [i for i, t in enumerate(control.target) if t == name]
        errs.append(float(np.hypot(*(r[m].mean(axis=0) - ground[names.index(name)]))))
    return float(np.sqrt(np.mean(np.square(errs))))


def test_control_puts_a_survey_without_gps_on_the_ground_and_bends_its_drift_out():
    rng = np.random.default_rng(0)
    Gs = _strip()
    pairs = _drifting_pairs(Gs, rng)
    names, ground, obs = _targets(Gs, rng)
    check = {names[t] for t in range(2, len(names) - 1, 4)}  # inside the strip
    control = _control(names, ground, obs, check=check)
    sol = solve_survey(len(Gs), pairs, _no_gps(len(Gs)), control=control)
    assert sol.figures['control_placed_survey'] and sol.figures['control_rejected'] == []
    assert sol.placed_by.count('registration') == len(Gs)
    rms = _target_rms_m(sol, control, ground, names, check)
    assert rms < 2.0 * GSD, rms
    # the same stills with control at the first two targets only: placed on the ground, but the
    # drift stays (the registrations alone carry the scale along the strip)
    ends = set(names[2:])
    sol_ends = solve_survey(len(Gs), pairs, _no_gps(len(Gs)), control=_control(names, ground, obs, check=ends))
    rms_ends = _target_rms_m(sol_ends, control, ground, names, check)
    assert rms_ends > 5.0 * rms, (rms_ends, rms)


def test_a_target_given_wrong_coordinates_is_caught_and_does_not_bend_the_survey():
    rng = np.random.default_rng(1)
    Gs = _strip()
    pairs = _drifting_pairs(Gs, rng)
    names, ground, obs = _targets(Gs, rng)
    check = {names[t] for t in range(2, len(names) - 1, 4)}
    wrong = 't05'
    assert wrong not in check
    control = _control(names, ground, obs, check=check, moved={wrong: (1.5, -1.0)})
    sol = solve_survey(len(Gs), pairs, _no_gps(len(Gs)), control=control)
    rejected = {control.target[m] for m in sol.figures['control_rejected']}
    assert rejected == {wrong}
    assert not any(sol.control_used[m] for m, t in enumerate(control.target) if t == wrong)
    assert _target_rms_m(sol, control, ground, names, check) < 2.0 * GSD
    # its residual says how far off it was given
    r = control_residuals(sol.ground_H_frame, control)
    m = [i for i, t in enumerate(control.target) if t == wrong]
    assert np.hypot(*r[m].mean(axis=0)) == pytest.approx(math.hypot(1.5, 1.0), abs=0.15)


def test_with_gps_the_control_adds_to_the_positions():
    """GPS 2.5 m off at every still, and ground control: the survey lands on the control."""
    rng = np.random.default_rng(2)
    Gs = _strip()
    pairs = _drifting_pairs(Gs, rng)
    names, ground, obs = _targets(Gs, rng)
    check = {names[t] for t in range(2, len(names) - 1, 4)}
    pos = np.array([G[:2, 2] for G in Gs]) + rng.normal(0.0, 2.5, (len(Gs), 2)) + np.array([3.0, -2.0])
    pri = SurveyPriors(pos, np.full(len(Gs), 2.5), AGL, np.zeros(len(Gs)))
    control = _control(names, ground, obs, check=check)
    sol = solve_survey(len(Gs), pairs, pri, control=control)
    assert not sol.figures['control_placed_survey']
    assert _target_rms_m(sol, control, ground, names, check) < 3.0 * GSD
    plain = solve_survey(len(Gs), pairs, pri)
    assert _target_rms_m(plain, control, ground, names, check) > 1.0  # the GPS alone: metres off


def test_two_parts_that_no_pair_joins_are_each_placed_by_their_own_targets():
    """The strip with no registration between its halves (a line turn that failed): without GPS,
    each half with two targets or more is placed on the ground by them; a half with fewer would
    not be."""
    rng = np.random.default_rng(3)
    Gs = _strip()
    half = len(Gs) // 2
    pairs = [p for p in _drifting_pairs(Gs, rng) if (p.i < half) == (p.j < half)]
    names, ground, obs = _targets(Gs, rng)
    control = _control(names, ground, obs, check=set())
    sol = solve_survey(len(Gs), pairs, _no_gps(len(Gs)), control=control)
    assert sol.placed_by.count('registration') == len(Gs)
    assert _target_rms_m(sol, control, ground, names, set(names)) < 2.0 * GSD
    # every target the second half sees held out: it cannot be placed with the first
    second = {names[t] for t, k, _ in obs if k >= half}
    sol = solve_survey(len(Gs), pairs, _no_gps(len(Gs)), control=_control(names, ground, obs, check=second))
    assert sol.placed_by[:half] == ['registration'] * half and set(sol.placed_by[half:]) == {''}


def test_one_wrong_pick_of_a_target_is_caught_and_its_other_picks_kept():
    rng = np.random.default_rng(6)
    Gs = _strip()
    pairs = _drifting_pairs(Gs, rng)
    names, ground, obs = _targets(Gs, rng)
    control = _control(names, ground, obs, check=set())
    seen = [m for m, t in enumerate(control.target) if t == 't06']
    assert len(seen) >= 3
    point_n = control.point_n.copy()
    point_n[seen[1]] += np.array([40.0, -25.0]) / F  # a pick 47 px off the target
    control = GroundControl(control.frame, point_n, control.ground_m, control.sigma_n, control.target, control.use)
    sol = solve_survey(len(Gs), pairs, _no_gps(len(Gs)), control=control)
    assert sol.figures['control_rejected'] == [seen[1]]
    assert _target_rms_m(sol, control, ground, names, set(names) - {'t06'}) < 2.0 * GSD
