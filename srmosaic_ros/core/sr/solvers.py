"""Matrix-free MAP solvers for (5.3): steepest descent, nonlinear conjugate gradient, Levenberg-Marquardt.

The objective (5.3) with per-frame weights ``w_k`` (robust down-weighting of outlier frames) is::

    f(x) = sum_k w_k ||y_k - A_k x||^2 + lambda * sum_g rho(G x, alpha)

where ``A_k = M_k D B W_k`` (the mask M_k is R, the frame's footprint). Its gradient is
``-2 sum_k w_k A_k^T (y_k - A_k x) + lambda G^T rho'(G x)``; (5.5) and (5.16) write the negative
half of the data part.

Step sizes (DESIGN: the reference's fixed 1.75 is unstable): steepest descent (5.5) and conjugate
gradient (5.13 to 5.16) move along ``p`` by the *exact* line search of
``phi(t) = f(x + t p)``. The data part of phi is a quadratic whose coefficients need ``A p``, which
the iteration needs anyway to update the residual ``y - A (x + t p) = r - t A p``; the prior part
is ``lambda sum rho(G x + t G p)``, evaluated on the clique arrays alone (no operator). phi is convex
and piecewise quadratic, so a safeguarded Newton search on phi' finds its minimiser in a few
elementwise passes: exact steps for the cost of one forward and one adjoint product per iteration,
where Armijo backtracking would pay one forward product per trial step. Every accepted step lowers
f (for a fixed lambda), so the objective decreases monotonically.

CG directions are Polak-Ribiere+ from the negative gradient (``beta = max(0, PR)``, restart on a
non-descent direction or when lambda / the frame weights change the objective).

Levenberg-Marquardt (5.17 to 5.24) is matrix-free: the residual vector is the weighted data residual
together with the prior as IRLS-weighted clique differences, so the Gauss-Newton Hessian is
``H = sum_k w_k A_k^T A_k + lambda G^T diag(omega) G`` with Huber weights omega = rho'(g) / (2 g);
``(H + c I) delta = -J^T r`` is solved by an inner conjugate gradient on Hessian-vector products.
Damping (section 5.6): c starts large (the Rayleigh quotient of H along the gradient, so the first
steps are steepest-descent-like); when the relative change (5.25) of a step is smaller than the
previous one c is divided by ``lm_down``, otherwise multiplied by ``lm_up``. As a safeguard the
reference lacks, a step that raises f is rejected and c multiplied by ``lm_reject``.

Each solver records per iteration the objective, lambda, the relative change
``||x_{n+1} - x_n|| / ||x_n||`` (5.25) and stops when that change is below ``tol`` or after
``iterations`` iterations.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from .modes import LAMBDA_MODES, SOLVERS

from .operators import LinearOperator
from .prior import (
    HuberPrior,
    adaptive_lambda,
    clique_differences,
    clique_differences_adjoint,
    huber_derivative,
    huber_irls_weight,
    huber_sum,
    huber_sum_parts,
    paper_lambda,
)

__all__ = [
    'LAMBDA_MODES',
    'SOLVERS',
    'LambdaRule',
    'Problem',
    'IterationRecord',
    'SolveResult',
    'solve',
    'steepest_descent',
    'conjugate_gradient',
    'levenberg_marquardt',
    'line_search_exact',
]



@dataclass(frozen=True)
class LambdaRule:
    """How lambda is chosen at every iteration.

    ``adaptive``: :func:`~srmosaic_ros.core.sr.prior.adaptive_lambda` (5.6, normalised) times
    ``gamma``: the residual of the current iterate over the prior activity ``reference`` (mean
    rho per clique) when given, else over the prior activity of the current iterate, as (5.6)
    reads. The current iterate's activity feeds back on itself: an estimate that turns noisy raises
    it, which lowers lambda, which lets the estimate turn noisier, and on sharp scenes lambda
    collapses (bench/sr.py, ``--world brighton``); a fixed reference such as the initial estimate's
    activity leaves only the residual to move lambda, which it does gently, and the iteration
    settles. ``fixed``: ``value``. ``paper``: (5.6) exactly as printed (size dependent; for
    comparison). ``noise_cap``: in ``adaptive`` mode, each frame's RMS residual is capped at this
    value (intensity) before it enters (5.6): the residual stands for the noise only where the
    model fits; on real frames it also holds misfit (parallax, lens, lighting) that a stronger
    prior does not cure (bench/sr_real.py). ``noise_floor``: each frame's RMS residual is taken as at
    least this (intensity) in ``adaptive`` mode: an estimate that fits its frames below their noise
    (one frame, or frames that agree, can be fitted exactly) has fitted the noise, and (5.6) would
    let lambda collapse with the residual and the noise be amplified into the HR estimate.
    """

    mode: str = 'adaptive'
    value: float = 0.0
    gamma: float = 1.0
    reference: float | None = None
    noise_cap: float | None = None
    noise_floor: float | None = None

    def __post_init__(self) -> None:
        if self.mode not in LAMBDA_MODES:
            msg = f'lambda mode must be one of {LAMBDA_MODES}, got {self.mode!r}.'
            raise ValueError(msg)
        if self.value < 0 or self.gamma < 0:
            msg = f'lambda value and gamma must be >= 0, got {self.value} and {self.gamma}.'
            raise ValueError(msg)


class Problem:
    """The data of (5.3): operator, observations, per-frame weights, prior and lambda rule.

    ``operator`` maps x ``(1, C, H, W)`` (any shape for the solvers; frames along dim 0 of the
    output) to the stacked predictions ``(K, ...)``; ``y`` has that shape and must already be zero
    where the operator's mask is zero. ``counts`` (K,) is the number of observed values of each frame
    (for the per-pixel RMS in lambda and in the robust weights); ``frame_weights`` (K,) the w_k.
    With ``prior=None`` the objective is the data term alone (lambda = 0).
    """

    def __init__(self, operator: LinearOperator, y: torch.Tensor, *, prior: HuberPrior | None = None,
                 lam: LambdaRule | None = None, frame_weights: torch.Tensor | None = None,
                 counts: torch.Tensor | None = None) -> None:
        self.operator = operator
        self.y = y
        self.prior = prior
        self.lam_rule = lam if lam is not None else LambdaRule()
        k = y.shape[0]
        self.counts = (torch.full((k,), float(y[0].numel()), dtype=torch.float64, device=y.device)
                       if counts is None else counts.to(device=y.device, dtype=torch.float64))
        self._counts_cpu = self.counts.cpu()
        self.set_frame_weights(torch.ones(k, dtype=y.dtype, device=y.device) if frame_weights is None
                               else frame_weights)

    def set_frame_weights(self, w: torch.Tensor) -> None:
        w = torch.as_tensor(w, dtype=self.y.dtype, device=self.y.device).reshape(-1)
        if w.numel() != self.y.shape[0] or bool((w < 0).any()):
            msg = f'frame weights must be {self.y.shape[0]} values >= 0, got {w.tolist()}.'
            raise ValueError(msg)
        self.frame_weights = w
        self._w = w.reshape(-1, *([1] * (self.y.ndim - 1)))
        self._w_cpu = w.detach().double().cpu()
        self._unit = bool((self._w_cpu == 1).all())

    # -- pieces ---------------------------------------------------------------------------
    def frame_sq(self, r: torch.Tensor) -> torch.Tensor:
        """(K,) float64: ||r_k||^2 per frame (on r's device)."""
        return torch.linalg.vector_norm(r.reshape(r.shape[0], -1), dim=1).double() ** 2

    def frame_rms(self, r: torch.Tensor) -> torch.Tensor:
        """(K,) float64: RMS residual of each frame over its observed values."""
        return torch.sqrt(self.frame_sq(r) / self.counts.clamp_min(1.0))

    def measure(self, r: torch.Tensor, gx: torch.Tensor | None) -> tuple[torch.Tensor, float]:
        """``(||r_k||^2 (K,) float64 on the CPU, sum rho(G x))`` with one device synchronisation."""
        parts = [self.frame_sq(r)]
        if self.prior is not None and gx is not None:
            parts.append(huber_sum_parts(gx, self.prior.alpha).double())
        vals = torch.cat(parts).cpu()
        k = r.shape[0]
        fsq = vals[:k]
        if len(parts) == 1:
            return fsq, 0.0
        cc, a_sum, c_sum = vals[k:].tolist()
        return fsq, cc + 2.0 * self.prior.alpha * (a_sum - c_sum)  # type: ignore[union-attr]

    def data_from(self, fsq: torch.Tensor) -> float:
        """sum_k w_k ||r_k||^2 from :meth:`measure`'s per-frame sums."""
        return float((self._w_cpu * fsq).sum())

    def data_value(self, r: torch.Tensor) -> float:
        return self.data_from(self.frame_sq(r).cpu())

    def prior_value(self, gx: torch.Tensor | None) -> float:
        if self.prior is None or gx is None:
            return 0.0
        return huber_sum(gx, self.prior.alpha)

    def lam_from(self, fsq: torch.Tensor, prior_sum: float, n_cliques: int) -> float:
        """lambda from :meth:`measure`'s figures (no device work)."""
        rule = self.lam_rule
        if self.prior is None or n_cliques == 0:
            return 0.0
        if rule.mode == 'fixed':
            return rule.value
        rho_sum = torch.tensor(prior_sum, dtype=torch.float64)
        if rule.mode == 'paper':
            return float(paper_lambda(torch.sqrt(fsq), rho_sum))
        rms = torch.sqrt(fsq / self._counts_cpu.clamp_min(1.0))
        if rule.noise_cap is not None:
            rms = rms.clamp_max(rule.noise_cap)
        if rule.noise_floor is not None:
            rms = rms.clamp_min(rule.noise_floor)
        mean_rho = rho_sum / n_cliques if rule.reference is None else rule.reference
        return float(adaptive_lambda(rms, self._w_cpu, mean_rho, gamma=rule.gamma))

    def lam(self, r: torch.Tensor, gx: torch.Tensor | None, prior_sum: float | None = None) -> float:
        """lambda at the current iterate (``prior_sum`` = sum rho(G x), when already known)."""
        if self.prior is None or gx is None:
            return 0.0
        fsq, rho = self.measure(r, gx)
        return self.lam_from(fsq, rho if prior_sum is None else prior_sum, gx.numel())

    def weighted(self, r: torch.Tensor) -> torch.Tensor:
        """w_k r_k (r itself when every weight is 1)."""
        return r if self._unit else r * self._w

    def diff(self, x: torch.Tensor) -> torch.Tensor | None:
        return clique_differences(x) if self.prior is not None else None

    def gradient(self, r: torch.Tensor, gx: torch.Tensor | None, lam: float) -> torch.Tensor:
        """grad f = -2 A^T (w r) + lambda G^T rho'(G x)."""
        g = self.operator.adjoint(self.weighted(r)) * -2.0
        if self.prior is not None and gx is not None and lam > 0:
            g = g + lam * clique_differences_adjoint(huber_derivative(gx, self.prior.alpha))
        return g


@dataclass
class IterationRecord:
    """One iteration: ``objective`` f(x_{n+1}) under the ``lam`` used for the step, its data and
    prior parts, ``rel_change`` ||x_{n+1} - x_n|| / ||x_n||, ``step`` (line-search t or LM 1/0),
    ``time_s`` since the solver started; ``damping`` and ``inner`` for LM."""

    iteration: int
    objective: float
    data: float
    prior: float
    lam: float
    rel_change: float
    step: float
    time_s: float
    damping: float = math.nan
    inner: int = 0
    accepted: bool = True


@dataclass
class SolveResult:
    """Solver output: the estimate ``x`` and the per-iteration ``history``."""

    x: torch.Tensor
    history: list[IterationRecord] = field(default_factory=list)
    converged: bool = False
    stop_reason: str = ''
    initial_objective: float = math.nan
    initial_lam: float = math.nan


Callback = Callable[[int, torch.Tensor], None]
Reweight = Callable[[int, torch.Tensor, torch.Tensor], torch.Tensor | None]


def _norm(x: torch.Tensor) -> float:
    return float(torch.linalg.vector_norm(x))


def _scalars(*values: torch.Tensor) -> list[float]:
    """Several 0-dim device tensors as Python floats with one synchronisation."""
    return torch.stack([v.reshape(()).to(torch.float64) for v in values]).tolist()


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.vdot(a.reshape(-1), b.reshape(-1))


def _vdot(a: torch.Tensor, b: torch.Tensor) -> float:
    """<a, b> as a Python float (BLAS dot; float32 accumulation is ample for step sizes)."""
    return float(torch.vdot(a.reshape(-1), b.reshape(-1)))


def line_search_exact(a: float, b: float, lam: float, gx: torch.Tensor | None, gp: torch.Tensor | None,
                      alpha: float, *, rtol: float = 1e-3, max_evals: int = 10) -> float:
    """argmin_{t >= 0} phi(t) = a t^2 + b t + lam sum rho(gx + t gp, alpha) (convex, piecewise quadratic).

    ``a = ||A p||_w^2``, ``b = -2 <w r, A p>``. The first trial is the Newton step from t = 0 (exact
    when no clique difference crosses +-alpha); then regula falsi (Illinois) on
    ``phi'(t) = 2 a t + b + 2 lam <gp, clip(gx + t gp, -alpha, alpha)>`` inside a bracket
    ``phi'(lo) < 0 <= phi'(hi)`` until ``|phi'(t)| <= rtol |phi'(0)|``. Each trial is three passes
    over the clique arrays and no operator product.
    """
    use_prior = lam > 0 and gx is not None and gp is not None
    if use_prior:
        gxf, gpf = gx.reshape(-1), gp.reshape(-1)  # type: ignore[union-attr]

    def dphi(t: float) -> float:
        d = 2.0 * a * t + b
        if use_prior:
            d += 2.0 * lam * float(torch.vdot(gpf, torch.add(gxf, gpf, alpha=t).clamp_(-alpha, alpha)))
        return d

    d0, dd0 = b, 2.0 * a
    if use_prior:
        s1, s2 = _scalars(_dot(gpf, gxf.clamp(-alpha, alpha)),
                          torch.sum(torch.where(gxf.abs() < alpha, gpf * gpf, 0.0)))
        d0 += 2.0 * lam * s1
        dd0 += 2.0 * lam * s2
    if not d0 < 0:
        return 0.0
    tol = rtol * abs(d0)
    t_hi = -d0 / dd0 if dd0 > 0 else 1.0
    d_hi = dphi(t_hi)
    evals = 1
    t_lo, d_lo = 0.0, d0
    while d_hi < 0:                       # curvature fell beyond alpha: grow the bracket
        if abs(d_hi) <= tol or evals >= max_evals:
            return t_hi
        t_lo, d_lo = t_hi, d_hi
        t_hi *= 2.0
        d_hi = dphi(t_hi)
        evals += 1
    if d_hi <= tol:
        return t_hi
    side = 0
    t = t_hi
    while evals < max_evals:
        t = t_hi - d_hi * (t_hi - t_lo) / (d_hi - d_lo)
        d = dphi(t)
        evals += 1
        if abs(d) <= tol:
            return t
        if d < 0:
            t_lo, d_lo = t, d
            if side == -1:
                d_hi *= 0.5
            side = -1
        else:
            t_hi, d_hi = t, d
            if side == 1:
                d_lo *= 0.5
            side = 1
    return t_lo if t_lo > 0 else t   # phi'(t_lo) < 0, so phi(t_lo) < phi(0)


def _state(problem: Problem, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
    r = problem.y - problem.operator.apply(x)
    return r, problem.diff(x)


def _maybe_reweight(problem: Problem, reweight: Reweight | None, n: int, x: torch.Tensor,
                    r: torch.Tensor) -> bool:
    if reweight is None:
        return False
    w = reweight(n, x, r)
    if w is None:
        return False
    problem.set_frame_weights(w)
    return True


def _gradient_descent_family(problem: Problem, x0: torch.Tensor, *, conjugate: bool, iterations: int,
                             tol: float, callback: Callback | None, reweight: Reweight | None,
                             refresh_every: int = 25) -> SolveResult:
    t_start = time.perf_counter()
    alpha = problem.prior.alpha if problem.prior is not None else 1.0
    x = x0.clone()
    r, gx = _state(problem, x)
    n_cliques = gx.numel() if gx is not None else 0
    fsq, prior = problem.measure(r, gx)
    res = SolveResult(x=x)
    lam = problem.lam_from(fsq, prior, n_cliques)
    res.initial_lam = lam
    res.initial_objective = problem.data_from(fsq) + lam * prior
    if callback is not None:
        callback(0, x)
    p: torch.Tensor | None = None
    grad_prev: torch.Tensor | None = None
    gg_prev = 0.0
    for n in range(iterations):
        if n and n % refresh_every == 0:  # the incremental residual and differences drift slowly
            r, gx = _state(problem, x)
            fsq, prior = problem.measure(r, gx)
        restart = _maybe_reweight(problem, reweight, n, x, r)
        if restart:  # a reweighting may change the observations' weights (robust_pixels.py): residual afresh
            r, gx = _state(problem, x)
            fsq, prior = problem.measure(r, gx)
        lam = problem.lam_from(fsq, prior, n_cliques)
        grad = problem.gradient(r, gx, lam)
        if not conjugate or p is None or grad_prev is None or restart or gg_prev <= 0:
            p = -grad
        else:
            # Polak-Ribiere+: beta = max(0, g.(g - g_prev) / g_prev.g_prev); p = -g + beta p.
            gg, g_gprev, p_g = _scalars(_dot(grad, grad), _dot(grad, grad_prev), _dot(p, grad))
            beta = max(0.0, (gg - g_gprev) / gg_prev)
            if beta > 0 and -gg + beta * p_g < 0:
                p = p.mul_(beta).sub_(grad)
            else:   # beta = 0, or not a descent direction: restart along the negative gradient
                p = -grad
        grad_prev = grad
        ap = problem.operator.apply(p)
        wap = problem.weighted(ap)
        gp = problem.diff(p)
        a, b, xx, pp, gg_prev = _scalars(_dot(wap, ap), _dot(wap, r), _dot(x, x), _dot(p, p), _dot(grad, grad))
        t = line_search_exact(a, -2.0 * b, lam, gx, gp, alpha)
        x = x.add_(p, alpha=t)
        r = r.sub_(ap, alpha=t)
        if gx is not None and gp is not None:
            gx = gx.add_(gp, alpha=t)
        fsq, prior = problem.measure(r, gx)
        data = problem.data_from(fsq)
        rel = t * math.sqrt(pp / xx) if xx > 0 else math.inf
        res.history.append(IterationRecord(
            iteration=n + 1, objective=data + lam * prior, data=data, prior=prior, lam=lam,
            rel_change=rel, step=t, time_s=time.perf_counter() - t_start))
        if callback is not None:
            callback(n + 1, x)
        if t == 0.0:
            res.stop_reason = 'no descent along the search direction (stationary point)'
            res.converged = True
            break
        if rel < tol:
            res.stop_reason = f'relative change {rel:.2e} < tol {tol:.2e}'
            res.converged = True
            break
    else:
        res.stop_reason = f'iteration cap {iterations}'
    res.x = x
    return res


def steepest_descent(problem: Problem, x0: torch.Tensor, *, iterations: int = 10, tol: float = 1e-4,
                     callback: Callback | None = None, reweight: Reweight | None = None) -> SolveResult:
    """Steepest descent (5.5) with exact line search. ``x0`` any shape the operator accepts."""
    return _gradient_descent_family(problem, x0, conjugate=False, iterations=iterations, tol=tol,
                                    callback=callback, reweight=reweight)


def conjugate_gradient(problem: Problem, x0: torch.Tensor, *, iterations: int = 10, tol: float = 1e-4,
                       callback: Callback | None = None, reweight: Reweight | None = None) -> SolveResult:
    """Nonlinear conjugate gradient (5.13 to 5.16), Polak-Ribiere+, exact line search."""
    return _gradient_descent_family(problem, x0, conjugate=True, iterations=iterations, tol=tol,
                                    callback=callback, reweight=reweight)


def levenberg_marquardt(problem: Problem, x0: torch.Tensor, *, iterations: int = 10, tol: float = 1e-4,
                        callback: Callback | None = None, reweight: Reweight | None = None,
                        inner_iterations: int = 8, inner_tol: float = 1e-2, damping0: float = 1.0,
                        lm_down: float = 3.0, lm_up: float = 2.0, lm_reject: float = 4.0,
                        min_damping: float = 1e-6) -> SolveResult:
    """Levenberg-Marquardt (5.17 to 5.24), matrix-free, inner CG on (H + c I) delta = -J^T r.

    ``damping0`` times the Rayleigh quotient of H along the gradient is the first c;
    ``min_damping`` (same relative units) its floor. ``inner_iterations`` / ``inner_tol`` bound
    the inner CG (relative residual).
    """
    t_start = time.perf_counter()
    prior = problem.prior
    alpha = prior.alpha if prior is not None else 1.0
    op = problem.operator
    x = x0.clone()
    r, gx = _state(problem, x)
    n_cliques = gx.numel() if gx is not None else 0
    res = SolveResult(x=x)
    fsq, prior_sum = problem.measure(r, gx)
    data = problem.data_from(fsq)
    lam = problem.lam_from(fsq, prior_sum, n_cliques)
    res.initial_lam = lam
    res.initial_objective = data + lam * prior_sum
    if callback is not None:
        callback(0, x)
    c: float | None = None
    scale = 1.0
    prev_err = math.inf
    for n in range(iterations):
        if _maybe_reweight(problem, reweight, n, x, r):
            prev_err = math.inf
            r, gx = _state(problem, x)
            fsq, prior_sum = problem.measure(r, gx)
            data = problem.data_from(fsq)
        lam = problem.lam_from(fsq, prior_sum, n_cliques)
        f = data + lam * prior_sum
        # Half gradient J^T r of the least-squares form: -A^T w r + lambda G^T diag(omega) G x.
        g = problem.gradient(r, gx, lam) * 0.5
        omega = huber_irls_weight(gx, alpha) if gx is not None and lam > 0 else None

        def hess(v: torch.Tensor, omega: torch.Tensor | None = omega,
                 lam: float = lam) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
            av = op.apply(v)
            hv = op.adjoint(problem.weighted(av))
            gv = problem.diff(v) if omega is not None else None
            if gv is not None and omega is not None:
                hv = hv + lam * clique_differences_adjoint(omega * gv)
            return hv, av, gv

        if c is None:
            hg, _, _ = hess(g)
            gg = _vdot(g, g)
            scale = _vdot(g, hg) / gg if gg > 0 else 1.0
            c = damping0 * scale
        # Inner CG on (H + c I) delta = -g, accumulating A delta and G delta on the way.
        delta = torch.zeros_like(x)
        a_delta = torch.zeros_like(r)
        g_delta = torch.zeros_like(gx) if gx is not None and omega is not None else None
        res_v = -g
        pdir = res_v.clone()
        rr = _vdot(res_v, res_v)
        rr0 = rr
        inner = 0
        for inner in range(1, inner_iterations + 1):  # noqa: B007
            hp, ap, gp = hess(pdir)
            hp = hp + c * pdir
            php = _vdot(pdir, hp)
            if php <= 0:
                break
            step = rr / php
            delta = delta + step * pdir
            a_delta = a_delta + step * ap
            if g_delta is not None and gp is not None:
                g_delta = g_delta + step * gp
            res_v = res_v - step * hp
            rr_new = _vdot(res_v, res_v)
            if rr_new <= inner_tol * inner_tol * rr0:
                break
            pdir = res_v + (rr_new / rr) * pdir
            rr = rr_new
        r_t = r - a_delta
        gx_t = gx + g_delta if gx is not None and g_delta is not None else gx
        fsq_t, prior_t = problem.measure(r_t, gx_t)
        data_t = problem.data_from(fsq_t)
        f_t = data_t + lam * prior_t
        xn = _norm(x)
        if f_t < f:
            err = _norm(delta) / xn if xn > 0 else math.inf
            x = x + delta
            r, gx = r_t, gx_t
            fsq, data, prior_sum = fsq_t, data_t, prior_t
            # Section 5.6: relative change (5.25) smaller than the previous one -> towards Gauss-Newton.
            c = max(c / lm_down, min_damping * scale) if err < prev_err else c * lm_up
            prev_err = err
            rec = IterationRecord(iteration=n + 1, objective=f_t, data=data_t, prior=prior_t, lam=lam,
                                  rel_change=err, step=1.0, time_s=time.perf_counter() - t_start,
                                  damping=c, inner=inner, accepted=True)
        else:
            err = 0.0
            c *= lm_reject
            rec = IterationRecord(iteration=n + 1, objective=f, data=data, prior=prior_sum, lam=lam,
                                  rel_change=0.0, step=0.0,
                                  time_s=time.perf_counter() - t_start, damping=c, inner=inner,
                                  accepted=False)
        res.history.append(rec)
        if callback is not None:
            callback(n + 1, x)
        if rec.accepted and err < tol:
            res.stop_reason = f'relative change {err:.2e} < tol {tol:.2e}'
            res.converged = True
            break
        if not rec.accepted and c > 1e12 * scale:
            res.stop_reason = 'no step lowers the objective (damping exhausted)'
            res.converged = True
            break
    else:
        res.stop_reason = f'iteration cap {iterations}'
    res.x = x
    return res


def solve(problem: Problem, x0: torch.Tensor, *, method: str = 'cg', iterations: int = 10,
          tol: float = 1e-4, callback: Callback | None = None, reweight: Reweight | None = None,
          **lm_options: float) -> SolveResult:
    """Dispatch to ``sd`` (:func:`steepest_descent`), ``cg`` (:func:`conjugate_gradient`) or
    ``lm`` (:func:`levenberg_marquardt`, which takes ``lm_options``)."""
    if method not in SOLVERS:
        msg = f'solver must be one of {SOLVERS}, got {method!r}.'
        raise ValueError(msg)
    if iterations < 0:
        msg = f'iterations must be >= 0, got {iterations}.'
        raise ValueError(msg)
    if method == 'lm':
        return levenberg_marquardt(problem, x0, iterations=iterations, tol=tol, callback=callback,
                                   reweight=reweight, **lm_options)  # type: ignore[arg-type]
    if lm_options:
        msg = f'options {sorted(lm_options)} apply to the lm solver only.'
        raise ValueError(msg)
    fn = conjugate_gradient if method == 'cg' else steepest_descent
    return fn(problem, x0, iterations=iterations, tol=tol, callback=callback, reweight=reweight)
