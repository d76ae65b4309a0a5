"""Drift control: a Kalman filter that fuses a chained frame placement with the pose-predicted one,
the pose errors being a Gauss-Markov process whose time constants come from the pose filter.

Two estimates of where frame k lies on the raster (its four corners, c in R^8, raster pixels):

- the chain: the previous frame's corrected placement times the registration, c_k^- ; precise
  from frame to frame (registration corner noise sigma_reg: a few hundredths to a few tenths of
  a pixel), but its errors accumulate;
- the pose: the corners of the flat-ground footprint of the fused pose, z_k. Its error is the
  error y_k of (east, north, up, roll, pitch, yaw, ground height) carried to the corners, J_k y_k
  (J_k = d corners / d y, numerical), with covariance P_k (7 x 7, FramePose.pose_ground_covariance:
  the footprint scales with the height above the ground, and at first the ground height is the
  largest uncertainty), plus a flat-ground model error n_k (white, sigma_model =
  ``homography_min_sigma_px`` per coordinate: relief, residual distortion).

Pose error model (first-order Gauss-Markov, from the filter). The filtered pose errors are not
independent from frame to frame: the same fixes and attitudes drive many consecutive frames, so
y_k wanders slowly, and averaging the poses as independent measurements copies that wander into
the mosaic; a fixed discount per frame would be right at one frame rate and one filter bandwidth
only. A Kalman filter that fuses information at the rate Lambda (information per second: the sum
of R_i^-1 of the measurements of one second) corrects its own error at the rate P Lambda:
dP/dt = Q - P Lambda P, and the error obeys dy/dt = -P Lambda y + (driving noise). In the
normalised error u = P^-1/2 y this is du/dt = -M u + w, M = P^1/2 Lambda P^1/2 (symmetric;
its eigenvalues are 1 / tau_i, one time constant per direction: for a GNSS position with variance
R at f Hz and a fused position variance P, tau = R / (f P) = 6.25 m^2 / (5 Hz * 0.2 m^2) ~ 6 s;
the attitudes renewed by a 50 Hz IMU well under a second). Lambda is what the Georeferencer counts
of the absolute measurements it fused (FramePose.info_rate: fixes, IMU attitudes), raised to the
growth of the pose's own information where that is faster, Lambda >= (P_k^-1 - P_(k-1)^-1) / dt
(dP^-1/dt = Lambda - P^-1 Q P^-1: a converging filter, or the ground height and tilt that only the
registrations measure). Over the actual spacing dt of two frames (their stamps)::

    y_k = A_k y_(k-1) + v_k,   E = exp(-M_k dt),
    A_k = P_k^1/2 E P_(k-1)^-1/2,   Cov(v_k) = P_k^1/2 (I - E^2) P_k^1/2

so that Cov(y_k) = P_k at every frame and the correlation of consecutive errors is
exp(-dt / tau): the frame rate enters through dt only, and the poses bring the same information
per second at any frame rate (twice the frames, each worth about half). With a configured time
constant tau (georef.drift_pose_time_constant_s), M = I / tau in every direction; tau = 0 makes
the pose errors white (independent from frame to frame).

Chain error model. The chain's error moves with the chain: a rotation or scale error of frame
k-1's placement displaces frame k (it is placed through it): delta_k = F_k delta_(k-1) + w_k, with
F_k = d corners_k / d corners_(k-1) of ``placed_(k-1) @ prev_H_cur`` (numerical) and w_k the
registration noise carried to the raster, Cov(w_k) = sigma_reg^2 D D^T per corner (D the local
Jacobian of the previous placement).

The canvas frame. A chain starts where the first frame's pose puts it, with that pose's error
(metres at the start of a flight, and a scale error as large as the ground height's uncertainty).
Correcting that anchor error live would move frames painted later against frames painted earlier:
distortion, not drift control. The anchor error's similarity part s = (tx, ty, theta, sigma)
(offset, rotation, scale about the anchor) is common to the whole mosaic, the *canvas frame*, and
is what the offline re-anchoring takes out (a similarity fitted on all smoothed poses,
anchoring.py). So the filter estimates the placement in the canvas frame: c^seg_k = c_k + G_k s,
G_k = d corners / d s (similarity_jacobian), s constant; delta_k = c^seg_k - c_k^- is the chain's
error in that frame, and what is left of the anchor error (the tilt's perspective part, r_0) is
corrected like drift. Later chains on the same canvas (segments after a registration failure) start
in the canvas frame, E(s_hat) times their first pose placement, so that the segments stay
consistent with each other.

The filter. State x = (delta_k, s, y_k), 8 + 4 + 7 values, covariance Sigma::

    predict:  Sigma <- Phi Sigma Phi^T + diag(Cov(w_k), 0, Cov(v_k)),  Phi = diag(F_k, I, A_k),
              y_hat <- A_k y_hat                  (the chained corners are the predicted c^seg_k)
    update:   z_k - c_k^- = delta_k - G_k s + J_k y_k + n_k:
              nu = z_k - c_k^- + G_k s_hat - J_k y_hat,  H = [I_8, -G_k, J_k],  R = sigma_model^2 I_8,
              S = H Sigma H^T + R,  K = Sigma H^T S^-1,  (c^seg_k, s_hat, y_hat) += K nu,
              Sigma <- (I - K H) Sigma (I - K H)^T + K R K^T
    start:    the first chain: J_0 y_0 = G_0 s + r_0 (least squares), delta_0 = -r_0, i.e.
              x_0 = T y_0 with T = (-(I - G L) J_0, L J_0, I), L = (G^T G)^-1 G^T;
              a later chain: delta_0 = G_0 (s - s_hat) - J_0 y_0

The corrected homography maps the frame corners exactly onto the updated c^seg_k and is fed back
into the chain. Slow pose wander is estimated (y_hat) instead of being copied into the mosaic,
and a persistent difference that a similarity explains goes into s_hat instead of bending it.
The live canvas is thus consistent but keeps the anchor's similarity error (Georeferencer.
canvas_similarity estimates it) until the outputs are re-anchored.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from .ground_homography import apply_H, homographies_from_corners, homography_from_corners

__all__ = ['AbsoluteInformation', 'CanvasSimilarity', 'DriftState', 'InformationRate', 'chain_jacobian', 'drift_init', 'drift_step',
           'pose_error_transition', 'scaled_drift', 'scaled_similarity', 'similarity_homography', 'similarity_jacobian']

_CORNERS = 8
_SIM = slice(8, 12)
_POSE = slice(12, None)


@dataclass
class CanvasSimilarity:
    """The estimated similarity error s = (tx, ty, theta, sigma) of a canvas (see the module doc):
    the canvas frame is the true one moved by tx, ty (px), turned by theta (rad) and scaled by
    1 + sigma about ``origin`` (raster px); ``cov`` (4, 4) its covariance."""

    origin: np.ndarray
    sim: np.ndarray
    cov: np.ndarray

    @property
    def homography(self) -> np.ndarray:
        """(3, 3) raster pixel of the true frame -> the canvas frame, E(s) (first order in s)."""
        return similarity_homography(self.sim, self.origin)


@dataclass
class DriftState:
    """The drift controller of one chain: the last placement returned (3, 3), the stamp and (d, d)
    covariance of the last pose fused, the canvas similarity's origin (2,), the estimates of the
    similarity (4,) and of the pose error (d,), and the covariance (12 + d, 12 + d) of (the
    chain's error of the 8 corner coordinates, the similarity, the pose error); d = 7 in the
    Georeferencer (the pose and the ground height). ``nis``: the normalised innovation squared
    nu^T S^-1 nu of the last pose update (chi-square with 8 degrees of freedom when the chain and
    the pose model agree); NaN before the first update and after a step without a pose."""

    placed: np.ndarray
    stamp_ns: int
    pose_cov: np.ndarray
    origin: np.ndarray
    sim: np.ndarray
    pose_error: np.ndarray
    cov: np.ndarray
    nis: float = float('nan')

    @property
    def canvas(self) -> CanvasSimilarity:
        return CanvasSimilarity(self.origin.copy(), self.sim.copy(), self.cov[_SIM, _SIM].copy())


def scaled_similarity(canvas: CanvasSimilarity, zoom: float) -> CanvasSimilarity:
    """``canvas`` on a raster sampled ``zoom`` times finer about pixel (0, 0) (new pixel = zoom x old):
    the origin and the offset (tx, ty) scale by zoom, the angle and scale error do not."""
    t = np.array([zoom, zoom, 1.0, 1.0])
    return CanvasSimilarity(canvas.origin * zoom, canvas.sim * t, canvas.cov * np.outer(t, t))


def scaled_drift(state: DriftState, zoom: float) -> DriftState:
    """``state`` on a raster sampled ``zoom`` times finer about pixel (0, 0) (new pixel = zoom x old):
    x' = T x with T = diag(zoom I_8, zoom, zoom, 1, 1, I_d) (corner errors and the similarity's offset
    in pixels; its angle and scale, and the pose error, in their own units), Sigma' = T Sigma T^T, the
    placement and the similarity's origin scaled by zoom."""
    t = np.ones(state.cov.shape[0])
    t[:_CORNERS + 2] = zoom
    placed = np.diag([zoom, zoom, 1.0]) @ state.placed
    return DriftState(placed, state.stamp_ns, state.pose_cov.copy(), state.origin * zoom, state.sim * t[_SIM],
                      state.pose_error.copy(), state.cov * np.outer(t, t), state.nis)


class InformationRate:
    """Information per second of one kind of measurement (sum of R^-1, (d, d)), averaged over the last
    ``window_s``: the sum over the window divided by the span it covers, which is the window, or
    early on the time since the first measurement plus one mean interval (a single measurement so
    far: the window). Stamps are expected in (nearly) increasing order."""

    def __init__(self, dim: int, window_s: float) -> None:
        self.window_ns = int(window_s * 1e9)
        self._items: deque[tuple[int, np.ndarray]] = deque()
        self._sum = np.zeros((dim, dim))
        self._first_ns: int | None = None
        self._last_ns = 0
        self._count = 0

    def add(self, stamp_ns: int, info: np.ndarray) -> None:
        stamp_ns = int(stamp_ns)
        self._items.append((stamp_ns, info))
        self._sum += info
        self._first_ns = stamp_ns if self._first_ns is None else min(self._first_ns, stamp_ns)
        self._last_ns = max(self._last_ns, stamp_ns)
        self._count += 1

    def rate(self, stamp_ns: int) -> np.ndarray:
        """(d, d) information per second at ``stamp_ns`` (measurements older than the window are dropped)."""
        horizon = int(stamp_ns) - self.window_ns
        while self._items and self._items[0][0] <= horizon:
            self._sum -= self._items.popleft()[1]
        if not self._items:
            self._sum[:] = 0.0
            return self._sum.copy()
        assert self._first_ns is not None
        if self._count < 2:
            span_ns = self.window_ns
        else:
            interval = (self._last_ns - self._first_ns) / (self._count - 1)
            span_ns = min(self.window_ns, max(int(stamp_ns) - self._first_ns, 0) + interval)
        return self._sum / max(span_ns * 1e-9, 1e-9)


def _sqrt_psd(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P^1/2, P^-1/2) of a symmetric positive semi-definite matrix (pseudo-inverse on null directions)."""
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    w = np.clip(w, 0.0, None)
    keep = w > max(float(w.max()), 0.0) * 1e-14
    root = np.sqrt(w)
    inv_root = np.where(keep, 1.0 / np.where(keep, root, 1.0), 0.0)
    return (V * root) @ V.T, (V * inv_root) @ V.T


def pose_error_transition(P_prev: np.ndarray, P_cur: np.ndarray, dt_s: float, *,
                          info_rate: np.ndarray | None = None,
                          time_constant_s: float = float('nan')) -> tuple[np.ndarray, np.ndarray]:
    """(A, Q): the Gauss-Markov step y_k = A y_(k-1) + v, Cov(v) = Q, of the pose error between two
    frames dt_s apart, with the marginal covariances P_prev, P_cur (d, d) of the two poses.

    ``time_constant_s`` finite: M = I / tau (0: white errors, A = 0, Q = P_cur); else M = P^1/2
    Lambda P^1/2 with Lambda the information rate: ``info_rate`` (d, d, information per second of
    the absolute measurements; None: none), raised where the pose's own information grows faster,
    (P_cur^-1 - P_prev^-1) / dt_s (a converging filter: information from the registrations too).
    No information at all: no renewal, the error persists."""
    dim = P_cur.shape[0]
    s_cur, s_cur_inv = _sqrt_psd(P_cur)
    _, s_prev_inv = _sqrt_psd(P_prev)
    dt = max(float(dt_s), 0.0)
    if math.isfinite(time_constant_s):
        decay = 0.0 if time_constant_s <= 0.0 else math.exp(-dt / time_constant_s)
        E, E2 = decay * np.eye(dim), decay**2 * np.eye(dim)
    else:
        lam = np.zeros((dim, dim)) if info_rate is None else np.asarray(info_rate, dtype=np.float64)
        lam = 0.5 * (lam + lam.T)
        if dt > 0.0:
            gained = (s_cur_inv @ s_cur_inv - s_prev_inv @ s_prev_inv) / dt
            w, V = np.linalg.eigh(0.5 * (gained - lam + (gained - lam).T))
            lam = lam + (V * np.clip(w, 0.0, None)) @ V.T
        M = s_cur @ lam @ s_cur
        w, V = np.linalg.eigh(0.5 * (M + M.T))
        w = np.clip(w, 0.0, None)
        E = (V * np.exp(-w * dt)) @ V.T
        E2 = (V * np.exp(-2.0 * w * dt)) @ V.T
    A = s_cur @ E @ s_prev_inv
    Q = s_cur @ (np.eye(dim) - E2) @ s_cur
    return A, 0.5 * (Q + Q.T)


def chain_jacobian(placed_prev: np.ndarray, prev_H_cur: np.ndarray, corners: np.ndarray,
                   step_px: float = 0.5) -> np.ndarray:
    """(8, 8) d corners_k / d corners_(k-1): how an error of the previous placement's corners moves the
    corners of ``placed_prev @ prev_H_cur`` (central differences; the map is smooth)."""
    base = apply_H(placed_prev, corners).ravel()
    q = np.c_[apply_H(prev_H_cur, corners), np.ones(4)]
    d = step_px * np.eye(_CORNERS)
    Hs = homographies_from_corners(corners, np.concatenate([base + d, base - d]).reshape(-1, 4, 2))
    p = Hs @ q.T                                          # (16, 3, 4): the 8 shifted placements, + then -
    moved = (p[:, :2] / p[:, 2:3]).transpose(0, 2, 1).reshape(2 * _CORNERS, _CORNERS)
    return ((moved[:_CORNERS] - moved[_CORNERS:]) / (2.0 * step_px)).T


def _local_jacobians(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2, 2) Jacobians of the homography H at points (N, 2)."""
    p = np.c_[points, np.ones(len(points))] @ H.T
    w = p[:, 2:3]
    uv = p[:, :2] / w
    return (H[None, :2, :2] - uv[:, :, None] * H[None, 2:3, :2]) / w[:, :, None]


def similarity_jacobian(corners_flat: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """(8, 4) G = d corners / d s of a similarity error s = (tx, ty, theta, sigma) about ``origin``
    at s = 0, for corners (8,) flattened x0, y0, x1, ...: a point p moves by
    (tx - theta (p - o)_y + sigma (p - o)_x, ty + theta (p - o)_x + sigma (p - o)_y)."""
    p = np.asarray(corners_flat, dtype=np.float64).reshape(-1, 2) - np.asarray(origin, dtype=np.float64)
    G = np.zeros((2 * len(p), 4))
    G[0::2, 0] = 1.0
    G[1::2, 1] = 1.0
    G[0::2, 2], G[1::2, 2] = -p[:, 1], p[:, 0]
    G[0::2, 3], G[1::2, 3] = p[:, 0], p[:, 1]
    return G


def similarity_homography(sim: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """(3, 3) E(s): p -> o + [[1 + sigma, -theta], [theta, 1 + sigma]] (p - o) + (tx, ty)."""
    tx, ty, theta, sigma = (float(v) for v in sim)
    ox, oy = (float(v) for v in origin)
    a, b = 1.0 + sigma, theta
    return np.array([[a, -b, ox + tx - a * ox + b * oy], [b, a, oy + ty - b * ox - a * oy], [0.0, 0.0, 1.0]])


def drift_init(placed: np.ndarray, stamp_ns: int, pose_cov: np.ndarray, J: np.ndarray, corners: np.ndarray,
               canvas: CanvasSimilarity | None = None) -> tuple[DriftState, np.ndarray]:
    """(state, placement) of a chain anchored at ``placed`` by a pose with covariance pose_cov (d, d)
    and corner Jacobian J (8, d).

    No ``canvas`` yet (the first chain on it): the anchor defines the canvas; its corner error is
    the pose's, J y_0 = G s + r_0 (the similarity s it puts into the canvas, the rest r_0 the chain's
    error delta_0 = -r_0), and ``placed`` is returned unchanged. On an existing canvas the chain is
    placed in the canvas frame, E(s_hat) placed, with delta_0 = G (s - s_hat) - J y_0."""
    P = 0.5 * (pose_cov + pose_cov.T)
    dim = len(P)
    placed = np.asarray(placed, dtype=np.float64)
    if canvas is None:
        c = apply_H(placed, corners).ravel()
        origin = c.reshape(-1, 2).mean(axis=0)
        G = similarity_jacobian(c, origin)
        L = np.linalg.solve(G.T @ G, G.T)  # least-squares similarity of a corner error
        T = np.vstack([-(np.eye(_CORNERS) - G @ L) @ J, L @ J, np.eye(dim)])  # state = T y_0
        cov = T @ P @ T.T
        sim = np.zeros(4)
    else:
        origin, sim = canvas.origin.copy(), canvas.sim.copy()
        placed = canvas.homography @ placed
        placed = placed / placed[2, 2]
        G = similarity_jacobian(apply_H(placed, corners).ravel(), origin)
        T = np.block([[G, -J], [np.eye(4), np.zeros((4, dim))], [np.zeros((dim, 4)), np.eye(dim)]])
        base = np.zeros((4 + dim, 4 + dim))
        base[:4, :4], base[4:, 4:] = canvas.cov, P
        cov = T @ base @ T.T
    state = DriftState(placed, int(stamp_ns), P, origin, sim, np.zeros(dim), 0.5 * (cov + cov.T))
    return state, placed


def drift_step(state: DriftState, chained: np.ndarray, corners: np.ndarray, chain_sigma_px: float,
               pose: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None, *, model_sigma_px: float,
               info_rate: np.ndarray | None, time_constant_s: float) -> np.ndarray:
    """One frame of drift control: predict with the chained placement (3, 3), update with the pose
    ``(stamp_ns, predicted corners (8,), J (8, d), covariance (d, d))`` when there is one. Updates
    ``state`` in place and returns the corrected placement (3, 3) (the chained one without a pose)."""

    chained = np.asarray(chained, dtype=np.float64)
    prev_H_cur = np.linalg.solve(state.placed, chained)  # includes any outside correction
    F = chain_jacobian(state.placed, prev_H_cur, corners)
    D = _local_jacobians(state.placed, apply_H(prev_H_cur, corners))
    n = len(state.cov)
    Phi = np.eye(n)  # the similarity is constant
    Phi[:_CORNERS, :_CORNERS] = F
    Q = np.zeros_like(Phi)
    for i in range(4):
        Q[2 * i:2 * i + 2, 2 * i:2 * i + 2] = chain_sigma_px**2 * D[i] @ D[i].T
    c = apply_H(chained, corners).ravel()
    if pose is None:
        state.cov = Phi @ state.cov @ Phi.T + Q
        state.placed, state.nis = chained, float('nan')
        return chained
    stamp_ns, z, J, P = pose
    A, Qy = pose_error_transition(state.pose_cov, P, (int(stamp_ns) - state.stamp_ns) * 1e-9,
                                  info_rate=info_rate, time_constant_s=time_constant_s)
    Phi[_POSE, _POSE] = A
    Q[_POSE, _POSE] = Qy
    cov = Phi @ state.cov @ Phi.T + Q
    y = A @ state.pose_error
    G = similarity_jacobian(c, state.origin)
    H = np.hstack([np.eye(_CORNERS), -G, J])  # z - c = delta - G s + J y + n
    R = max(model_sigma_px, 1e-3) ** 2 * np.eye(_CORNERS)
    S = H @ cov @ H.T + R
    K = np.linalg.solve(S, H @ cov).T  # cov H^T S^-1 (S and cov symmetric)
    nu = np.asarray(z, dtype=np.float64) - c + G @ state.sim - J @ y
    dx = K @ nu
    # how far the pose's placement lies from the chain's, in their sigma: evidence whether the pose
    # model (with no attitude measured, the mount assumed) fits the footage
    state.nis = float(nu @ np.linalg.solve(S, nu))
    c = c + dx[:_CORNERS]
    IKH = np.eye(n) - K @ H
    cov = IKH @ cov @ IKH.T + K @ R @ K.T
    out = homography_from_corners(corners, c.reshape(4, 2))
    state.placed, state.stamp_ns, state.pose_cov = out, int(stamp_ns), 0.5 * (P + P.T)
    state.sim, state.pose_error, state.cov = state.sim + dx[_SIM], y + dx[_POSE], 0.5 * (cov + cov.T)
    return out


class AbsoluteInformation:
    """The absolute measurements fused (R^-1 of the fixes: position block; of the IMU attitudes:
    attitude block), each an :class:`InformationRate` over ``window_s``, for FramePose.info_rate;
    ``last`` is the (6, 6) rate of the latest frame, the drift controller's fallback."""

    def __init__(self, window_s: float) -> None:
        self._kinds = {'fix': InformationRate(3, window_s), 'imu': InformationRate(3, window_s)}
        self.last: np.ndarray | None = None

    def add(self, kind: str, stamp_ns: int, R: np.ndarray) -> None:
        """Count one measurement of ``kind`` ('fix' or 'imu') with covariance R (3, 3)."""
        try:
            info = np.linalg.inv(0.5 * (R + R.T))
        except np.linalg.LinAlgError:
            return
        self._kinds[kind].add(stamp_ns, info)

    def rate(self, stamp_ns: int) -> np.ndarray:
        """(6, 6) information per second before ``stamp_ns``: fixes in the position block, IMU attitudes
        in the attitude block (non-decreasing stamps)."""
        out = np.zeros((6, 6))
        out[:3, :3] = self._kinds['fix'].rate(stamp_ns)
        out[3:, 3:] = self._kinds['imu'].rate(stamp_ns)
        return out
