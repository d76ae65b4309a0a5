"""The initial ground homographies of a survey's frames (the start of the least-squares solve).

With positions, each frame starts at its position, at the survey's scale, turned by the angle its
pairs imply (their GPS baselines against their registered displacements), else by its attitude or
its track direction plus the camera's median offset from it. Without positions, a part of the
survey is chained along its spanning tree on its root frame's plane (:mod:`.pair_graph`).
"""
from __future__ import annotations

import math

import numpy as np

from .pair_graph import chain_component, pair_components
from .survey_model import FLIP, PairConstraint, SurveyPriors

__all__ = ['angle_scale', 'attitude_angle', 'circular_median', 'initial_placement', 'pair_angles', 'similarity_G']


def circular_median(angles: np.ndarray) -> float:
    a = np.asarray(angles, dtype=np.float64)
    a = a[np.isfinite(a)]
    if not len(a):
        return float('nan')
    mean = math.atan2(float(np.sin(a).mean()), float(np.cos(a).mean()))
    return mean + float(np.median(np.angle(np.exp(1j * (a - mean)))))


def similarity_G(scale: float, angle: float, east: float, north: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[scale * c, scale * s, east], [scale * s, -scale * c, north], [0.0, 0.0, 1.0]])


def angle_scale(G: np.ndarray) -> tuple[float, float]:
    """(angle of the image x axis on the ground, scale) of a ground homography's linear part."""
    a = G[:2, :2] / G[2, 2]
    return math.atan2(a[1, 0], a[0, 0]), math.sqrt(abs(float(np.linalg.det(a))))


def attitude_angle(G: np.ndarray) -> float:
    """Angle of the image x axis on the ground at the principal point of a ground_H_frame (3, 3)
    (attitude_ground_H): the homography's Jacobian there is A - t g^T (G = [[A, t], [g^T, 1]])."""
    G = G / G[2, 2]
    J = G[:2, :2] - np.outer(G[:2, 2], G[2, :2])
    return math.atan2(J[1, 0], J[0, 0])


def pair_angles(pairs: list[PairConstraint], used: np.ndarray, pos: np.ndarray, n: int,
                 min_baseline_m: float) -> list[list[float]]:
    """Per frame, the angle of its image x axis on the ground that each of its pairs implies: the
    GPS baseline's direction minus the registered displacement's direction in the frame (through
    the image's y-down reflection); pairs with a baseline under ``min_baseline_m`` say nothing."""
    out: list[list[float]] = [[] for _ in range(n)]
    for p, u in zip(pairs, used):
        if not u:
            continue
        d = pos[p.j] - pos[p.i]
        if not (np.isfinite(d).all() and np.hypot(*d) >= min_baseline_m):
            continue
        phi = math.atan2(d[1], d[0])
        for k, H, sign in ((p.i, p.i_H_j, 1.0), (p.j, np.linalg.inv(p.i_H_j), -1.0)):
            q = H @ np.array([0.0, 0.0, 1.0])
            qx, qy = q[0] / q[2], q[1] / q[2]
            out[k].append(phi + (0.0 if sign > 0 else math.pi) - math.atan2(-qy, qx))
    return out


def initial_placement(n: int, pairs: list[PairConstraint], used: np.ndarray, pri: SurveyPriors,
             min_extent_m: float, *, every_component: bool = False) -> tuple[np.ndarray, list[str]]:
    """Initial ground_H_frame (N, 3, 3) and placed_by.

    With positions, every frame starts where its position says, at the survey's scale, turned
    by the angle its pairs imply (else its track direction plus the camera's median offset from
    the track): a start a few metres from the solution whatever wrong matches there are, where
    chaining along a spanning tree would carry a wrong match into every frame behind it. Frames
    in a pair are 'registration' (solved), the others 'pose' (kept). Without any position, the
    largest component (every component of two frames or more with ``every_component``: ground
    control will place each) is chained along its spanning tree on its root frame's plane.
    """
    pos = np.asarray(pri.position_m, dtype=np.float64)
    G = np.full((n, 3, 3), np.nan)
    placed_by = [''] * n
    comps = pair_components(n, pairs, used)
    if not np.isfinite(pos).all(axis=1).any():
        for comp in comps[:len(comps) if every_component else 1]:
            if len(comp) < 2:
                continue
            chain = chain_component(comp, pairs, used)
            for k in comp:
                G[k] = FLIP @ chain[k]
                placed_by[k] = 'registration'
        return G, placed_by
    scale = pri.scale_m
    sigma = np.asarray(pri.position_sigma_m, dtype=np.float64)
    base = max(min_extent_m / 2.0, 3.0 * float(np.nanmedian(sigma)) if np.isfinite(sigma).any() else 0.0)
    angles = pair_angles(pairs, used, pos, n, base)
    track = pri.track_rad if pri.track_rad is not None else np.full(n, np.nan)
    own = np.array([circular_median(np.array(a)) if a else np.nan for a in angles])
    offset = circular_median(own - track)
    # no pair to tell it: the default mount, image top toward the nose, so the image x axis (toward
    # the right wing) is 90 deg clockwise of the track
    offset = -math.pi / 2.0 if not math.isfinite(offset) else offset
    known = np.flatnonzero(np.isfinite(own))
    for comp in comps:
        has = [k for k in comp if np.isfinite(pos[k]).all()]
        if not has:
            continue  # a component nothing places on the ground
        for k in comp:
            if math.isfinite(own[k]):
                angle = own[k]
            elif k in pri.shape:  # its own attitude (gimbal yaw): the turn its footprint has
                angle = attitude_angle(pri.shape[k][0])
            elif math.isfinite(track[k]):
                angle = track[k] + offset
            elif len(known):
                angle = own[known[np.argmin(np.abs(known - k))]]
            else:
                angle = 0.0
            if np.isfinite(pos[k]).all():
                e, nn = pos[k]
            else:  # no position of its own: its neighbour's in the component
                e, nn = pos[min(has, key=lambda h: abs(h - k))]
            G[k] = similarity_G(scale, float(angle), float(e), float(nn))
            placed_by[k] = 'registration' if len(comp) >= 2 else 'pose'
    return G, placed_by
