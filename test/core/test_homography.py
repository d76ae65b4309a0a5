"""core.homography.h8_jacobian: the exact Jacobians the covariances are carried by, against
central differences of the maps they stand for."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.core.homography import h8_jacobian


def _h8(H: np.ndarray) -> np.ndarray:
    return (H / H[2, 2]).reshape(-1)[:8]


def _X(h: np.ndarray) -> np.ndarray:
    return np.r_[h, 1.0].reshape(3, 3)


def _numeric(f, h0: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    J = np.zeros((8, 8))
    for k in range(8):
        d = np.zeros(8)
        d[k] = eps
        J[:, k] = (f(h0 + d) - f(h0 - d)) / (2.0 * eps)
    return J


@pytest.mark.parametrize('seed', range(4))
def test_h8_jacobian_matches_central_differences(seed):
    rng = np.random.default_rng(seed)
    H = np.eye(3) + rng.normal(0.0, 0.05, (3, 3))
    H[2, :2] *= 0.01
    H /= H[2, 2]
    h0 = _h8(H)
    Hi = np.linalg.inv(H)
    t = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])  # a pyramid level to full size
    ti = np.linalg.inv(t)
    cases = [
        (h8_jacobian(-Hi, Hi, Hi), lambda h: _h8(np.linalg.inv(_X(h)))),       # inverse
        (h8_jacobian(t, ti, t @ H @ ti), lambda h: _h8(t @ _X(h) @ ti)),       # conjugation
    ]
    for exact, f in cases:
        numeric = _numeric(f, h0)
        assert np.abs(exact - numeric).max() <= 1e-7 * np.abs(numeric).max()
