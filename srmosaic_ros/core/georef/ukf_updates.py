"""The measurement updates of the pose UKF (ukf.py) on filterpy's UnscentedKalmanFilter object.

Both write x, P and the innovation terms where filterpy's own ``update`` writes them, so the
filter object reads the same after either; shapes: x (STATE_DIM,), P (STATE_DIM, STATE_DIM),
z (m,), R (m, m).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg
from filterpy.kalman import UnscentedKalmanFilter, unscented_transform

from .ukf_models import _EPS_VAR, _sym, nearest_positive_definite

__all__: list[str] = []


def _batch_update(ukf: UnscentedKalmanFilter, z: np.ndarray, R: np.ndarray,
                  hx_batch: Callable[[np.ndarray], np.ndarray], iterations: int = 1,
                  tolerance_sigma: float = 1e-3) -> float:
    """filterpy's UnscentedKalmanFilter.update with the sigma points mapped by hx_batch in one call
    (and the cross-covariance as one product); writes x, P, sigmas_h, S, SI, K, y, z as it does.
    Returns the squared Mahalanobis distance of the innovation (of the first pass: the gate tests
    the measurement against the prediction).

    iterations > 1: iterated posterior linearisation (García-Fernández, Svensson, Morelande and
    Särkkä, "Posterior linearization filter", IEEE TSP 63(20), 2015). The first pass is the UKF
    update above. Each further pass draws the sigma points from the latest posterior (x_i, P_i)
    instead of the prior, fits the statistical linear regression of hx there,
    z ~ A x + b + N(0, Omega) with A = Psi^T P_i^-1, b = z_bar - A x_i, Omega = Phi - A P_i A^T
    (Psi, Phi: the sigma points' cross- and output covariances), and updates the *prior* (x0, P0)
    with that linear model and R + Omega. Why: a homography constrains displacement / height
    above ground, a ratio; linearised once at a ground prior far off (40 m on a 60 m flight with
    the default nominal 100 m AGL), every update is fused at the wrong slope: the estimate creeps
    toward the truth over seconds while P shrinks at once, and the filter is overconfident
    (its normalised estimation error squared with and without: docs/results.md, "Georeferencing").
    Stops when the estimate moves by less than ``tolerance_sigma`` prior standard deviations in
    every component.
    """
    x0, P0 = ukf.x.copy(), ukf.P.copy()
    ukf.sigmas_h = np.atleast_2d(hx_batch(ukf.sigmas_f))
    zp, ukf.S = unscented_transform(ukf.sigmas_h, ukf.Wm, ukf.Wc, R, ukf.z_mean, ukf.residual_z)
    ukf.SI = ukf.inv(ukf.S)
    # P_xz = sum_i Wc_i (chi_i - x)(Z_i - z)^T (filterpy's cross_variance, default residuals)
    pxz = (ukf.Wc[:, None] * (ukf.sigmas_f - ukf.x)).T @ (ukf.sigmas_h - zp)
    ukf.K = pxz @ ukf.SI
    ukf.y = ukf.residual_z(z, zp)
    d2 = float(ukf.y @ ukf.SI @ ukf.y)
    ukf.x = ukf.state_add(ukf.x, ukf.K @ ukf.y)
    ukf.P = ukf.P - ukf.K @ ukf.S @ ukf.K.T
    prior_sd = np.sqrt(np.maximum(np.diag(P0), _EPS_VAR))
    for _ in range(iterations - 1):
        x_i, P_i = ukf.x, _sym(ukf.P)
        try:
            sig = ukf.points_fn.sigma_points(x_i, P_i)
            zs = np.atleast_2d(hx_batch(sig))
            z_bar = ukf.Wm @ zs
            dz = zs - z_bar
            psi = (ukf.Wc[:, None] * (sig - x_i)).T @ dz                    # (n, m)
            phi = (ukf.Wc[:, None] * dz).T @ dz                             # (m, m)
            A = scipy.linalg.solve(P_i, psi, assume_a='pos').T  # (m, n)
            omega = nearest_positive_definite(phi - A @ P_i @ A.T, floor=0.0)
            S = A @ P0 @ A.T + omega + R
            SI = ukf.inv(S)
            K = P0 @ A.T @ SI
            y = z - (A @ x0 + (z_bar - A @ x_i))
            x_new, P_new = x0 + K @ y, P0 - K @ S @ K.T
        except (np.linalg.LinAlgError, ValueError, scipy.linalg.LinAlgError):
            break  # keep the last good pass
        if not np.all(np.isfinite(x_new)) or not np.all(np.isfinite(P_new)):
            break
        step = np.max(np.abs(x_new - x_i) / prior_sd)
        ukf.x, ukf.P, ukf.S, ukf.SI, ukf.K, ukf.y = x_new, P_new, S, SI, K, y
        if step < tolerance_sigma:
            break
    ukf.z = np.array(z, copy=True)
    ukf.x_post, ukf.P_post = ukf.x.copy(), ukf.P.copy()
    return d2


def _linear_update(ukf: UnscentedKalmanFilter, z: np.ndarray, R: np.ndarray, M: np.ndarray) -> float:
    """Kalman update of ukf.x, ukf.P by z = M x + N(0, R), written where filterpy's update writes it
    (x, P, y, S, SI, K, z); returns the squared Mahalanobis distance of the innovation."""
    y = z - M @ ukf.x
    PMt = ukf.P @ M.T
    S = M @ PMt + R
    SI = np.linalg.inv(S)
    K = PMt @ SI
    ukf.x = ukf.x + K @ y
    ukf.P = ukf.P - K @ S @ K.T
    ukf.y, ukf.S, ukf.SI, ukf.K, ukf.z = y, S, SI, K, np.array(z, copy=True)
    ukf.x_post, ukf.P_post = ukf.x.copy(), ukf.P.copy()
    return float(y @ SI @ y)


