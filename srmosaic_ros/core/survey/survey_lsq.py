"""The least-squares problem of a survey's global alignment and its Levenberg-Marquardt solve.

Residuals in metres over their sd (pairs' transfer errors, positions, ground control, shape priors;
see :mod:`.global_align`'s docstring for each term), their analytic sparse Jacobian, and Huber's
loss minimised on the reweighted sparse normal equations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .survey_model import apply_h8, GroundControl, h8, h8_scale, h8_scale_jacobian, PairConstraint, point_jacobian, SHAPE_POINTS, SurveyPriors

__all__ = ['ControlTerms', 'PairTerms', 'ShapeTerms', 'SurveyProblem', 'huber_cost', 'levenberg_marquardt']


@dataclass(frozen=True)
class PairTerms:
    """The pairs' transfer residuals, per pair point: the columns of frames i and j (``ci``, ``cj``),
    the point p of frame j (``pj``, (P, 2)), its transfer i_H_j p (``qi``, (P, 2)), its weight 1 / sd
    (``w``) and its pair's index in ``pairs`` (``of_point``)."""

    pairs: list[PairConstraint]
    of_point: np.ndarray
    ci: np.ndarray
    cj: np.ndarray
    pj: np.ndarray
    qi: np.ndarray
    w: np.ndarray

    @classmethod
    def of(cls, col: dict[int, int], pairs: list[PairConstraint], use: np.ndarray) -> PairTerms:
        """The used pairs of ``pairs`` between frames of columns ``col`` (frame -> column)."""
        sel = [p for p, u in zip(pairs, use) if u and p.i in col and p.j in col]
        of_point = np.concatenate([np.full(len(p.points_j), k) for k, p in enumerate(sel)]) if sel else np.zeros(0, int)
        if not sel:
            return cls(sel, of_point, np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
        ci = np.concatenate([np.full(len(p.points_j), col[p.i]) for p in sel])
        cj = np.concatenate([np.full(len(p.points_j), col[p.j]) for p in sel])
        pj = np.concatenate([p.points_j for p in sel])
        qi = np.concatenate([(p.i_H_j @ np.c_[p.points_j, np.ones(len(p.points_j))].T).T for p in sel])
        return cls(sel, of_point, ci, cj, pj, qi[:, :2] / qi[:, 2:3], 1.0 / np.concatenate([p.sigma for p in sel]))


@dataclass(frozen=True)
class ControlTerms:
    """The ground control's residuals G_k(x) - X: the observations' indices in the GroundControl
    (``index``), their frames' columns (``col``), points x (``pts``, (C, 2)), targets X (``ground``,
    (C, 2) metres) and weights 1 / sd (``w``)."""

    index: np.ndarray
    col: np.ndarray
    pts: np.ndarray
    ground: np.ndarray
    w: np.ndarray

    @classmethod
    def of(cls, col: dict[int, int], scale: float, control: GroundControl | None, control_use: np.ndarray | None) -> ControlTerms:
        """The used observations of ``control`` in frames of columns ``col``; sd sqrt((s0 sd_pick)^2 + sd_survey^2)."""
        ctl = [] if control is None or control_use is None else \
            [m for m in range(len(control.frame)) if control_use[m] and int(control.frame[m]) in col]
        if not ctl:
            return cls(np.array(ctl, dtype=int), np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
        assert control is not None
        return cls(np.array(ctl, dtype=int), np.array([col[int(control.frame[m])] for m in ctl]), control.point_n[ctl],
                   control.ground_m[ctl], 1.0 / np.hypot(scale * control.sigma_n[ctl], control.sigma_ground_m))


@dataclass(frozen=True)
class ShapeTerms:
    """The attitude's shape priors: per point of SHAPE_POINTS of each frame whose attitude is known,
    its column (``col``), the point (``pts``), its offset from the frame's centre on the ground that
    the attitude predicts (``target``, metres) and its weight 1 / sd (``w``)."""

    col: np.ndarray
    pts: np.ndarray
    target: np.ndarray
    w: np.ndarray

    @classmethod
    def of(cls, col: dict[int, int], pri: SurveyPriors) -> ShapeTerms:
        shp = [(col[k], G, sd) for k, (G, sd) in pri.shape.items() if k in col]
        if not shp:
            return cls(np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
        m = len(SHAPE_POINTS)
        tgt = []
        for _, G, _ in shp:
            hp = np.tile(h8(G), (m, 1))
            e, nn, _ = apply_h8(hp, SHAPE_POINTS)
            e0, n0, _ = apply_h8(hp[:1], np.zeros((1, 2)))
            tgt.append(np.stack([e - e0, nn - n0], axis=1))
        return cls(np.repeat([c for c, _, _ in shp], m), np.tile(SHAPE_POINTS, (len(shp), 1)), np.concatenate(tgt),
                   np.repeat([1.0 / sd for _, _, sd in shp], m))


class SurveyProblem:
    """Residuals and their sparse Jacobian over the free frames (:mod:`.global_align`'s docstring):
    the pairs' (:class:`PairTerms`), the positions', the shape priors' (:class:`ShapeTerms`), the
    ground control's (:class:`ControlTerms`) and the anchors' that hold a gauge."""

    def __init__(self, free: list[int], pairs: list[PairConstraint], use: np.ndarray, pri: SurveyPriors,
                 scale: float, anchor: dict[int, np.ndarray], control: GroundControl | None = None,
                 control_use: np.ndarray | None = None) -> None:
        self.col = {k: c for c, k in enumerate(free)}
        self.n = len(free)
        self.sel_pairs, self.sel_use = pairs, use
        self.pt = PairTerms.of(self.col, pairs, use)
        pos = np.asarray(pri.position_m, dtype=np.float64)
        self.gps = [(self.col[k], pos[k], 1.0 / float(pri.position_sigma_m[k])) for k in free
                    if np.isfinite(pos[k]).all() and math.isfinite(float(pri.position_sigma_m[k]))]
        self.scale = scale
        self.pri = pri
        self.anchor = [(self.col[k], h8(H)) for k, H in anchor.items() if k in self.col]
        self.ctl = ControlTerms.of(self.col, scale, control, control_use)
        self.shp = ShapeTerms.of(self.col, pri)

    @property
    def ctl_index(self) -> np.ndarray:
        """(C,) int: the control observations in the solve (indices in the GroundControl)."""
        return self.ctl.index

    def _transfer(self, h: np.ndarray, *, jacobian: bool = False) -> tuple:
        """Transfer error of every pair point in frame i's normalised coordinates: the ground point
        of frame j's point p, G_j p, taken back through G_i^-1, minus i_H_j p. Returns ((ry, rx),
        d r / d h_i (P, 2, 8), d r / d h_j (P, 2, 8)); rows of r are (x, y)."""
        Gi = np.concatenate([h, np.ones((self.n, 1))], axis=1).reshape(self.n, 3, 3)
        Mi = np.linalg.inv(Gi)[self.pt.ci]  # (P, 3, 3)
        e, n, _ = apply_h8(h[self.pt.cj], self.pt.pj)
        X = np.stack([e, n, np.ones_like(e)], axis=1)
        y = np.einsum('pab,pb->pa', Mi, X)
        rx, ry = y[:, 0] / y[:, 2] - self.pt.qi[:, 0], y[:, 1] / y[:, 2] - self.pt.qi[:, 1]
        if not jacobian:
            return (ry, rx), None, None
        z = y[:, 2]
        dr_dy = np.zeros((len(z), 2, 3))
        dr_dy[:, 0, 0] = dr_dy[:, 1, 1] = 1.0 / z
        dr_dy[:, 0, 2], dr_dy[:, 1, 2] = -y[:, 0] / z**2, -y[:, 1] / z**2
        je, jn = point_jacobian(h[self.pt.cj], self.pt.pj)
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
        if len(self.pt.w):
            ry, rx = self._transfer(h)[0]
            out += [rx * self.pt.w, ry * self.pt.w]
        if self.gps:
            c = np.array([g[0] for g in self.gps])
            target = np.array([g[1] for g in self.gps])
            w = np.array([g[2] for g in self.gps])
            out += [(h[c, 2] - target[:, 0]) * w, (h[c, 5] - target[:, 1]) * w]
        s0, pri = self.scale, self.pri
        out += [(h[:, 0] + h[:, 4]) / (s0 * pri.shape_sigma), (h[:, 1] - h[:, 3]) / (s0 * pri.shape_sigma),
                h[:, 6] / pri.perspective_sigma, h[:, 7] / pri.perspective_sigma,
                (h8_scale(h) - s0) / (s0 * pri.scale_rel_sigma)]
        if len(self.shp.col):
            hs = h[self.shp.col]
            e, nn, _ = apply_h8(hs, self.shp.pts)
            e0, n0, _ = apply_h8(hs, np.zeros_like(self.shp.pts))
            out += [(e - e0 - self.shp.target[:, 0]) * self.shp.w, (nn - n0 - self.shp.target[:, 1]) * self.shp.w]
        if len(self.ctl.index):
            e, nn, _ = apply_h8(h[self.ctl.col], self.ctl.pts)
            out += [(e - self.ctl.ground[:, 0]) * self.ctl.w, (nn - self.ctl.ground[:, 1]) * self.ctl.w]
        for c, target in self.anchor:  # no positions anywhere: the root holds the gauge
            out.append((h[c] - target) * 1e3)
        return np.concatenate(out)

    def control_rows(self) -> slice:
        """The rows of the control residuals in residuals()."""
        start = 2 * len(self.pt.w) + 2 * len(self.gps) + 5 * self.n + 2 * len(self.shp.col)
        return slice(start, start + 2 * len(self.ctl.index))

    def control_sigmas(self, x: np.ndarray) -> np.ndarray:
        """(C,) RMS over east and north of each control observation's residual, in its sd."""
        if not len(self.ctl.index):
            return np.zeros(0)
        e, nn, _ = apply_h8(x.reshape(self.n, 8)[self.ctl.col], self.ctl.pts)
        r = np.stack([e - self.ctl.ground[:, 0], nn - self.ctl.ground[:, 1]], axis=1) * self.ctl.w[:, None]
        return np.sqrt(np.mean(r**2, axis=1))

    def jacobian(self, x: np.ndarray) -> sp.csr_matrix:
        h = x.reshape(self.n, 8)
        rows, cols, vals = [], [], []
        r0 = 0
        m = len(self.pt.w)
        if m:
            (ry, rx), dr_dhi, dr_dhj = self._transfer(h, jacobian=True)
            idx = np.arange(m)
            for block in range(2):
                r = r0 + block * m + idx
                for k in range(8):
                    rows += [r, r]
                    cols += [self.pt.ci * 8 + k, self.pt.cj * 8 + k]
                    vals += [dr_dhi[:, block, k] * self.pt.w, dr_dhj[:, block, k] * self.pt.w]
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
        ds = h8_scale_jacobian(h) / (s0 * pri.scale_rel_sigma)
        for k in (0, 1, 3, 4):
            rows.append(r0 + f)
            cols.append(f * 8 + k)
            vals.append(ds[:, k])
        r0 += n
        if len(self.shp.col):
            hs = h[self.shp.col]
            je, jn = point_jacobian(hs, self.shp.pts)
            je0, jn0 = point_jacobian(hs, np.zeros_like(self.shp.pts))
            q = len(self.shp.col)
            for block, (j1, j0) in enumerate(((je, je0), (jn, jn0))):
                for k in range(8):
                    rows.append(r0 + block * q + np.arange(q))
                    cols.append(self.shp.col * 8 + k)
                    vals.append((j1[:, k] - j0[:, k]) * self.shp.w)
            r0 += 2 * q
        if len(self.ctl.index):
            je, jn = point_jacobian(h[self.ctl.col], self.ctl.pts)
            q = len(self.ctl.index)
            for block, jac in enumerate((je, jn)):
                for k in range(8):
                    rows.append(r0 + block * q + np.arange(q))
                    cols.append(self.ctl.col * 8 + k)
                    vals.append(jac[:, k] * self.ctl.w)
            r0 += 2 * q
        for c, _ in self.anchor:
            rows.append(r0 + np.arange(8))
            cols.append(c * 8 + np.arange(8))
            vals.append(np.full(8, 1e3))
            r0 += 8
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, n * 8))

    def pair_rms(self, x: np.ndarray) -> np.ndarray:
        """RMS normalised residual of each selected pair."""
        m = len(self.pt.w)
        if not m:
            return np.zeros(0)
        r = self.residuals(x)[:2 * m].reshape(2, m)  # (x, y) rows
        sq = np.bincount(self.pt.of_point, weights=(r**2).sum(axis=0), minlength=len(self.pt.pairs))
        cnt = np.bincount(self.pt.of_point, minlength=len(self.pt.pairs)) * 2
        return np.sqrt(sq / np.maximum(cnt, 1))


def huber_cost(r: np.ndarray, k: float, plain: slice | None = None) -> float:
    """Huber's cost of residuals r, with threshold k; rows ``plain``: squares (least squares)."""
    a = np.abs(r)
    c = np.where(a <= k, 0.5 * a * a, k * a - 0.5 * k * k)
    if plain is not None:
        c[plain] = 0.5 * a[plain] ** 2
    return float(np.sum(c))


def levenberg_marquardt(prob: SurveyProblem, x0: np.ndarray, huber: float, *, max_iterations: int = 100,
                         rel_tol: float = 1e-9, plain: slice | None = None) -> tuple[np.ndarray, int, bool]:
    """Minimise the Huber cost of prob's residuals: Levenberg-Marquardt on the iteratively
    reweighted normal equations (J^T W J + mu diag(J^T W J)) dx = -J^T W r, solved as a sparse
    system (SuperLU). Returns (x, iterations, converged).

    Not scipy.optimize.least_squares: with LSMR its 'trf' converges far more slowly on this problem
    (the evaluations each needs: docs/results.md), and its dense 'exact' solver costs time and memory
    that grow with the square of the frames."""
    from scipy.sparse.linalg import spsolve

    x = x0.copy()
    r = prob.residuals(x)
    cost = huber_cost(r, huber, plain)
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
            cn = huber_cost(rn, huber, plain) if np.all(np.isfinite(rn)) else math.inf
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
