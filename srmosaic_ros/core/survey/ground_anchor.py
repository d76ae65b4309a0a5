"""Ground control as the survey's anchor: the similarity that takes a part of the survey solved on
its root's plane to the ground, and the search for wrong picks or targets by leaving each target out
in turn (the control's residuals are least squares, so a wrong point bends the survey to itself)."""
from __future__ import annotations

import numpy as np

from .survey_lsq import levenberg_marquardt, SurveyProblem
from .survey_model import apply_h8, control_residuals, GroundControl

__all__ = ['control_similarity', 'left_out_outlier']


def control_similarity(G: np.ndarray, placed_by: list[str], control: GroundControl,
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


def left_out_outlier(prob: SurveyProblem, x: np.ndarray, huber: float, control: GroundControl, use: np.ndarray,
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
        sub = SurveyProblem([k for k in prob.col], prob.sel_pairs, prob.sel_use, prob.pri, scale, {}, control, rest)
        xt, _, _ = levenberg_marquardt(sub, x, huber, plain=sub.control_rows(), max_iterations=30)
        h = xt.reshape(prob.n, 8)
        cols = np.array([prob.col[int(control.frame[m])] for m in mine])
        e, nn, _ = apply_h8(h[cols], control.point_n[mine])
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
