"""The pose UKF of the dissertation's Table 6: the two most recent poses, fused with GNSS, IMU and video.

State (13,), float64: the poses of the body at the two most recent frame stamps (4.21, 4.22), the
12 values of Table 6, and the height of the ground plane::

    x = [y_prev, y_cur, g],   y = (east_m, north_m, up_m, roll_rad, pitch_rad, yaw_rad)

position of the body origin (where the GNSS antenna is) in a local ENU plane, attitude of the body
(x forward, y left, z up) in ENU as REP 103 fixed-axis roll, pitch, yaw
(:func:`frames.R_enu_from_body`); g is the ENU height of the flat ground (m). Angles are kept
continuous in the state (yaw is not wrapped between the two slots) and wrapped on output.

Why g: a homography only constrains the camera's height *above the ground* (d in 4.28), while
GNSS measures ellipsoidal heights; with the ground height fixed at a guess (first fix minus a
nominal AGL, 5 m wrong with a 5 m vertical GNSS sigma) every registration's translation is scaled
wrongly and the fused track is biased. With g in the state, the ratio of GNSS horizontal
displacement to image motion estimates the height above ground, and g follows. It is a slow
random walk (terrain is not exactly flat); it drops out of the pose slots' predict, so the pose
part of the filter is Table 6's.

Motion model (predict, at each new frame stamp t_k): the slots shift, y_prev <- y_cur, and the new
current pose is extrapolated at constant velocity from the two poses,
``y_cur <- y_cur + r (y_cur - y_prev)`` with r = dt_k / dt_(k-1), plus white acceleration noise
(standard deviation ``accel * dt**2`` per axis). Linear, so the unscented predict is exact.

Measurement models (updates, each a filterpy ``UnscentedKalmanFilter.update`` with its own hx and
R; sigma points are regenerated from the current (x, P) before each one, so sequential updates are
correct; the two linear ones, GNSS and IMU orientation, take the Kalman update that the unscented
one is exactly equal to for a linear hx, computed directly, see PoseUkf._update):

- GNSS fix at time t in [t_prev, t_cur]: the ENU position interpolated linearly between the two
  slots, ``(1 - a) p_prev + a p_cur``, a = (t - t_prev) / (t_cur - t_prev); R = the fix's ENU
  covariance plus the interpolation's model error (the motion model's acceleration sigma times
  (t - t_prev)(t_cur - t) / 2). Telemetry between frames is thus used at its own time stamp, which
  is what two poses in the state allow.
- IMU orientation at time t: the interpolated (roll, pitch, yaw); R = the message's orientation
  covariance (small angles: rotation-vector covariance ~ Euler-angle covariance near level
  flight); the measurement is wrapped to within pi of the prediction.
- Gyro: the body rotation from t_prev to t_cur integrated from the angular velocities of the Imu
  messages between the two frames, a relative measurement of the two slots,
  ``log(R_prev^T R_cur)``; R from the per-sample gyro noise and a bias allowance. The homography
  of a narrow nadir view hardly separates a small rotation from a translation (pitch by dtheta
  moves the image like a displacement of d dtheta), so without a precise relative attitude the
  absolute attitude noise of the IMU leaks into the position as frame-to-frame jitter
  (docs/results.md, "Georeferencing"); the gyro removes it.
- Homography prev_H_cur of a registration (Table 6, 4.30 to 4.39): predicted by the flat-ground
  model (4.28, 4.29) of the two camera poses in the state, :func:`frame2_H_frame1` with frame 1 the
  current camera and frame 2 the previous one. The 8 free entries of H are expressed as the
  positions in the previous frame of the current frame's 4 corners (the "4-point"
  parametrisation: a one-to-one, smooth change of coordinates of the same 8 numbers, in pixels,
  so that S = P_hh + R is well conditioned; the entries of h span 12 orders of magnitude). The
  registration's covariance P_h of (h00 .. h21) (4.43) is carried into corner space by the
  Jacobian of that map, J P_h J^T, plus an isotropic model-error floor (non-flat ground,
  residual distortion, time-stamp jitter).

The two nonlinear updates (homography, gyro) are iterated: after the UKF pass, the sigma points
are redrawn from the posterior and the update of the prior is repeated with the statistical
linearisation there (posterior linearisation, up to ``UkfParams.iterations`` passes, see
:func:`_batch_update`); this keeps the filter consistent while the ground height is still far
from its prior.

Every update is gated by its Mahalanobis distance (chi-square at ``gate_probability``): a wrong
registration or a GNSS outlier is refused rather than fused. After ``max_gated_in_a_row``
refusals in a row of one kind the filter admits it is the one that is wrong: the absolute
uncertainty of both slots is inflated together (relative motion untouched) and the measurement is
fused.

Sigma points: ``MerweScaledSigmaPoints`` with alpha = 1, beta = 2, kappa = 0 by default (2L + 1 =
27 points at +-sqrt(L) sigma; weights Wm_0 = 0, Wc_0 = 2, the others 1 / 2L, none negative). The reference's L + kappa = 3
(4.32) is available (kappa = 3 - L) but is not the default: with L = 13 it gives a central weight
of -3.3, which biases the height on simulated flights (docs/results.md, "Georeferencing").

Offline, :func:`rts_smooth` runs the Rauch-Tung-Striebel recursion over the stored moments of a
run (the predict is linear, so it is exact for this filter's Gaussian approximation).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from scipy.spatial.transform import Rotation
from scipy.special import chdtri

from .frames import R_enu_from_body, rotvec_from_matrix
from .ground_homography import apply_H
from .rts_smoother import rts_smooth
from .ukf_models import (
    UkfParams,
    _EPS_VAR,
    GROUND,
    POSE_DIM,
    SLOT_CUR,
    SLOT_PREV,
    STATE_DIM,
    CameraMount,
    _interpolation_matrix,
    _R_enu_from_body_batch,
    _sym,
    corner_jacobian,
    homography_model,
    homography_model_batch,
    nearest_positive_definite,
    transition_matrix,
    wrap_angle,
)
from .ukf_updates import _batch_update, _linear_update

__all__ = [
    'POSE_DIM',
    'STATE_DIM',
    'GROUND',
    'SLOT_PREV',
    'SLOT_CUR',
    'CameraMount',
    'UkfParams',
    'UpdateResult',
    'PoseUkf',
    'corner_jacobian',
    'rts_smooth',
    'transition_matrix',
    'wrap_angle',
]


@dataclass(frozen=True)
class UpdateResult:
    """Outcome of one measurement update: 'accepted', 'gated' (refused as an outlier),
    'reacquired' (accepted after inflating the uncertainty) or 'failed' (numerical)."""

    status: str
    mahalanobis2: float = float('nan')

    @property
    def accepted(self) -> bool:
        return self.status in ('accepted', 'reacquired')



class PoseUkf:
    """The 12-state UKF (see the module docstring). Times are integer nanoseconds.

    Use: ``initialize`` once, then per frame ``advance(stamp)`` followed by any number of
    ``update_*`` calls for measurements with stamps in [t_prev, t_cur].
    """

    def __init__(self, params: UkfParams | None = None) -> None:
        self.params = params or UkfParams()
        p = self.params
        points = MerweScaledSigmaPoints(STATE_DIM, alpha=p.alpha, beta=p.beta, kappa=p.kappa)
        self.ukf = UnscentedKalmanFilter(dim_x=STATE_DIM, dim_z=3, dt=1.0, hx=_slot_cur_position,
                                         fx=_constant_velocity, points=points)
        self.t_prev_ns: int | None = None
        self.t_cur_ns: int | None = None
        self._rate_known = False
        self.last_F: np.ndarray | None = None  # the transition of the latest advance
        self._gated_in_a_row: dict[str, int] = {}
        self._gate_cache: dict[int, float] = {}

    # -- state ---------------------------------------------------------------------------------
    @property
    def initialized(self) -> bool:
        return self.t_cur_ns is not None

    @property
    def x(self) -> np.ndarray:
        return self.ukf.x

    @property
    def P(self) -> np.ndarray:
        return self.ukf.P

    def pose(self, slot: slice = SLOT_CUR) -> tuple[np.ndarray, np.ndarray]:
        """(pose (6,), covariance (6, 6)) of one slot; yaw wrapped to (-pi, pi]."""
        y = self.ukf.x[slot].copy()
        y[5] = wrap_angle(y[5])
        return y, self.ukf.P[slot, slot].copy()

    @property
    def angle_sd_limit_rad(self) -> float:
        """The largest angle standard deviation (rad) the sigma points represent: they lie at
        +-alpha sqrt(n + kappa) sd from the mean, and beyond +-pi a yaw point aliases onto another
        heading (the homography model is periodic in it), so the unscented mean is meaningless."""
        p = self.params
        return math.pi / (p.alpha * math.sqrt(STATE_DIM + p.kappa))

    @property
    def ground_z(self) -> tuple[float, float]:
        """(height of the ground plane in ENU, its variance), m and m^2."""
        return float(self.ukf.x[GROUND]), float(self.ukf.P[GROUND, GROUND])

    def initialize(self, stamp_ns: int, pose6: np.ndarray, cov6: np.ndarray, ground_z_m: float = 0.0,
                   ground_var_m2: float = 1.0) -> None:
        """Both slots at ``pose6`` (the same pose: velocity unknown until the next frame), the
        ground plane at ``ground_z_m`` with variance ``ground_var_m2`` (> 0). Angle standard
        deviations above :attr:`angle_sd_limit_rad` (an unknown heading) are reduced to it."""
        pose6 = np.asarray(pose6, dtype=np.float64)
        cov6 = _sym(np.asarray(cov6, dtype=np.float64))
        # an unknown yaw (sd 90 deg) would put sigma points +-325 deg apart, onto other headings
        sd = np.sqrt(np.maximum(np.diag(cov6)[3:], 0.0))
        shrink = np.ones(POSE_DIM)
        shrink[3:] = np.minimum(1.0, self.angle_sd_limit_rad / np.maximum(sd, 1e-300))
        cov6 = cov6 * np.outer(shrink, shrink)
        self.ukf.x = np.r_[pose6, pose6, ground_z_m]
        P = np.zeros((STATE_DIM, STATE_DIM))
        P[SLOT_PREV, SLOT_PREV] = P[SLOT_PREV, SLOT_CUR] = P[SLOT_CUR, SLOT_PREV] = cov6
        P[SLOT_CUR, SLOT_CUR] = cov6 + _EPS_VAR * np.eye(POSE_DIM)
        P[GROUND, GROUND] = max(float(ground_var_m2), _EPS_VAR)
        self.ukf.P = P
        self.t_prev_ns = self.t_cur_ns = int(stamp_ns)
        self._rate_known = False
        self._gated_in_a_row.clear()

    def advance(self, stamp_ns: int) -> None:
        """Predict to a new frame stamp (> t_cur): shift the slots, extrapolate at constant velocity."""
        if self.t_cur_ns is None or self.t_prev_ns is None:
            msg = 'PoseUkf.advance before initialize'
            raise RuntimeError(msg)
        if stamp_ns <= self.t_cur_ns:
            msg = f'PoseUkf.advance to {stamp_ns} ns, not after the current {self.t_cur_ns} ns'
            raise ValueError(msg)
        p = self.params
        dt = (stamp_ns - self.t_cur_ns) * 1e-9
        dt_prev = (self.t_cur_ns - self.t_prev_ns) * 1e-9
        ratio = dt / dt_prev if (self._rate_known and dt_prev > 0.0) else 0.0
        q = np.empty(POSE_DIM)
        q[0:2] = (p.accel_sigma_h_m_s2 * dt * dt) ** 2
        q[2] = (p.accel_sigma_v_m_s2 * dt * dt) ** 2
        q[3:6] = (p.angular_accel_sigma_rad_s2 * dt * dt) ** 2
        if not self._rate_known:  # first step: the velocity is not known at all
            q[0:3] += (p.initial_speed_sigma_m_s * dt) ** 2
            q[3:6] += (p.initial_rate_sigma_rad_s * dt) ** 2
        # The white angular acceleration makes the attitude's extrapolation error grow as dt^2 (80 deg
        # over 2 s at 20 deg/s^2); an aircraft's attitude does not wander that far between two frames,
        # and sigma points at +-3.6 such sigmas make the homography and gyro models meaningless (unbounded,
        # the filter diverges on stills 2 s apart). Bounded per step; inactive below 1 s at the defaults.
        q[3:6] = np.minimum(q[3:6], p.max_attitude_step_sigma_rad**2)
        Q = np.zeros((STATE_DIM, STATE_DIM))
        Q[SLOT_PREV, SLOT_PREV] = _EPS_VAR * np.eye(POSE_DIM)
        Q[SLOT_CUR, SLOT_CUR] = np.diag(q)
        Q[GROUND, GROUND] = p.ground_walk_m_per_sqrt_s**2 * dt + _EPS_VAR
        self.ukf.Q = Q
        try:
            np.linalg.cholesky(self.ukf.P)
        except np.linalg.LinAlgError:  # numerically lost definiteness: repair rather than fail
            self.ukf.P = nearest_positive_definite(self.ukf.P)
        # The motion model is linear (x' = F x): the unscented transform of filterpy's predict is
        # then exact, x' = F x and P' = F P F^T + Q, so it is computed directly (27 sigma points
        # through fx in a Python loop cost more than the rest of the step). The updates draw their
        # sigma points from (x, P) themselves (_update).
        F = transition_matrix(ratio)
        ukf = self.ukf
        ukf.x = F @ ukf.x
        ukf.P = _sym(F @ ukf.P @ F.T + Q)
        ukf.x_prior, ukf.P_prior = ukf.x.copy(), ukf.P.copy()
        self.last_F = F
        # keep yaw near (-pi, pi]: shift both slots by the same turns
        turns = round(self.ukf.x[11] / (2.0 * math.pi))
        if turns:
            self.ukf.x[[5, 11]] -= 2.0 * math.pi * turns
        self.t_prev_ns, self.t_cur_ns = self.t_cur_ns, int(stamp_ns)
        self._rate_known = True

    def interpolation_weight(self, stamp_ns: int) -> float:
        """a in [0, 1] such that the pose at ``stamp_ns`` is (1 - a) y_prev + a y_cur."""
        assert self.t_prev_ns is not None and self.t_cur_ns is not None
        span = self.t_cur_ns - self.t_prev_ns
        if span <= 0:
            return 1.0
        return float(np.clip((stamp_ns - self.t_prev_ns) / span, 0.0, 1.0))

    # -- updates -------------------------------------------------------------------------------
    def update_position(self, stamp_ns: int, enu_m: np.ndarray, R: np.ndarray) -> UpdateResult:
        """GNSS position (ENU, m) at ``stamp_ns`` in [t_prev, t_cur] with covariance R (3, 3) m^2."""
        a = self.interpolation_weight(stamp_ns)

        def hx(x: np.ndarray) -> np.ndarray:
            return (1.0 - a) * x[0:3] + a * x[6:9]

        bow = self._chord_error_s2(stamp_ns)
        p = self.params
        accel = np.array([p.accel_sigma_h_m_s2, p.accel_sigma_h_m_s2, p.accel_sigma_v_m_s2])
        R_chord = np.diag((accel * bow) ** 2)
        R_total = np.asarray(R, dtype=np.float64) + R_chord
        return self._update('position', np.asarray(enu_m, dtype=np.float64), R_total, hx, inflate=(0, 1, 2),
                            linear=_interpolation_matrix(0, a))

    def update_attitude(self, stamp_ns: int, rpy_rad: np.ndarray, R: np.ndarray) -> UpdateResult:
        """Body attitude (roll, pitch, yaw; rad) at ``stamp_ns`` with covariance R (3, 3) rad^2."""
        a = self.interpolation_weight(stamp_ns)

        def hx(x: np.ndarray) -> np.ndarray:
            return (1.0 - a) * x[3:6] + a * x[9:12]

        pred = hx(self.ukf.x)
        z = pred + wrap_angle(np.asarray(rpy_rad, dtype=np.float64) - pred)
        bow = self._chord_error_s2(stamp_ns)
        R_chord = (self.params.angular_accel_sigma_rad_s2 * bow) ** 2 * np.eye(3)
        return self._update('attitude', z, np.asarray(R, dtype=np.float64) + R_chord, hx, inflate=(3, 4, 5),
                            linear=_interpolation_matrix(3, a))

    def _chord_error_s2(self, stamp_ns: int) -> float:
        """(t - t_prev)(t_cur - t) / 2 in s^2: how far a path of unit acceleration strays from the chord
        between the two slots at time t (the model error of interpolating linearly)."""
        assert self.t_prev_ns is not None and self.t_cur_ns is not None
        a = max(0.0, (stamp_ns - self.t_prev_ns) * 1e-9)
        b = max(0.0, (self.t_cur_ns - stamp_ns) * 1e-9)
        return 0.5 * a * b

    def update_relative_rotation(self, rotvec_body: np.ndarray, R: np.ndarray) -> UpdateResult:
        """Rotation of the body from t_prev to t_cur, integrated from the gyro (rotation vector, body
        frame of t_prev, rad), with covariance R (3, 3) rad^2: R_prev^T R_cur = exp(rotvec)."""

        def hx(x: np.ndarray) -> np.ndarray:
            r_prev = R_enu_from_body(x[3], x[4], x[5])
            r_cur = R_enu_from_body(x[9], x[10], x[11])
            return rotvec_from_matrix(r_prev.T @ r_cur)

        def hx_batch(xs: np.ndarray) -> np.ndarray:   # hx of every row of xs (N, STATE_DIM) at once
            r = np.swapaxes(_R_enu_from_body_batch(xs[:, 3:6]), 1, 2) @ _R_enu_from_body_batch(xs[:, 9:12])
            return Rotation.from_matrix(r).as_rotvec()

        return self._update('rotation', np.asarray(rotvec_body, dtype=np.float64), np.asarray(R, dtype=np.float64),
                            hx, inflate=None, hx_batch=hx_batch)

    def homography_model(self, K: np.ndarray, mount: CameraMount,
                         corners: np.ndarray, K_prev: np.ndarray | None = None) -> Callable[[np.ndarray], np.ndarray]:
        """hx(x) -> (2N,) of a registration: :func:`ukf_models.homography_model`."""
        return homography_model(K, mount, corners, K_prev)

    def homography_model_batch(self, K: np.ndarray, mount: CameraMount,
                               corners: np.ndarray, K_prev: np.ndarray | None = None) -> Callable[[np.ndarray], np.ndarray]:
        """hx of every row of xs (N, STATE_DIM) at once: :func:`ukf_models.homography_model_batch`."""
        return homography_model_batch(K, mount, corners, K_prev)


    def update_homography(self, prev_H_cur: np.ndarray, R_corners: np.ndarray, K: np.ndarray,
                          mount: CameraMount, corners: np.ndarray, K_prev: np.ndarray | None = None) -> UpdateResult:
        """A registration prev_H_cur (current -> previous frame pixels) of the two frames in the state.

        R_corners: (2N, 2N) covariance (px^2) of the mapped corners (see :func:`corner_jacobian`).
        K, K_prev: the current and the previous frame's intrinsics (K_prev None: the same).
        """
        z = apply_H(np.asarray(prev_H_cur, dtype=np.float64), np.asarray(corners, dtype=np.float64)).ravel()
        hx = self.homography_model(K, mount, corners, K_prev)
        return self._update('homography', z, R_corners, hx, inflate=None,
                            hx_batch=self.homography_model_batch(K, mount, corners, K_prev))

    # -- internals -----------------------------------------------------------------------------
    def _gate(self, dof: int) -> float:
        if dof not in self._gate_cache:
            self._gate_cache[dof] = float(chdtri(dof, 1.0 - self.params.gate_probability))
        return self._gate_cache[dof]

    def _update(self, kind: str, z: np.ndarray, R: np.ndarray, hx: Callable[[np.ndarray], np.ndarray],
                *, inflate: tuple[int, ...] | None, linear: np.ndarray | None = None,
                hx_batch: Callable[[np.ndarray], np.ndarray] | None = None) -> UpdateResult:
        """Fuse z ~ hx(x) + N(0, R), gated; ``linear``: the matrix M when hx(x) = M x exactly.

        For a linear hx the unscented transform is exact (the sigma points reproduce x and P, so the
        predicted z is M x, P_zz = M P M^T and P_xz = P M^T), and the update reduces to the Kalman
        one, computed directly: identical to filterpy's within rounding, and cheaper
        (the IMU orientation at 50 to 100 Hz is most of the filter's updates). ``hx_batch``: hx of
        all sigma points at once (N, STATE_DIM) -> (N, m); the unscented update is then filterpy's,
        step for step (its sigma points, weights and unscented_transform), without its per-point
        Python loop (the homography and gyro models, once per frame each).
        """
        ukf = self.ukf
        x0, P0 = ukf.x.copy(), ukf.P.copy()
        try:
            if linear is None and hx_batch is not None:
                ukf.sigmas_f = ukf.points_fn.sigma_points(ukf.x, ukf.P)
                d2 = _batch_update(ukf, z, _sym(R), hx_batch, iterations=self.params.iterations)
            elif linear is None:
                ukf.sigmas_f = ukf.points_fn.sigma_points(ukf.x, ukf.P)
                ukf.update(z, R=_sym(R), hx=hx)
                d2 = float(ukf.y @ ukf.SI @ ukf.y)
            else:
                d2 = _linear_update(ukf, z, _sym(R), linear)
            np.linalg.cholesky(_sym(ukf.P))
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            ukf.x, ukf.P = x0, P0
            return UpdateResult('failed')
        if not np.all(np.isfinite(ukf.x)) or not np.isfinite(d2):
            ukf.x, ukf.P = x0, P0
            return UpdateResult('failed')
        if d2 <= self._gate(len(z)):
            ukf.P = _sym(ukf.P)
            self._gated_in_a_row[kind] = 0
            return UpdateResult('accepted', d2)
        ukf.x, ukf.P = x0, P0
        n = self._gated_in_a_row.get(kind, 0) + 1
        self._gated_in_a_row[kind] = n
        if inflate is None or n < self.params.max_gated_in_a_row:
            return UpdateResult('gated', d2)
        # Re-acquisition: the innovation, not the measurement, is the outlier. Inflate the
        # absolute uncertainty of both slots together (a common offset: relative motion is kept).
        innovation = z - hx(x0)
        add = np.zeros((STATE_DIM, STATE_DIM))
        idx = list(inflate) + [i + POSE_DIM for i in inflate]
        block = np.diag(innovation**2 + np.diag(R))
        for i, a in enumerate(idx):
            for j, b in enumerate(idx):
                add[a, b] = block[i % 3, j % 3]
        ukf.P = P0 + add
        ukf.x = x0
        res = self._update(kind, z, R, hx, inflate=None)
        self._gated_in_a_row[kind] = 0
        return UpdateResult('reacquired' if res.accepted else res.status, res.mahalanobis2)



def _slot_cur_position(x: np.ndarray) -> np.ndarray:
    return x[6:9]



def _constant_velocity(x: np.ndarray, dt: float, ratio: float = 0.0) -> np.ndarray:
    """Shift and extrapolate: [y_prev, y_cur, g] -> [y_cur, y_cur + ratio (y_cur - y_prev), g]."""
    y_prev, y_cur = x[SLOT_PREV], x[SLOT_CUR]
    return np.r_[y_cur, y_cur + ratio * (y_cur - y_prev), x[GROUND]]
