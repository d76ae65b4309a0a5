"""The registration graph of a survey: pairs in normalised coordinates, their agreement with the
GPS baselines, connected parts and the spanning tree that chains each part (most inliers first)."""
from __future__ import annotations

import math

import numpy as np

from .survey_model import h8, PairConstraint, point_jacobian

__all__ = ['chain_component', 'check_pairs_against_positions', 'estimate_scale', 'pair_components', 'pair_constraint']


def pair_constraint(i: int, j: int, i_H_j_px: np.ndarray, covariance_px: np.ndarray | None,
                    K_i: np.ndarray, K_j: np.ndarray, size_i: tuple[int, int], size_j: tuple[int, int], *,
                    grid: int = 4, inliers: int = 0, model_px: float = 1.0) -> PairConstraint | None:
    """PairConstraint, in normalised coordinates, of a registration in pixels.

    i_H_j_px: (3, 3) frame j pixels -> frame i pixels; covariance_px: (8, 8) covariance of its
    entries h00..h21 (h22 = 1), or None (model_px alone); K_i, K_j: (3, 3) intrinsics of the two
    frames as registered; size_i, size_j: (width, height) in pixels. The points are a grid x grid
    lattice over frame j, kept where they land inside frame i (None when fewer than four do); the
    sd of each is that of its transferred position (pixels, from the covariance) and model_px, over
    frame i's focal length.
    """
    wj, hj = size_j
    wi, hi = size_i
    u = (np.arange(grid) + 0.5) / grid
    pts = np.array([[a * (wj - 1), b * (hj - 1)] for b in u for a in u])
    H = np.asarray(i_H_j_px, dtype=np.float64)
    H = H / H[2, 2]
    q = (H @ np.c_[pts, np.ones(len(pts))].T).T
    q = q[:, :2] / q[:, 2:3]
    inside = (q[:, 0] >= 0) & (q[:, 0] <= wi - 1) & (q[:, 1] >= 0) & (q[:, 1] <= hi - 1) & np.isfinite(q).all(axis=1)
    if inside.sum() < 4:
        return None
    pts = pts[inside]
    var = np.full(len(pts), float(model_px) ** 2)
    if covariance_px is not None and np.all(np.isfinite(covariance_px)):
        je, jn = point_jacobian(np.tile(h8(H), (len(pts), 1)), pts)
        cov = np.asarray(covariance_px, dtype=np.float64)
        var += 0.5 * np.maximum(np.einsum('pk,kl,pl->p', je, cov, je) + np.einsum('pk,kl,pl->p', jn, cov, jn), 0.0)
    Ki, Kj = np.asarray(K_i, dtype=np.float64), np.asarray(K_j, dtype=np.float64)
    i_H_j = np.linalg.inv(Ki) @ H @ Kj  # normalised j -> normalised i
    pts_n = (pts - Kj[:2, 2]) / np.diag(Kj)[:2]
    return PairConstraint(i, j, i_H_j / i_H_j[2, 2], pts_n, np.sqrt(var) / float(Ki[0, 0]), int(inliers))


def estimate_scale(pairs: list[PairConstraint], position_m: np.ndarray, min_baseline_m: float) -> float:
    """The frames' scale (metres per normalised unit) as the median ratio of GPS baseline to the
    registered displacement of frame j's principal point in frame i, over pairs whose positions
    are at least ``min_baseline_m`` apart; NaN without such pairs."""
    ratios = []
    for p in pairs:
        d = position_m[p.j] - position_m[p.i]
        base = float(np.hypot(*d))
        q = p.i_H_j @ np.array([0.0, 0.0, 1.0])
        shift = float(np.hypot(q[0] / q[2], q[1] / q[2]))
        if math.isfinite(base) and base >= min_baseline_m and shift > 1e-6:
            ratios.append(base / shift)
    return float(np.median(ratios)) if ratios else float('nan')


def check_pairs_against_positions(pairs: list[PairConstraint], position_m: np.ndarray, sigma_m: np.ndarray,
                                  scale_m: float, *, rel_tolerance: float = 0.25) -> np.ndarray:
    """(P,) bool: whether each pair's registered baseline (scale x the displacement of j's principal
    point in i) agrees with its GPS baseline within 3 sqrt(2) sd plus ``rel_tolerance`` of it;
    True where either is unknown. A wrong match between look-alike places fails it."""
    ok = np.ones(len(pairs), dtype=bool)
    if not math.isfinite(scale_m):
        return ok
    for k, p in enumerate(pairs):
        base = float(np.hypot(*(position_m[p.j] - position_m[p.i])))
        if not math.isfinite(base):
            continue
        q = p.i_H_j @ np.array([0.0, 0.0, 1.0])
        shift = scale_m * float(np.hypot(q[0] / q[2], q[1] / q[2]))
        tol = 3.0 * float(np.hypot(sigma_m[p.i], sigma_m[p.j])) + rel_tolerance * base
        ok[k] = abs(shift - base) <= tol
    return ok


def pair_components(n: int, pairs: list[PairConstraint], used: np.ndarray) -> list[list[int]]:
    """Connected components of the graph of used pairs (singletons included), largest first."""
    parent = list(range(n))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for p, u in zip(pairs, used):
        if u:
            parent[find(p.i)] = find(p.j)
    groups: dict[int, list[int]] = {}
    for k in range(n):
        groups.setdefault(find(k), []).append(k)
    return sorted(groups.values(), key=len, reverse=True)


def chain_component(comp: list[int], pairs: list[PairConstraint], used: np.ndarray) -> dict[int, np.ndarray]:
    """root_H_frame (normalised coordinates of the component's root frame) for every frame of the
    component, along a maximum spanning tree (most inliers first, Prim)."""
    members = set(comp)
    adj: dict[int, list[tuple[int, np.ndarray, int]]] = {k: [] for k in comp}
    for p, u in zip(pairs, used):
        if u and p.i in members:
            adj[p.i].append((p.j, p.i_H_j, p.inliers))
            adj[p.j].append((p.i, np.linalg.inv(p.i_H_j), p.inliers))
    root = max(comp, key=lambda k: sum(w for _, _, w in adj[k]))
    placed = {root: np.eye(3)}
    frontier = [(w, root, k, H) for k, H, w in adj[root]]
    while frontier:
        frontier.sort(key=lambda t: t[0])
        _, a, b, a_H_b = frontier.pop()
        if b in placed:
            continue
        placed[b] = placed[a] @ a_H_b
        placed[b] /= placed[b][2, 2]
        frontier.extend((w, b, k, H) for k, H, w in adj[b] if k not in placed)
    return placed
