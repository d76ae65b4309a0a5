"""Global alignment of a stills survey: every frame's ground homography from all pairwise
registrations and the GPS positions at once (the reference's "bundle adjustment against drift").

Model. Frame i has a homography G_i from its normalised image coordinates x^ = K^-1 (u, v, 1)
(intrinsics K; a nominal focal length when unknown) to local ground metres (east, north) of a
flat ground plane. For a nadir camera at height h whose image x axis points at angle a
(counter-clockwise from east), G_i = [[h cos a, h sin a, e], [h sin a, -h cos a, n], [0, 0, 1]]
(the image's y axis points down, the map's north up: a reflection); a tilt adds the projective
terms g6, g7 and the linear part leaves that form.

Least squares over the eight free entries of every G_i (g22 = 1), with residuals in metres
divided by their standard deviations:
- pairs: for a registration i_H_j (frame j -> frame i) and points p of frame j inside the
  overlap, G_i(i_H_j p) - G_j(p), with sd = s0 sqrt(sd_H(p)^2 + sd_model^2): sd_H(p) from the
  registration's covariance propagated to the transferred point (sd_model absorbs what the
  planar model lacks: lens distortion, relief);
- positions: G_i(0, 0) (where the principal ray meets the ground) - the GPS position, sd from
  the receiver and the unknown tilt;
- ground control (core/survey's GroundControl, io/gcp.py): for target X (east, north, metres)
  seen at normalised point x of frame k, G_k(x) - X, with sd sqrt((s0 sd_pick)^2 + sd_survey^2)
  (sd_pick: the pick's pixels over the focal length; s0 the frames' scale);
- shape: (g0 + g4) and (g1 - g3) over s0 (a reflected similarity has both zero), and g6, g7
  (small tilts), and the scale sqrt|det| - s0 over s0: weak priors that keep a frame with few
  constraints from folding;
with Huber's loss on every residual, minimised by Levenberg-Marquardt on the reweighted sparse
normal equations (an analytic Jacobian; see _levenberg_marquardt for why not scipy's solvers). A wrong match that survived RANSAC leaves
a pair whose residuals stand far out from the rest: pairs whose RMS residual exceeds
``reject_sigma`` (and three times the median pair's) are dropped and the solve repeated.

Ground control without GPS: each connected part of the survey is first solved on its root frame's
plane (the root held), then a similarity fit to its control observations (the two-target
hypothesis that most targets agree with, refitted on them) takes it to the ground, and the solve is
repeated with the control and without the roots held: the control fixes position, turn and scale,
and bends out the drift that chained registrations accumulate. The control's residuals are least
squares, not Huber's (a robust loss gives up on the targets that a drifted survey misses by more
than a few sd: they would pull with a bounded force and the drift would stay). A wrong pick or a
wrong target is found instead by leaving each target out in turn (_left_out_outlier: where the
others put it, against its surveyed position) and dropped, the worst first, one per solve.
A part of the survey with fewer than two targets is not placed.

Initialisation: a spanning tree of the registration graph (most inliers first) chains each
connected component, which a similarity fit to its GPS positions places on the ground; frames
in no pair are placed by their position, the survey's median scale and their heading (their own
attitude's, else the track direction plus the camera's median offset from it, or the default
mount's when no frame shows it), and stay fixed (``placed_by`` 'pose').
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp


__all__ = ['GroundControl', 'PairConstraint', 'SurveyPriors', 'SurveySolution', 'check_pairs_against_positions',
           'control_residuals', 'estimate_scale', 'pair_constraint', 'solve_survey']

_FLIP = np.diag([1.0, -1.0, 1.0])


@dataclass(frozen=True)
class PairConstraint:
    """One registered pair: i_H_j maps frame j's normalised coordinates to frame i's; points_j (M, 2)
    normalised coordinates of frame j inside the overlap; sigma (M,) sd of each transferred point,
    normalised units; inliers of the registration."""

    i: int
    j: int
    i_H_j: np.ndarray
    points_j: np.ndarray
    sigma: np.ndarray
    inliers: int = 0


@dataclass(frozen=True)
class SurveyPriors:
    """What the metadata says. position_m (N, 2): ground point of each frame's principal ray,
    metres east/north on the survey's plane (NaN: unknown); position_sigma_m (N,); scale_m: the
    frames' nominal scale (height above ground for a nadir camera, metres per normalised unit);
    track_rad (N,): direction of flight at each frame, counter-clockwise from east (NaN: unknown);
    shape: frame -> (ground_H_frame (3, 3) its attitude and height predict, sd in metres of the
    predicted corner offsets from the centre): where the camera's attitude is known (gimbal angles),
    the footprint's turn, scale and tilt are known to about that (see attitude_ground_H)."""

    position_m: np.ndarray
    position_sigma_m: np.ndarray
    scale_m: float
    track_rad: np.ndarray | None = None
    shape: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)
    shape_sigma: float = 0.05
    perspective_sigma: float = 0.2
    scale_rel_sigma: float = 0.25


@dataclass(frozen=True)
class GroundControl:
    """Observations of surveyed targets. frame (M,) int: the frame each is seen in; point_n (M, 2):
    where, in that frame's normalised coordinates; ground_m (M, 2): the target's surveyed position,
    metres east and north on the survey's plane; sigma_n (M,): sd of the pick, normalised units
    (pixels over the focal length); target (M,): target names; use (M,) bool: the observations that
    constrain the solve (the others, check points and contradicting picks, only get residuals);
    sigma_ground_m: sd of the surveyed positions."""

    frame: np.ndarray
    point_n: np.ndarray
    ground_m: np.ndarray
    sigma_n: np.ndarray
    target: tuple[str, ...]
    use: np.ndarray
    sigma_ground_m: float = 0.02


@dataclass
class SurveySolution:
    """ground_H_frame (N, 3, 3): normalised frame coordinates -> ground metres (NaN: not placed);
    placed_by (N,): 'registration', 'pose' or ''; pair_rms_sigma (P,): RMS residual of each pair
    in its standard deviations; pair_used (P,) bool; figures: counts and residuals for the report;
    control_used (M,) bool: the ground control observations the final solve kept (None: no control)."""

    ground_H_frame: np.ndarray
    placed_by: list[str]
    pair_rms_sigma: np.ndarray
    pair_used: np.ndarray
    figures: dict = field(default_factory=dict)
    control_used: np.ndarray | None = None


def control_residuals(ground_H_frame: np.ndarray, control: GroundControl) -> np.ndarray:
    """(M, 2) G_k(x) - X of every control observation, metres east and north (NaN where frame k
    is not placed)."""
    out = np.full((len(control.frame), 2), np.nan)
    for m, (k, x) in enumerate(zip(control.frame, control.point_n)):
        G = ground_H_frame[int(k)]
        if np.all(np.isfinite(G)):
            q = G @ np.array([x[0], x[1], 1.0])
            out[m] = q[:2] / q[2] - control.ground_m[m]
    return out


def _apply(h: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(E, N, den) of homographies h (P, 8) applied to points pts (P, 2)."""
    x, y = pts[:, 0], pts[:, 1]
    den = h[:, 6] * x + h[:, 7] * y + 1.0
    e = (h[:, 0] * x + h[:, 1] * y + h[:, 2]) / den
    n = (h[:, 3] * x + h[:, 4] * y + h[:, 5]) / den
    return e, n, den


def _point_jac(h: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d(E)/dh and d(N)/dh, each (P, 8)."""
    x, y = pts[:, 0], pts[:, 1]
    e, n, den = _apply(h, pts)
    z = np.zeros_like(x)
    je = np.stack([x, y, np.ones_like(x), z, z, z, -e * x, -e * y], axis=1) / den[:, None]
    jn = np.stack([z, z, z, x, y, np.ones_like(x), -n * x, -n * y], axis=1) / den[:, None]
    return je, jn


def _scale(h: np.ndarray) -> np.ndarray:
    """(P,) sqrt|det| of the linear parts of homographies h (P, 8): metres per normalised unit."""
    return np.sqrt(np.maximum(np.abs(h[:, 0] * h[:, 4] - h[:, 1] * h[:, 3]), 1e-12))


def _scale_jac(h: np.ndarray) -> np.ndarray:
    """(P, 8) derivative of _scale."""
    det = h[:, 0] * h[:, 4] - h[:, 1] * h[:, 3]
    g = np.sign(det) / (2.0 * _scale(h))
    out = np.zeros((len(h), 8))
    out[:, 0], out[:, 4], out[:, 1], out[:, 3] = g * h[:, 4], g * h[:, 0], -g * h[:, 3], -g * h[:, 1]
    return out


_SHAPE_POINTS = np.array([[-0.5, -0.4], [0.5, -0.4], [0.5, 0.4], [-0.5, 0.4]])


def attitude_ground_H(R_enu_from_cam: np.ndarray, centre_m: np.ndarray, height_m: float) -> np.ndarray:
    """(3, 3) ground_H_frame of a camera (normalised coordinates -> ground metres) whose optical centre
    is ``height_m`` above the flat ground and whose principal ray meets it at ``centre_m`` (east,
    north), looking along R_enu_from_cam's z axis (eqs. 4.23-4.29 for a single pose). A ray
    d = R (x, y, 1) from C meets the ground at C_xy - C_z d_xy / d_z, i.e. the homography rows
    (C_xy R_2 - C_z R_01) over R_2, normalised to g22 = 1."""
    R = np.asarray(R_enu_from_cam, dtype=np.float64)
    axis = R[:, 2]
    C = np.array([centre_m[0] + height_m * axis[0] / axis[2], centre_m[1] + height_m * axis[1] / axis[2], height_m])
    G = np.vstack([C[0] * R[2] - C[2] * R[0], C[1] * R[2] - C[2] * R[1], R[2]])
    return G / G[2, 2]


def _h8(H: np.ndarray) -> np.ndarray:
    H = H / H[2, 2]
    return H.ravel()[:8].copy()


def _H(h: np.ndarray) -> np.ndarray:
    return np.append(h, 1.0).reshape(3, 3)


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
        je, jn = _point_jac(np.tile(_h8(H), (len(pts), 1)), pts)
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


def _components(n: int, pairs: list[PairConstraint], used: np.ndarray) -> list[list[int]]:
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


def _chain_component(comp: list[int], pairs: list[PairConstraint], used: np.ndarray) -> dict[int, np.ndarray]:
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


def _circular_median(angles: np.ndarray) -> float:
    a = np.asarray(angles, dtype=np.float64)
    a = a[np.isfinite(a)]
    if not len(a):
        return float('nan')
    mean = math.atan2(float(np.sin(a).mean()), float(np.cos(a).mean()))
    return mean + float(np.median(np.angle(np.exp(1j * (a - mean)))))


def _similarity_G(scale: float, angle: float, east: float, north: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[scale * c, scale * s, east], [scale * s, -scale * c, north], [0.0, 0.0, 1.0]])


def _angle_scale(G: np.ndarray) -> tuple[float, float]:
    """(angle of the image x axis on the ground, scale) of a ground homography's linear part."""
    a = G[:2, :2] / G[2, 2]
    return math.atan2(a[1, 0], a[0, 0]), math.sqrt(abs(float(np.linalg.det(a))))


def _attitude_angle(G: np.ndarray) -> float:
    """Angle of the image x axis on the ground at the principal point of a ground_H_frame (3, 3)
    (attitude_ground_H): the homography's Jacobian there is A - t g^T (G = [[A, t], [g^T, 1]])."""
    G = G / G[2, 2]
    J = G[:2, :2] - np.outer(G[:2, 2], G[2, :2])
    return math.atan2(J[1, 0], J[0, 0])


def _pair_angles(pairs: list[PairConstraint], used: np.ndarray, pos: np.ndarray, n: int,
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


def _initial(n: int, pairs: list[PairConstraint], used: np.ndarray, pri: SurveyPriors,
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
    comps = _components(n, pairs, used)
    if not np.isfinite(pos).all(axis=1).any():
        for comp in comps[:len(comps) if every_component else 1]:
            if len(comp) < 2:
                continue
            chain = _chain_component(comp, pairs, used)
            for k in comp:
                G[k] = _FLIP @ chain[k]
                placed_by[k] = 'registration'
        return G, placed_by
    scale = pri.scale_m
    sigma = np.asarray(pri.position_sigma_m, dtype=np.float64)
    base = max(min_extent_m / 2.0, 3.0 * float(np.nanmedian(sigma)) if np.isfinite(sigma).any() else 0.0)
    angles = _pair_angles(pairs, used, pos, n, base)
    track = pri.track_rad if pri.track_rad is not None else np.full(n, np.nan)
    own = np.array([_circular_median(np.array(a)) if a else np.nan for a in angles])
    offset = _circular_median(own - track)
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
                angle = _attitude_angle(pri.shape[k][0])
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
            G[k] = _similarity_G(scale, float(angle), float(e), float(nn))
            placed_by[k] = 'registration' if len(comp) >= 2 else 'pose'
    return G, placed_by


class _Problem:
    """Residuals and their sparse Jacobian over the free frames (module docstring)."""

    def __init__(self, free: list[int], pairs: list[PairConstraint], use: np.ndarray, pri: SurveyPriors,
                 scale: float, anchor: dict[int, np.ndarray], control: GroundControl | None = None,
                 control_use: np.ndarray | None = None) -> None:
        self.col = {k: c for c, k in enumerate(free)}
        self.n = len(free)
        self.sel_pairs, self.sel_use = pairs, use
        sel = [p for p, u in zip(pairs, use) if u and p.i in self.col and p.j in self.col]
        self.pair_of_point = np.concatenate([np.full(len(p.points_j), k) for k, p in enumerate(sel)]) \
            if sel else np.zeros(0, int)
        self.sel = sel
        if sel:
            self.ci = np.concatenate([np.full(len(p.points_j), self.col[p.i]) for p in sel])
            self.cj = np.concatenate([np.full(len(p.points_j), self.col[p.j]) for p in sel])
            pj = np.concatenate([p.points_j for p in sel])
            qi = np.concatenate([(p.i_H_j @ np.c_[p.points_j, np.ones(len(p.points_j))].T).T for p in sel])
            self.pj, self.qi = pj, qi[:, :2] / qi[:, 2:3]
            self.w = 1.0 / np.concatenate([p.sigma for p in sel])
        else:
            self.ci = self.cj = np.zeros(0, int)
            self.pj = self.qi = np.zeros((0, 2))
            self.w = np.zeros(0)
        pos = np.asarray(pri.position_m, dtype=np.float64)
        self.gps = [(self.col[k], pos[k], 1.0 / float(pri.position_sigma_m[k])) for k in free
                    if np.isfinite(pos[k]).all() and math.isfinite(float(pri.position_sigma_m[k]))]
        self.scale = scale
        self.pri = pri
        self.anchor = [(self.col[k], _h8(H)) for k, H in anchor.items() if k in self.col]
        ctl = [] if control is None or control_use is None else \
            [m for m in range(len(control.frame)) if control_use[m] and int(control.frame[m]) in self.col]
        self.ctl_index = np.array(ctl, dtype=int)
        if ctl:
            self.ctl_col = np.array([self.col[int(control.frame[m])] for m in ctl])
            self.ctl_pts = control.point_n[ctl]
            self.ctl_ground = control.ground_m[ctl]
            self.ctl_w = 1.0 / np.hypot(scale * control.sigma_n[ctl], control.sigma_ground_m)
        shp = [(self.col[k], G, sd) for k, (G, sd) in pri.shape.items() if k in self.col]
        if shp:
            m = len(_SHAPE_POINTS)
            self.shape_col = np.repeat([c for c, _, _ in shp], m)
            self.shape_pts = np.tile(_SHAPE_POINTS, (len(shp), 1))
            tgt = []
            for _, G, _ in shp:
                hp = np.tile(_h8(G), (m, 1))
                e, nn, _ = _apply(hp, _SHAPE_POINTS)
                e0, n0, _ = _apply(hp[:1], np.zeros((1, 2)))
                tgt.append(np.stack([e - e0, nn - n0], axis=1))
            self.shape_target = np.concatenate(tgt)
            self.shape_w = np.repeat([1.0 / sd for _, _, sd in shp], m)
        else:
            self.shape_col = np.zeros(0, int)

    def _transfer(self, h: np.ndarray, *, jacobian: bool = False) -> tuple:
        """Transfer error of every pair point in frame i's normalised coordinates: the ground point
        of frame j's point p, G_j p, taken back through G_i^-1, minus i_H_j p. Returns ((ry, rx),
        d r / d h_i (P, 2, 8), d r / d h_j (P, 2, 8)); rows of r are (x, y)."""
        Gi = np.concatenate([h, np.ones((self.n, 1))], axis=1).reshape(self.n, 3, 3)
        Mi = np.linalg.inv(Gi)[self.ci]  # (P, 3, 3)
        e, n, _ = _apply(h[self.cj], self.pj)
        X = np.stack([e, n, np.ones_like(e)], axis=1)
        y = np.einsum('pab,pb->pa', Mi, X)
        rx, ry = y[:, 0] / y[:, 2] - self.qi[:, 0], y[:, 1] / y[:, 2] - self.qi[:, 1]
        if not jacobian:
            return (ry, rx), None, None
        z = y[:, 2]
        dr_dy = np.zeros((len(z), 2, 3))
        dr_dy[:, 0, 0] = dr_dy[:, 1, 1] = 1.0 / z
        dr_dy[:, 0, 2], dr_dy[:, 1, 2] = -y[:, 0] / z**2, -y[:, 1] / z**2
        je, jn = _point_jac(h[self.cj], self.pj)
        dX = np.stack([je, jn], axis=1)  # (P, 2, 8)
        dr_dhj = np.einsum('pay,pyx,pxk->pak', dr_dy, Mi[:, :, :2], dX)
        # d(G^-1) = -G^-1 dG G^-1: entry k of G (row a, column b) moves y by -M[:, a] y[b]
        dy_dhi = np.zeros((len(z), 3, 8))
        for k in range(8):
            a, b = divmod(k, 3)
            dy_dhi[:, :, k] = -Mi[:, :, a] * y[:, b:b + 1]
        dr_dhi = np.einsum('pay,pyk->pak', dr_dy, dy_dhi)
        return (ry, rx), dr_dhi, dr_dhj

    def residuals(self, x: np.ndarray) -> np.ndarray:
        h = x.reshape(self.n, 8)
        out = []
        if len(self.w):
            ry, rx = self._transfer(h)[0]
            out += [rx * self.w, ry * self.w]
        if self.gps:
            c = np.array([g[0] for g in self.gps])
            target = np.array([g[1] for g in self.gps])
            w = np.array([g[2] for g in self.gps])
            out += [(h[c, 2] - target[:, 0]) * w, (h[c, 5] - target[:, 1]) * w]
        s0, pri = self.scale, self.pri
        out += [(h[:, 0] + h[:, 4]) / (s0 * pri.shape_sigma), (h[:, 1] - h[:, 3]) / (s0 * pri.shape_sigma),
                h[:, 6] / pri.perspective_sigma, h[:, 7] / pri.perspective_sigma,
                (_scale(h) - s0) / (s0 * pri.scale_rel_sigma)]
        if len(self.shape_col):
            hs = h[self.shape_col]
            e, nn, _ = _apply(hs, self.shape_pts)
            e0, n0, _ = _apply(hs, np.zeros_like(self.shape_pts))
            out += [(e - e0 - self.shape_target[:, 0]) * self.shape_w, (nn - n0 - self.shape_target[:, 1]) * self.shape_w]
        if len(self.ctl_index):
            e, nn, _ = _apply(h[self.ctl_col], self.ctl_pts)
            out += [(e - self.ctl_ground[:, 0]) * self.ctl_w, (nn - self.ctl_ground[:, 1]) * self.ctl_w]
        for c, target in self.anchor:  # no positions anywhere: the root holds the gauge
            out.append((h[c] - target) * 1e3)
        return np.concatenate(out)

    def control_rows(self) -> slice:
        """The rows of the control residuals in residuals()."""
        start = 2 * len(self.w) + 2 * len(self.gps) + 5 * self.n + 2 * len(self.shape_col)
        return slice(start, start + 2 * len(self.ctl_index))

    def control_sigmas(self, x: np.ndarray) -> np.ndarray:
        """(C,) RMS over east and north of each control observation's residual, in its sd."""
        if not len(self.ctl_index):
            return np.zeros(0)
        e, nn, _ = _apply(x.reshape(self.n, 8)[self.ctl_col], self.ctl_pts)
        r = np.stack([e - self.ctl_ground[:, 0], nn - self.ctl_ground[:, 1]], axis=1) * self.ctl_w[:, None]
        return np.sqrt(np.mean(r**2, axis=1))

    def jacobian(self, x: np.ndarray) -> sp.csr_matrix:
        h = x.reshape(self.n, 8)
        rows, cols, vals = [], [], []
        r0 = 0
        m = len(self.w)
        if m:
            (ry, rx), dr_dhi, dr_dhj = self._transfer(h, jacobian=True)
            idx = np.arange(m)
            for block in range(2):
                r = r0 + block * m + idx
                for k in range(8):
                    rows += [r, r]
                    cols += [self.ci * 8 + k, self.cj * 8 + k]
                    vals += [dr_dhi[:, block, k] * self.w, dr_dhj[:, block, k] * self.w]
            r0 += 2 * m
        if self.gps:
            c = np.array([g[0] for g in self.gps])
            w = np.array([g[2] for g in self.gps])
            g = len(c)
            rows += [r0 + np.arange(g), r0 + g + np.arange(g)]
            cols += [c * 8 + 2, c * 8 + 5]
            vals += [w, w]
            r0 += 2 * g
        n, s0, pri = self.n, self.scale, self.pri
        f = np.arange(n)
        ks = 1.0 / (s0 * pri.shape_sigma)
        for block, entries in enumerate((((0, ks), (4, ks)), ((1, ks), (3, -ks)))):
            for k, v in entries:
                rows.append(r0 + block * n + f)
                cols.append(f * 8 + k)
                vals.append(np.full(n, v))
        r0 += 2 * n
        for block, k in enumerate((6, 7)):
            rows.append(r0 + block * n + f)
            cols.append(f * 8 + k)
            vals.append(np.full(n, 1.0 / pri.perspective_sigma))
        r0 += 2 * n
        ds = _scale_jac(h) / (s0 * pri.scale_rel_sigma)
        for k in (0, 1, 3, 4):
            rows.append(r0 + f)
            cols.append(f * 8 + k)
            vals.append(ds[:, k])
        r0 += n
        if len(self.shape_col):
            hs = h[self.shape_col]
            je, jn = _point_jac(hs, self.shape_pts)
            je0, jn0 = _point_jac(hs, np.zeros_like(self.shape_pts))
            q = len(self.shape_col)
            for block, (j1, j0) in enumerate(((je, je0), (jn, jn0))):
                for k in range(8):
                    rows.append(r0 + block * q + np.arange(q))
                    cols.append(self.shape_col * 8 + k)
                    vals.append((j1[:, k] - j0[:, k]) * self.shape_w)
            r0 += 2 * q
        if len(self.ctl_index):
            je, jn = _point_jac(h[self.ctl_col], self.ctl_pts)
            q = len(self.ctl_index)
            for block, jac in enumerate((je, jn)):
                for k in range(8):
                    rows.append(r0 + block * q + np.arange(q))
                    cols.append(self.ctl_col * 8 + k)
                    vals.append(jac[:, k] * self.ctl_w)
            r0 += 2 * q
        for c, _ in self.anchor:
            rows.append(r0 + np.arange(8))
            cols.append(c * 8 + np.arange(8))
            vals.append(np.full(8, 1e3))
            r0 += 8
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, n * 8))

    def pair_rms(self, x: np.ndarray) -> np.ndarray:
        """RMS normalised residual of each selected pair."""
        m = len(self.w)
        if not m:
            return np.zeros(0)
        r = self.residuals(x)[:2 * m].reshape(2, m)  # (x, y) rows
        sq = np.bincount(self.pair_of_point, weights=(r**2).sum(axis=0), minlength=len(self.sel))
        cnt = np.bincount(self.pair_of_point, minlength=len(self.sel)) * 2
        return np.sqrt(sq / np.maximum(cnt, 1))


def _huber_cost(r: np.ndarray, k: float, plain: slice | None = None) -> float:
    """Huber's cost of residuals r, with threshold k; rows ``plain``: squares (least squares)."""
    a = np.abs(r)
    c = np.where(a <= k, 0.5 * a * a, k * a - 0.5 * k * k)
    if plain is not None:
        c[plain] = 0.5 * a[plain] ** 2
    return float(np.sum(c))


def _levenberg_marquardt(prob: _Problem, x0: np.ndarray, huber: float, *, max_iterations: int = 100,
                         rel_tol: float = 1e-9, plain: slice | None = None) -> tuple[np.ndarray, int, bool]:
    """Minimise the Huber cost of prob's residuals: Levenberg-Marquardt on the iteratively
    reweighted normal equations (J^T W J + mu diag(J^T W J)) dx = -J^T W r, solved as a sparse
    system (SuperLU). Returns (x, iterations, converged).

    Not scipy.optimize.least_squares: with LSMR its 'trf' converges far more slowly on this problem
    (a 40-frame lawnmower: not within 200 evaluations, where this needs about ten), and its dense
    'exact' solver costs time and memory that grow with the square of the frames."""
    from scipy.sparse.linalg import spsolve

    x = x0.copy()
    r = prob.residuals(x)
    cost = _huber_cost(r, huber, plain)
    mu = 1e-4
    for it in range(1, max_iterations + 1):
        J = prob.jacobian(x)
        a = np.abs(r)
        w = np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-300))
        if plain is not None:
            w[plain] = 1.0
        JtW = J.T @ sp.diags(w)
        A = (JtW @ J).tocsc()
        g = JtW @ r
        d = A.diagonal() + 1e-12
        while True:
            dx = spsolve(A + sp.diags(mu * d), -g)
            xn = x + dx
            rn = prob.residuals(xn)
            cn = _huber_cost(rn, huber, plain) if np.all(np.isfinite(rn)) else math.inf
            if cn < cost:
                break
            mu *= 10.0
            if mu > 1e10:
                return x, it, True  # no step lowers the cost: at the minimum
        done = cost - cn <= rel_tol * cost
        x, r, cost = xn, rn, cn
        mu = max(mu / 10.0, 1e-12)
        if done:
            return x, it, True
    return x, max_iterations, False


def _control_similarity(G: np.ndarray, placed_by: list[str], control: GroundControl,
                        use: np.ndarray) -> np.ndarray | None:
    """(3, 3) ground_S_plane: the similarity (turn, scale, shift; no reflection) from a survey solved
    on its own plane to the ground that most control targets agree with. Every two observations of
    different targets propose one; the proposal with the most targets within a tenth of the
    targets' spread (then the smallest error) is refitted by least squares on those. None with
    fewer than two targets seen in placed frames."""
    idx = [m for m in range(len(control.frame)) if use[m] and placed_by[int(control.frame[m])]]
    if len({control.target[m] for m in idx}) < 2:
        return None
    sub = GroundControl(control.frame[idx], control.point_n[idx], control.ground_m[idx], control.sigma_n[idx],
                        tuple(control.target[m] for m in idx), np.ones(len(idx), bool), control.sigma_ground_m)
    p_xy = control_residuals(G, sub) + sub.ground_m  # where the plane puts each observation
    p = p_xy[:, 0] + 1j * p_xy[:, 1]
    X = sub.ground_m[:, 0] + 1j * sub.ground_m[:, 1]
    spread = float(np.sqrt(np.mean(np.abs(X - X.mean()) ** 2)))
    tol = max(0.1 * spread, 0.5)
    names = np.array(sub.target)
    best, best_key = None, None
    for a in range(len(idx)):
        for b in range(a + 1, len(idx)):
            if names[a] == names[b] or abs(p[a] - p[b]) < 1e-9 or abs(X[a] - X[b]) < 1e-6:
                continue
            s_ab = (X[a] - X[b]) / (p[a] - p[b])
            err = np.abs(s_ab * (p - p[a]) + X[a] - X)
            inl = err <= tol
            key = (len(set(names[inl])), -float(np.minimum(err, tol).sum()))
            if best_key is None or key > best_key:
                best, best_key = inl, key
    if best is None:
        return None
    A = np.stack([p[best], np.ones(int(best.sum()))], axis=1)
    (s_fit, t_fit), *_ = np.linalg.lstsq(A, X[best], rcond=None)
    return np.array([[s_fit.real, -s_fit.imag, t_fit.real], [s_fit.imag, s_fit.real, t_fit.imag], [0.0, 0.0, 1.0]])


def _left_out_outlier(prob: _Problem, x: np.ndarray, huber: float, control: GroundControl, use: np.ndarray,
                      reject_sigma: float, left_out: dict[str, np.ndarray]) -> list[int]:
    """The control observations to drop, found by leaving each target out in turn: [] when none.

    With the control fitted by least squares a wrong point bends the survey to itself and its own
    residual stays small; left out, the others and the registrations say where it is. Each target
    used is left out once (the solve warm-started from x) and the ground points of its picks
    compared with its surveyed position:
    - one pick away from the target's other picks (three or more; by more than reject_sigma times
      the pick's sd and three times the median such distance over all targets): that pick is wrong;
    - the target's mean off by more than reject_sigma sd and three times the median of the others':
      its coordinates (or all its picks) are wrong, all its picks go.
    The most extreme of these goes, one per solve; nothing goes where the median target left out is
    itself more than reject_sigma sd off (the test cannot tell a wrong point from the survey's own
    error there). ``left_out`` gets each target's mean residual (metres, east and north)."""
    ci = prob.ctl_index
    names = sorted({control.target[m] for m in ci})
    if len(names) < 4:
        return []
    scale = prob.scale
    sd = np.hypot(scale * control.sigma_n, control.sigma_ground_m)  # (M,) metres
    per: dict[str, tuple[np.ndarray, list[int], np.ndarray]] = {}
    for t in names:
        mine = [int(m) for m in ci if control.target[m] == t]
        rest = use.copy()
        rest[mine] = False
        sub = _Problem([k for k in prob.col], prob.sel_pairs, prob.sel_use, prob.pri, scale, {}, control, rest)
        xt, _, _ = _levenberg_marquardt(sub, x, huber, plain=sub.control_rows(), max_iterations=30)
        h = xt.reshape(prob.n, 8)
        cols = np.array([prob.col[int(control.frame[m])] for m in mine])
        e, nn, _ = _apply(h[cols], control.point_n[mine])
        r = np.stack([e, nn], axis=1) - control.ground_m[mine]
        per[t] = (r.mean(axis=0), mine, r)
        left_out[t] = r.mean(axis=0)
    # The test has power only where the survey, each target left out, still puts the targets within
    # a few sd of their surveyed positions; where it misses them all by far more (drift, relief),
    # a wrong point cannot be told from the survey's own error, and nothing is dropped.
    typical_sd = float(np.median(sd[ci]))
    if float(np.median([np.hypot(*per[t][0]) for t in per])) > reject_sigma * typical_sd:
        return []
    worst: tuple[float, list[int]] = (0.0, [])
    # how far a pick strays from its target's other picks when the target is left out, over all
    # targets: what the registrations between its stills allow (drift, relief), not a wrong pick
    spread = {t: np.hypot(*(r - np.median(r, axis=0)).T) for t, (_, mine, r) in per.items() if len(mine) >= 3}
    usual = float(np.median(np.concatenate(list(spread.values())))) if spread else 0.0
    for t, (mean, mine, _) in per.items():
        if t in spread:  # one pick against the target's others
            dev = spread[t]
            k = int(np.argmax(dev))
            z = float(dev[k] / sd[mine[k]])
            if z > reject_sigma and dev[k] > 3.0 * max(usual, 1e-9) and z > worst[0]:
                worst = (z, [mine[k]])
        err = float(np.hypot(*mean))
        others = np.median([float(np.hypot(*per[o][0])) for o in per if o != t])
        z = err / float(np.mean(sd[mine]))
        if z > reject_sigma and err > 3.0 * others and z > worst[0]:
            worst = (z, mine)
    return worst[1]


def solve_survey(n: int, pairs: list[PairConstraint], priors: SurveyPriors, *, min_extent_m: float = 10.0,
                 reject_sigma: float = 5.0, rounds: int = 4, huber_sigma: float = 2.0,
                 control: GroundControl | None = None, control_reject_sigma: float = 5.0,
                 control_loss: str = 'squares') -> SurveySolution:
    """Solve every frame's ground homography (module docstring).

    Args:
        n: number of frames; pairs: registered pairs (PairConstraint, normalised coordinates);
        priors: positions, their sd, the nominal scale and the flight direction;
        min_extent_m: a component's GPS positions must spread this far (RMS) to fit its own similarity;
        reject_sigma: a pair whose RMS residual exceeds this many sd (and 3x the median pair's) is dropped;
        rounds: solves at most (each after dropping pairs); huber_sigma: Huber's threshold, in sd;
        control: ground control observations (None: none); control_reject_sigma: a control pick or
            target that the others place this many sd away (and three times further than the median
            target) is dropped, the worst first (_left_out_outlier); control_loss: 'squares' (the
            survey bends to the control: the drift between targets is solved out) or 'huber' (each
            observation's residual in Huber's loss, dropped beyond control_reject_sigma: robust, but
            the control can no longer bend a survey that has drifted by more than a few sd).
    """
    use = np.ones(len(pairs), dtype=bool)
    pos = np.asarray(priors.position_m, dtype=np.float64)
    georeferenced = bool(np.isfinite(pos).all(axis=1).any())
    gross = 0
    rejected_positions: list[int] = []
    if georeferenced and math.isfinite(priors.scale_m):
        # A wrong match between look-alike places: its baseline disagrees with the GPS baseline.
        # A wrong position (a receiver's glitch): most of its still's pairs disagree; then the
        # position goes, not the pairs.
        sd = np.asarray(priors.position_sigma_m, dtype=np.float64)
        ok = check_pairs_against_positions(pairs, pos, sd, priors.scale_m)
        fails, count = np.zeros(n), np.zeros(n)
        for p, good in zip(pairs, ok):
            for k in (p.i, p.j):
                count[k] += 1
                fails[k] += not good
        rejected_positions = [k for k in range(n) if fails[k] >= 2 and fails[k] > 0.5 * count[k]]
        if rejected_positions:
            pos = pos.copy()
            pos[rejected_positions] = np.nan
            priors = dataclasses.replace(priors, position_m=pos)
            ok = check_pairs_against_positions(pairs, pos, sd, priors.scale_m)
        use &= ok
        gross = int((~use).sum())
    by_control = control is not None and not georeferenced
    G, placed_by = _initial(n, pairs, use, priors, min_extent_m, every_component=by_control)
    free = [k for k in range(n) if placed_by[k] == 'registration']
    rms = np.full(len(pairs), np.nan)
    ctl_use = None if control is None else np.asarray(control.use, dtype=bool).copy()
    ctl_rejected: list[int] = []
    state: dict = {'iterations': 0, 'converged': False, 'dropped': 0, 'left_out': {}}

    def run(held: bool, with_control: bool, max_rounds: int) -> None:
        nonlocal free
        scale = float(np.median([_angle_scale(G[k])[1] for k in free])) if free else priors.scale_m
        for _ in range(max(max_rounds, 1)):
            if not free:
                break
            # held: each component's first frame holds its gauge
            anchor = {c[0]: G[c[0]].copy() for c in _components(n, pairs, use) if c[0] in free} if held else {}
            prob = _Problem(free, pairs, use, priors, scale, anchor, control if with_control else None, ctl_use)
            x0 = np.concatenate([_h8(G[k]) for k in free])
            x, iterations, state['converged'] = _levenberg_marquardt(
                prob, x0, huber_sigma, plain=prob.control_rows() if control_loss == 'squares' else None)
            state['iterations'] += iterations
            sol = x.reshape(-1, 8)
            for c, k in enumerate(free):
                G[k] = _H(sol[c])
            pr = prob.pair_rms(x)
            idx = [k for k, (p, u) in enumerate(zip(pairs, use)) if u and p.i in prob.col and p.j in prob.col]
            rms[:] = np.nan
            rms[idx] = pr
            med = float(np.median(pr)) if len(pr) else 0.0
            bad = [k for k, r in zip(idx, pr) if r > reject_sigma and r > 3.0 * med]
            if with_control and not georeferenced:
                # nothing but the registrations holds a part of the survey to the rest: a pair whose
                # loss would cut it off stays (the control bends it instead)
                parts = len(_components(n, pairs, use))
                bad = [k for k in bad if len(_components(n, pairs, use & (np.arange(len(use)) != k))) == parts]
            wrong: list[int] = []
            if with_control and control_loss == 'squares' and not bad:
                wrong = _left_out_outlier(prob, x, huber_sigma, control, ctl_use, control_reject_sigma,
                                          state['left_out'])
            elif with_control and control_loss == 'huber':
                cs = prob.control_sigmas(x)
                worst = int(np.argmax(cs)) if len(cs) else -1
                if worst >= 0 and cs[worst] > control_reject_sigma and cs[worst] > 3.0 * float(np.median(cs)) \
                        and len({control.target[m] for m in prob.ctl_index}) > 2:
                    wrong = [int(prob.ctl_index[worst])]
            ctl_bad = bool(wrong)
            for m in wrong:  # one pick or one target per solve: the others may have been bent by it
                ctl_use[m] = False
                ctl_rejected.append(m)
            if not bad and not ctl_bad:
                break
            use[bad] = False
            state['dropped'] += len(bad)
            # a frame left in no pair keeps its place from the last solve, as placed by its pose
            in_pair = {p.i for p, u in zip(pairs, use) if u} | {p.j for p, u in zip(pairs, use) if u}
            for k in free:
                if k not in in_pair:
                    placed_by[k] = 'pose'
            free = [k for k in free if k in in_pair]

    if by_control:
        # each component on its root's plane, then to the ground by its own control; a component
        # with fewer than two targets cannot be placed with the others
        run(True, False, rounds)
        placed_any = False
        for comp in _components(n, pairs, use):
            members = [k for k in comp if placed_by[k]]
            if not members:
                continue
            in_comp = np.isin(control.frame, members)
            S = _control_similarity(G, placed_by, control, ctl_use & in_comp)
            if S is None:
                for k in members:
                    G[k], placed_by[k] = np.nan, ''
                continue
            placed_any = True
            for k in members:
                G[k] = S @ G[k]
        by_control = placed_any
        free = [k for k in range(n) if placed_by[k] == 'registration']
        if by_control:
            run(False, True, rounds + int(ctl_use.sum()))
        else:  # no component holds two targets: back to the largest, on its own plane
            G, placed_by = _initial(n, pairs, use, priors, min_extent_m)
            free = [k for k in range(n) if placed_by[k] == 'registration']
            run(True, False, rounds)
    else:
        run(not georeferenced, control is not None, rounds + (int(ctl_use.sum()) if control is not None else 0))
    solved = [k for k in range(n) if placed_by[k] == 'registration']
    if solved:  # frames placed by their pose take the solved survey's scale
        s_med = float(np.median([_angle_scale(G[k])[1] for k in solved]))
        for k in range(n):
            if placed_by[k] == 'pose':
                angle, s_k = _angle_scale(G[k])
                G[k] = _similarity_G(s_med, angle, float(G[k][0, 2]), float(G[k][1, 2]))
    gps_res = []
    for k in range(n):
        if placed_by[k] and np.isfinite(pos[k]).all():
            gps_res.append(float(np.hypot(G[k][0, 2] / G[k][2, 2] - pos[k, 0], G[k][1, 2] / G[k][2, 2] - pos[k, 1])))
    figures = {'pairs': len(pairs), 'pairs_used': int(use.sum()), 'pairs_against_gps': gross,
               'pairs_dropped': state['dropped'], 'positions_rejected': rejected_positions,
               'frames_by_registration': placed_by.count('registration'), 'frames_by_pose': placed_by.count('pose'),
               'frames_not_placed': placed_by.count(''),
               'median_pair_rms_sigma': float(np.nanmedian(rms)) if np.isfinite(rms).any() else None,
               'position_residual_rms_m': float(np.sqrt(np.mean(np.square(gps_res)))) if gps_res else None,
               'solver_iterations': state['iterations'], 'solver_converged': state['converged']}
    if control is not None:
        figures['control_placed_survey'] = by_control  # no GPS: the control alone put it on the ground
        # each control target's residual when the solve leaves it out (metres east, north; the last test)
        figures['control_left_out_m'] = {t: [round(float(v), 4) for v in r] for t, r in state['left_out'].items()}
        figures['control_rejected'] = ctl_rejected
    return SurveySolution(G, placed_by, rms, use, figures, ctl_use)
