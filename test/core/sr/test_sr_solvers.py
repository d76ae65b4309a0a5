"""Huber prior (5.4, 5.7 to 5.11), lambda (5.6) and the SD / CG / LM solvers on problems with known answers."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from srmosaic_ros.core.sr.observation import build_frame_stack
from srmosaic_ros.core.sr.operators import LinearOperator, dot, gaussian_psf
from srmosaic_ros.core.sr.prior import (
    CLIQUE_KERNELS,
    HuberPrior,
    adaptive_lambda,
    clique_differences,
    clique_differences_adjoint,
    huber,
    huber_derivative,
    huber_irls_weight,
    paper_lambda,
)
from srmosaic_ros.core.sr.solvers import LambdaRule, Problem, line_search_exact, solve

SOLVERS = ['sd', 'cg', 'lm']


class Dense(LinearOperator):
    """x (1, 1, n, n) -> (K, m) by K dense matrices: a small full-rank stand-in for A."""

    def __init__(self, mats: torch.Tensor, shape: tuple[int, int]) -> None:
        self.mats = mats          # (K, m, n*n)
        self.shape = shape

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return torch.einsum('kmn,n->km', self.mats, x.reshape(-1))

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return torch.einsum('kmn,km->n', self.mats, y).reshape(1, 1, *self.shape)


def _dense_problem(seed=0, frames=3, n=6, cond=3.0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    m = n * n
    q, _ = torch.linalg.qr(torch.randn(frames * m, m, generator=g, dtype=dtype))
    sv = torch.linspace(1.0, 1.0 / cond, m, dtype=dtype)
    v, _ = torch.linalg.qr(torch.randn(m, m, generator=g, dtype=dtype))
    a = (q * sv) @ v.T                                   # singular values 1 .. 1 / cond
    op = Dense(a.reshape(frames, m, m), (n, n))
    x_true = torch.rand(1, 1, n, n, generator=g, dtype=dtype)
    return op, x_true


# ----------------------------------------------------------------------------------------- prior


def test_clique_differences_are_the_clique_kernels():
    x = torch.rand(2, 3, 9, 11, dtype=torch.float64)
    w = CLIQUE_KERNELS[:, None].repeat(3, 1, 1, 1)
    torch.testing.assert_close(clique_differences(x), torch.nn.functional.conv2d(x, w, groups=3))


def test_clique_differences_match_equations():
    x = torch.zeros(1, 1, 5, 5, dtype=torch.float64)
    x[0, 0, 2, 2] = 1.0
    x[0, 0, 1, 3] = 3.0          # x[n1 - 1, n2 + 1] of the centre
    g = clique_differences(x)[0, :, 1, 1]     # the centre pixel (2, 2) of the 5x5 input
    assert g.tolist() == [-2.0, -2.0, -1.0 + 1.5, -1.0]     # (5.8) (5.9) (5.10) (5.11)
    assert clique_differences(torch.rand(2, 3, 7, 9)).shape == (2, 12, 5, 7)


@pytest.mark.parametrize('dtype', [torch.float64, torch.float32])
@pytest.mark.parametrize('impl', ['slices', 'conv'])
def test_clique_differences_adjoint(dtype, impl):
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 3, 11, 13, generator=g, dtype=dtype)
    gx = clique_differences(x, impl=impl)
    y = torch.randn(gx.shape, generator=g, dtype=dtype)
    lhs, rhs = float(dot(gx, y)), float(dot(x, clique_differences_adjoint(y, impl=impl)))
    assert abs(lhs - rhs) <= 1e-5 * abs(lhs)
    torch.testing.assert_close(gx, clique_differences(x, impl='conv' if impl == 'slices' else 'slices'))


def test_huber_values_derivative_and_irls_weight():
    a = 0.1
    g = torch.tensor([-0.3, -0.1, -0.05, 0.0, 0.05, 0.1, 0.3], dtype=torch.float64)
    expected = torch.tensor([2 * a * 0.3 - a * a, 0.01, 0.0025, 0.0, 0.0025, 0.01, 2 * a * 0.3 - a * a],
                            dtype=torch.float64)
    torch.testing.assert_close(huber(g, a), expected)
    gg = g.clone().requires_grad_(True)
    huber(gg, a).sum().backward()
    torch.testing.assert_close(huber_derivative(g, a), gg.grad)
    torch.testing.assert_close(huber_irls_weight(g, a) * 2 * g, huber_derivative(g, a))


def test_prior_gradient_matches_autograd():
    x = torch.rand(1, 2, 9, 8, dtype=torch.float64, requires_grad=True)
    prior = HuberPrior(alpha=0.05)
    prior.value(x).backward()
    torch.testing.assert_close(prior.gradient(x.detach()), x.grad)
    with pytest.raises(ValueError, match='alpha'):
        HuberPrior(alpha=0.0)


def test_adaptive_lambda_is_a_per_pixel_ratio_and_paper_lambda_is_not():
    rms = torch.tensor([0.01, 0.01, 0.01], dtype=torch.float64)
    w = torch.ones(3, dtype=torch.float64)
    lam = adaptive_lambda(rms, w, torch.tensor(1e-4, dtype=torch.float64), gamma=0.5)
    assert math.isclose(float(lam), 0.5 * 1e-4 / 1e-4)
    # (5.6) as printed: the same image twice as large (4x pixels) gets a 4x smaller lambda.
    n = 1000
    small = paper_lambda(torch.full((3,), 0.01 * math.sqrt(n)), torch.tensor(1e-4 * n))
    large = paper_lambda(torch.full((3,), 0.01 * math.sqrt(4 * n)), torch.tensor(1e-4 * 4 * n))
    assert math.isclose(float(small) / float(large), 4.0, rel_tol=1e-9)


def test_lambda_rule_reference_freezes_the_prior_activity():
    op, x_true = _dense_problem(seed=9)
    y = op.apply(x_true)
    fsq = torch.tensor([1e-4, 1e-4, 1e-4], dtype=torch.float64) * 36
    frozen = Problem(op, y, prior=HuberPrior(0.05), lam=LambdaRule('adaptive', gamma=0.5, reference=2e-4))
    live = Problem(op, y, prior=HuberPrior(0.05), lam=LambdaRule('adaptive', gamma=0.5))
    n = 4 * 16
    for prior_sum in (1e-3, 1e-2):
        assert math.isclose(frozen.lam_from(fsq, prior_sum, n), 0.5 * 1e-4 / 2e-4)
    assert live.lam_from(fsq, 1e-3, n) > live.lam_from(fsq, 1e-2, n)   # the live one follows the iterate


def test_lambda_rule_noise_cap_bounds_the_residual():
    """sigma(n) of (5.6) is the frames' RMS residual (0.01 here), capped at the noise when given."""
    op, x_true = _dense_problem(seed=9)
    y = op.apply(x_true)
    fsq = torch.tensor([1e-4, 1e-4, 1e-4], dtype=torch.float64) * 36
    n = 4 * 16
    for cap, expect in ((0.005, 0.5 * 0.005**2 / 2e-4), (0.02, 0.5 * 1e-4 / 2e-4), (None, 0.5 * 1e-4 / 2e-4)):
        p = Problem(op, y, prior=HuberPrior(0.05), lam=LambdaRule('adaptive', gamma=0.5, reference=2e-4, noise_cap=cap))
        assert math.isclose(p.lam_from(fsq, 1e-3, n), expect)


def test_lambda_rule_noise_floor_keeps_lambda_when_the_residual_vanishes():
    """sigma(n) of (5.6) is taken as at least the floor: a residual of 0.001 (the estimate fits its
    frames below their noise) gives the lambda of the floor, a residual above it its own."""
    op, x_true = _dense_problem(seed=9)
    y = op.apply(x_true)
    n = 4 * 16
    for rms, floor, expect in ((1e-3, 0.01, 0.5 * 0.01**2 / 2e-4), (0.02, 0.01, 0.5 * 0.02**2 / 2e-4),
                               (1e-3, None, 0.5 * 1e-3**2 / 2e-4)):
        fsq = torch.tensor([rms**2] * 3, dtype=torch.float64) * 36
        p = Problem(op, y, prior=HuberPrior(0.05), lam=LambdaRule('adaptive', gamma=0.5, reference=2e-4, noise_floor=floor))
        assert math.isclose(p.lam_from(fsq, 1e-3, n), expect)


# ----------------------------------------------------------------------------------- line search


def test_exact_line_search_finds_the_minimiser():
    g = torch.Generator().manual_seed(1)
    gx = torch.randn(500, generator=g, dtype=torch.float64) * 0.1
    gp = torch.randn(500, generator=g, dtype=torch.float64) * 0.1
    a, b, lam, alpha = 2.0, -3.0, 5.0, 0.05
    t = line_search_exact(a, b, lam, gx, gp, alpha, rtol=1e-10, max_evals=60)
    ts = torch.linspace(0, 3 * t, 3001, dtype=torch.float64)
    phi = torch.stack([a * s * s + b * s + lam * huber(gx + s * gp, alpha).sum() for s in ts])
    assert abs(float(ts[int(phi.argmin())]) - t) <= 3 * t / 3000 + 1e-9
    assert line_search_exact(1.0, 1.0, 0.0, None, None, 1.0) == 0.0     # ascent direction: no step


# ------------------------------------------------------------------------------------ solvers


@pytest.mark.parametrize('method', SOLVERS)
def test_lambda_zero_full_rank_recovers_x_exactly(method):
    op, x_true = _dense_problem()
    problem = Problem(op, op.apply(x_true), prior=None)
    x0 = torch.zeros_like(x_true)
    iters = {'sd': 400, 'cg': 80, 'lm': 30}[method]
    res = solve(problem, x0, method=method, iterations=iters, tol=1e-12)
    err = float(torch.linalg.vector_norm(res.x - x_true) / torch.linalg.vector_norm(x_true))
    assert err < 1e-6, (method, err, len(res.history))


def test_cg_is_linear_cg_on_a_quadratic():
    """With lambda = 0 and exact line search, nonlinear CG is linear CG: n unknowns, at most ~n steps."""
    op, x_true = _dense_problem(seed=2, n=5, cond=30.0)
    problem = Problem(op, op.apply(x_true), prior=None)
    res = solve(problem, torch.zeros_like(x_true), method='cg', iterations=25 + 5, tol=1e-14)
    assert float(torch.linalg.vector_norm(res.x - x_true)) < 1e-6 * float(torch.linalg.vector_norm(x_true))
    sd = solve(problem, torch.zeros_like(x_true), method='sd', iterations=30, tol=1e-14)
    assert sd.history[-1].objective > 1e3 * res.history[-1].objective


@pytest.mark.parametrize('method', ['sd', 'cg'])
def test_objective_decreases_monotonically_with_huber_prior(method):
    op, x_true = _dense_problem(seed=3)
    g = torch.Generator().manual_seed(5)
    y = op.apply(x_true) + 0.05 * torch.randn(op.apply(x_true).shape, generator=g, dtype=torch.float64)
    problem = Problem(op, y, prior=HuberPrior(0.05), lam=LambdaRule('fixed', value=0.3))
    res = solve(problem, torch.zeros_like(x_true), method=method, iterations=40, tol=0.0)
    f = [res.initial_objective] + [h.objective for h in res.history]
    assert all(b <= a * (1 + 1e-12) for a, b in zip(f, f[1:], strict=False)), f
    assert f[-1] < 0.5 * f[0]
    assert all(h.lam == 0.3 for h in res.history)


def test_lm_never_accepts_an_increase_and_adapts_damping():
    op, x_true = _dense_problem(seed=4)
    g = torch.Generator().manual_seed(6)
    y = op.apply(x_true) + 0.05 * torch.randn(op.apply(x_true).shape, generator=g, dtype=torch.float64)
    problem = Problem(op, y, prior=HuberPrior(0.02), lam=LambdaRule('fixed', value=0.5))
    res = solve(problem, torch.zeros_like(x_true), method='lm', iterations=25, tol=0.0)
    f = [res.initial_objective] + [h.objective for h in res.history]
    assert all(b <= a * (1 + 1e-12) for a, b in zip(f, f[1:], strict=False))
    damping = [h.damping for h in res.history]
    assert min(damping) < damping[0]                    # moves towards Gauss-Newton as steps shrink
    # and it reaches the same minimiser as CG
    cg = solve(problem, torch.zeros_like(x_true), method='cg', iterations=300, tol=1e-12)
    assert abs(res.history[-1].objective - cg.history[-1].objective) < 1e-4 * cg.history[-1].objective


def test_gradient_matches_autograd_with_frame_weights():
    op, x_true = _dense_problem(seed=7)
    y = op.apply(x_true)
    w = torch.tensor([1.0, 0.3, 2.0], dtype=torch.float64)
    problem = Problem(op, y, prior=HuberPrior(0.05), lam=LambdaRule('fixed', value=0.7), frame_weights=w)
    x = torch.rand_like(x_true).requires_grad_(True)
    r = y - op.apply(x)
    f = (w[:, None] * r**2).sum() + 0.7 * huber(clique_differences(x), 0.05).sum()
    f.backward()
    xd = x.detach()
    grad = problem.gradient(y - op.apply(xd), clique_differences(xd), 0.7)
    torch.testing.assert_close(grad, x.grad)


@pytest.mark.parametrize('method', SOLVERS)
def test_sr_operator_lambda_zero_fits_the_data_and_stays_minimum_norm(method):
    """The real observation operator, lambda = 0, y = A x_true, x0 = 0.

    A D B W model with a ``valid`` blur cannot see every HR pixel (A has a null space at any size),
    so the known answer is the minimum-norm solution pinv(A) y: every solver started at 0 stays in
    range(A^T) and converges to it, and the data residual vanishes.
    """
    s, tile = 2, (6, 6)
    rng = np.random.default_rng(0)
    mats = [np.array([[1.0, 0, rng.uniform(-4.6, -3.4)], [0, 1.0, rng.uniform(-4.6, -3.4)], [0, 0, 1]])
            for _ in range(6)]
    frames = [torch.zeros(1, 14, 14, dtype=torch.float64) for _ in mats]
    stack = build_frame_stack(frames, mats, tile, s, gaussian_psf(0.4 * s, s, dtype=torch.float64),
                              min_observed=1)
    assert stack is not None
    n = (tile[0] * s) * (tile[1] * s)
    eye = torch.eye(n, dtype=torch.float64).reshape(n, 1, 1, tile[0] * s, tile[1] * s)
    a = torch.stack([stack.operator.apply(e).reshape(-1) for e in eye], dim=1)
    g = torch.Generator().manual_seed(0)
    x_true = torch.rand(1, 1, tile[0] * s, tile[1] * s, generator=g, dtype=torch.float64)
    y = stack.operator.apply(x_true)
    x_min_norm = (torch.linalg.pinv(a) @ y.reshape(-1)).reshape(x_true.shape)
    problem = Problem(stack.operator, y, prior=None, counts=stack.counts)
    iters = {'sd': 100, 'cg': 60, 'lm': 15}[method]
    res = solve(problem, torch.zeros_like(x_true), method=method, iterations=iters, tol=1e-14,
                **({'inner_iterations': 30, 'damping0': 1e-3} if method == 'lm' else {}))
    # no component in the null space of A, ever
    _, sv, vh = torch.linalg.svd(a)
    null = vh[sv.numel():] if vh.shape[0] > sv.numel() else vh[sv < 1e-9 * sv[0]]
    null = torch.cat([null, vh[:sv.numel()][sv < 1e-9 * sv[0]]])
    assert float((null @ res.x.reshape(-1)).abs().max()) < 1e-8
    if method == 'sd':      # cond(A) ~ 500: steepest descent only gets part of the way in 100 steps
        assert res.history[-1].data < 1e-3 * res.initial_objective
    else:
        assert res.history[-1].data < 1e-12 * res.initial_objective
        assert float((res.x - x_min_norm).abs().max()) < 1e-6


def test_history_records_and_stopping_rule():
    op, x_true = _dense_problem(seed=8)
    problem = Problem(op, op.apply(x_true), prior=HuberPrior(0.05), lam=LambdaRule('adaptive', gamma=0.1))
    res = solve(problem, torch.zeros_like(x_true), method='cg', iterations=500, tol=1e-3)
    assert res.converged and 'tol' in res.stop_reason and len(res.history) < 500
    h = res.history[-1]
    assert h.rel_change < 1e-3 and h.lam >= 0 and math.isfinite(h.objective) and h.time_s >= 0
    capped = solve(problem, torch.zeros_like(x_true), method='sd', iterations=3, tol=0.0)
    assert not capped.converged and len(capped.history) == 3 and 'cap' in capped.stop_reason
    with pytest.raises(ValueError, match='solver'):
        solve(problem, torch.zeros_like(x_true), method='newton')
    with pytest.raises(ValueError, match='lm solver only'):
        solve(problem, torch.zeros_like(x_true), method='cg', inner_iterations=3)
    with pytest.raises(ValueError, match='lambda mode'):
        LambdaRule('auto')
