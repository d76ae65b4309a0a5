"""Offline Rauch-Tung-Striebel smoothing of a run of the pose UKF (ukf.py).

The UKF's predict is linear (ukf_models.transition_matrix), so the recursion is exact for the
filter's Gaussian approximation.
"""
from __future__ import annotations

import numpy as np

from .ukf_models import _sym

__all__ = ['rts_smooth']


def rts_smooth(steps: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]]
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rauch-Tung-Striebel smoothing of a run of this filter.

    steps[k] = (x_pred, P_pred, x_post, P_post, F) of frame k: the state right after the predict
    to frame k (F the transition that produced it; None for the first) and right before the
    predict to frame k + 1. The predict is linear, so the smoother is the exact RTS recursion on
    these moments: C = P_post F'^T P_pred'^-1, x_s = x_post + C (x_s' - x_pred'),
    P_s = P_post + C (P_s' - P_pred') C^T. Returns the smoothed (x, P) per frame.
    """
    out: list[tuple[np.ndarray, np.ndarray]] = [(np.empty(0), np.empty(0))] * len(steps)
    if not steps:
        return out
    x_s, P_s = steps[-1][2], steps[-1][3]
    out[-1] = (x_s.copy(), P_s.copy())
    for k in range(len(steps) - 2, -1, -1):
        _, _, x_post, P_post, _ = steps[k]
        x_pred, P_pred, _, _, F = steps[k + 1]
        C = np.linalg.solve(P_pred, F @ P_post).T  # P_post F^T P_pred^-1 (P symmetric)
        x_s = x_post + C @ (x_s - x_pred)
        P_s = _sym(P_post + C @ (P_s - P_pred) @ C.T)
        out[k] = (x_s.copy(), P_s.copy())
    return out

