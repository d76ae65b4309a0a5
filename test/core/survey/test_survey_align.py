"""Pairs by predicted footprint and the global solve of a survey (core/survey), against the truth of a
synthetic lawnmower: exact ground homographies, noisy registrations, GPS with 2.5 m noise, planted
wrong matches and frames in no pair."""
from __future__ import annotations

import math

import numpy as np
import pytest

from srmosaic_ros.core.georef.frames import R_enu_from_cam_aviation
from srmosaic_ros.core.survey.global_align import (SurveyPriors, attitude_ground_H, check_pairs_against_positions,
                                                   estimate_scale, pair_constraint, solve_survey)
from srmosaic_ros.core.survey.pairs import disc_overlap, predicted_pairs

W, H, F = 1000, 750, 800.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])


def _ground_H(east: float, north: float, agl: float, angle: float, tilt: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    G = np.array([[agl * c, agl * s, east], [agl * s, -agl * c, north], [tilt[0], tilt[1], 1.0]])
    return G


def _lawnmower(lines: int = 4, per_line: int = 10, spacing: float = 20.0, line_gap: float = 40.0, agl: float = 60.0):
    """True ground homographies (normalised -> metres) and positions of a lawnmower survey whose
    camera points its image top along the track (the heading flips on each line)."""
    Gs, pos, track = [], [], []
    rng = np.random.default_rng(3)
    for li in range(lines):
        for k in range(per_line):
            east = k * spacing if li % 2 == 0 else (per_line - 1 - k) * spacing
            north = li * line_gap
            heading = 0.0 if li % 2 == 0 else math.pi  # direction of flight, CCW from east
            angle = heading - math.pi / 2  # image top along the track: x axis 90 deg clockwise of it
            tilt = tuple(rng.normal(0.0, 0.02, 2))
            Gs.append(_ground_H(east, north, agl * (1 + rng.normal(0, 0.02)), angle, tilt))
            pos.append((east, north))
            track.append(heading)
    return np.array(Gs), np.array(pos), np.array(track)


def _pair(Gs: np.ndarray, i: int, j: int, rng: np.random.Generator, noise_px: float = 0.3,
          wrong: bool = False, subtle: bool = False):
    i_H_j = K @ np.linalg.inv(Gs[i]) @ Gs[j] @ np.linalg.inv(K)  # pixels j -> pixels i
    if wrong or subtle:  # a wrong match: the pair registered 25 m (or 12 m) off
        shift = (300.0, -200.0) if wrong else (-120.0, -100.0)
        i_H_j = np.array([[1.0, 0, shift[0]], [0, 1.0, shift[1]], [0, 0, 1]]) @ i_H_j
    cov = np.diag([1e-6, 1e-6, noise_px**2, 1e-6, 1e-6, noise_px**2, 1e-12, 1e-12])
    i_H_j = i_H_j / i_H_j[2, 2]
    i_H_j[:2, 2] += rng.normal(0.0, noise_px, 2)
    return pair_constraint(i, j, i_H_j, cov, K, K, (W, H), (W, H), inliers=200)


def _footprint_wh(agl: float) -> np.ndarray:
    return np.array([agl * W / F, agl * H / F])


def test_disc_overlap_is_one_at_zero_distance_and_zero_beyond_the_diameter():
    assert disc_overlap(0.0, 10.0) == pytest.approx(1.0)
    assert disc_overlap(20.0, 10.0) == pytest.approx(0.0)
    assert 0.3 < float(disc_overlap(8.0, 10.0)) < 0.6


def test_predicted_pairs_find_the_neighbouring_line_and_not_the_far_ones():
    _, pos, _ = _lawnmower()
    wh = np.tile(_footprint_wh(60.0), (len(pos), 1))
    pairs = predicted_pairs(pos, wh, min_overlap=0.2)
    found = {(i, j) for i, j, _ in pairs}
    # frame 0 (line 0, east 0) and frame 19 (line 1, east 0) are 40 m apart: their 75 x 56 m footprints overlap
    assert (0, 19) in found
    assert (0, 39) not in found  # 120 m apart
    assert all((i, i + 1) in found for i in range(len(pos) - 1))
    assert all(f >= 0.2 for i, j, f in pairs if j != i + 1)


def _priors(pos: np.ndarray, track: np.ndarray, rng: np.random.Generator, sigma: float = 2.5) -> SurveyPriors:
    return SurveyPriors(pos + rng.normal(0.0, sigma, pos.shape), np.full(len(pos), sigma), 60.0, track)


def _corner_error_m(G_est: np.ndarray, G_true: np.ndarray) -> float:
    corners = np.linalg.inv(K) @ np.array([[0, W - 1, W - 1, 0], [0, 0, H - 1, H - 1], [1, 1, 1, 1.0]])
    a, b = G_est @ corners, G_true @ corners
    return float(np.sqrt(np.mean(np.sum((a[:2] / a[2] - b[:2] / b[2]) ** 2, axis=0))))


def test_global_solve_places_every_frame_within_its_gps_error_and_drops_planted_wrong_matches():
    rng = np.random.default_rng(0)
    Gs, pos, track = _lawnmower()
    wh = np.tile(_footprint_wh(60.0), (len(pos), 1))
    cand = predicted_pairs(pos, wh, min_overlap=0.2)
    gross, subtle = (3, 4), (12, 27)  # 25 m off (the GPS baselines refute it), 12 m off (only the solve can)
    pairs = [p for p in (_pair(Gs, i, j, rng, wrong=(i, j) == gross, subtle=(i, j) == subtle) for i, j, _ in cand)
             if p is not None]
    wrong = {gross, subtle}
    assert wrong <= {(p.i, p.j) for p in pairs}
    pri = _priors(pos, track, rng)
    sol = solve_survey(len(pos), pairs, pri)
    assert sol.placed_by.count('registration') == len(pos)
    dropped = {(p.i, p.j) for p, u in zip(pairs, sol.pair_used) if not u}
    assert wrong <= dropped, dropped
    assert len(dropped) <= len(wrong) + 2
    errors = [_corner_error_m(sol.ground_H_frame[k], Gs[k]) for k in range(len(pos))]
    # the registrations hold the frames together to centimetres; the GPS noise of 2.5 m over 40
    # positions leaves the whole's offset, turn, scale and tilt (0.8 m RMS over the corners here)
    assert max(errors) < 2.0 and float(np.mean(errors)) < 1.2, errors
    relative = [_corner_error_m(np.linalg.inv(sol.ground_H_frame[0]) @ sol.ground_H_frame[k],
                                np.linalg.inv(Gs[0]) @ Gs[k]) for k in range(len(pos))]
    assert max(relative) < 0.05


def test_frames_in_no_pair_are_placed_by_their_position_and_heading():
    rng = np.random.default_rng(1)
    Gs, pos, track = _lawnmower()
    wh = np.tile(_footprint_wh(60.0), (len(pos), 1))
    lonely = {5, 25}  # textureless: no pair registers
    pairs = [p for p in (_pair(Gs, i, j, rng) for i, j, _ in predicted_pairs(pos, wh, min_overlap=0.2)
                         if i not in lonely and j not in lonely) if p is not None]
    sol = solve_survey(len(pos), pairs, _priors(pos, track, rng))
    assert [sol.placed_by[k] for k in sorted(lonely)] == ['pose', 'pose']
    for k in lonely:
        G = sol.ground_H_frame[k]
        assert np.hypot(G[0, 2] - pos[k, 0], G[1, 2] - pos[k, 1]) < 3 * 2.5 * math.sqrt(2)
        angle = math.atan2(G[1, 0], G[0, 0])
        true = math.atan2(Gs[k][1, 0], Gs[k][0, 0])
        assert abs(math.remainder(angle - true, 2 * math.pi)) < math.radians(5)


def test_scale_and_gps_consistency_checks():
    rng = np.random.default_rng(2)
    Gs, pos, _ = _lawnmower()
    pairs = [_pair(Gs, i, i + 1, rng) for i in range(9)] + [_pair(Gs, 3, 4, rng, wrong=True)]
    scale = estimate_scale(pairs, pos, min_baseline_m=5.0)
    assert scale == pytest.approx(60.0, rel=0.05)
    ok = check_pairs_against_positions(pairs, pos, np.full(len(pos), 2.5), scale)
    assert ok[:9].all() and not ok[9]


def test_without_any_position_the_largest_component_is_solved_on_its_own_plane():
    rng = np.random.default_rng(4)
    Gs, pos, _ = _lawnmower(lines=2)
    wh = np.tile(_footprint_wh(60.0), (len(pos), 1))
    pairs = [p for p in (_pair(Gs, i, j, rng) for i, j, _ in predicted_pairs(pos, wh)) if p is not None]
    pri = SurveyPriors(np.full_like(pos, np.nan), np.full(len(pos), np.nan), 1.0, None)
    sol = solve_survey(len(pos), pairs, pri)
    assert sol.placed_by.count('registration') == len(pos)
    relative = [_corner_error_m(60.0 * np.linalg.inv(sol.ground_H_frame[0]) @ sol.ground_H_frame[k],
                                60.0 * np.linalg.inv(Gs[0]) @ Gs[k]) for k in range(len(pos))]
    assert max(relative) < 0.2


def test_max_per_frame_keeps_each_frames_largest_overlaps():
    _, pos, _ = _lawnmower()
    wh = np.tile(_footprint_wh(60.0) * 3, (len(pos), 1))  # seen from high up: everything overlaps
    every = predicted_pairs(pos, wh, min_overlap=0.2)
    few = predicted_pairs(pos, wh, min_overlap=0.2, max_per_frame=4)
    assert len(few) < len(every) / 3
    for k in range(len(pos)):
        mine = sorted(((f, (i, j)) for i, j, f in every if k in (i, j)), reverse=True)[:4]
        kept = {(i, j) for i, j, _ in few}
        assert all(key in kept for _, key in mine)


def test_attitude_ground_H_of_a_nadir_camera_and_of_a_tilted_one():
    """Nadir, image top to the north: the reflected similarity of scale = height; tilted 10 deg
    forward, the principal ray still meets the ground at the given centre and the image top
    stretches away (a projective term)."""
    G = attitude_ground_H(R_enu_from_cam_aviation(0.0, -90.0, 0.0), np.array([5.0, 7.0]), 60.0)
    assert np.allclose(G, _ground_H(5.0, 7.0, 60.0, 0.0), atol=1e-9)
    G = attitude_ground_H(R_enu_from_cam_aviation(0.0, -80.0, 0.0), np.array([5.0, 7.0]), 60.0)
    c = G @ [0.0, 0.0, 1.0]
    assert np.allclose(c[:2] / c[2], [5.0, 7.0])
    top, bottom = G @ [0.0, -0.4, 1.0], G @ [0.0, 0.4, 1.0]
    assert top[1] / top[2] - 7.0 > 7.0 - bottom[1] / bottom[2] > 0  # farther ground is wider apart
