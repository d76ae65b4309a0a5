"""Operators of the observation model (5.1): exact adjoints (dot-product tests), grids, shapes, errors."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from srmosaic_ros.core.sr.observation import build_frame_stack, frame_window
from srmosaic_ros.core.sr.operators import (
    Blur,
    BlurDecimate,
    Compose,
    Crop,
    Decimate,
    Mask,
    Warp,
    dot,
    gaussian_psf,
    hr_H_lr,
    lr_H_hr,
    psf_kernel_size,
)

RTOL = 1e-5
DTYPES = [torch.float64, torch.float32]
DEVICES = ['cpu', *(['cuda'] if torch.cuda.is_available() else [])]


def _homography(rng: np.random.Generator, cx: float, cy: float) -> np.ndarray:
    a = np.deg2rad(rng.uniform(-5, 5))
    s = 1.0 + rng.uniform(-0.05, 0.05)
    h = np.array([[s * np.cos(a), -s * np.sin(a), 0.0], [s * np.sin(a), s * np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    h[2, :2] = rng.uniform(-2e-4, 2e-4, 2)
    t = np.array([[1, 0, cx + rng.uniform(-3, 3)], [0, 1, cy + rng.uniform(-3, 3)], [0, 0, 1.0]])
    c = np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1.0]])
    return t @ h @ c


def _dot_test(op, x_shape, dtype, seed=0, device='cpu'):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(*x_shape, generator=g, dtype=dtype).to(device)
    ax = op.apply(x)
    y = torch.randn(ax.shape, generator=g, dtype=dtype).to(device)
    aty = op.adjoint(y)
    assert aty.shape == x.shape
    lhs, rhs = float(dot(ax, y)), float(dot(x, aty))
    # The dot-product test's scale is that of the summands, ||Ax|| ||y|| (and ||x|| ||A^T y||),
    # not the inner product itself, which can cancel to near zero and leave float32 rounding
    # (~1e-7 of the summands) above a tolerance taken relative to it.
    scale = max(float(ax.norm() * y.norm()), float(x.norm() * aty.norm()), 1e-12)
    assert abs(lhs - rhs) <= RTOL * scale, (lhs, rhs, scale)


@pytest.mark.parametrize('device', DEVICES)
@pytest.mark.parametrize('dtype', DTYPES)
@pytest.mark.parametrize('frames', [1, 4])
def test_warp_adjoint(dtype, frames, device):
    rng = np.random.default_rng(frames)
    mats = np.stack([_homography(rng, 20, 15) for _ in range(frames)])
    op = Warp(mats, (30, 40), (33, 37), dtype=dtype, device=device)
    _dot_test(op, (1, 3, 30, 40), dtype, device=device)


@pytest.mark.parametrize('dtype', DTYPES)
def test_warp_adjoint_per_frame_sources(dtype):
    rng = np.random.default_rng(3)
    mats = np.stack([_homography(rng, 10, 10) for _ in range(3)])
    op = Warp(mats, (21, 19), (15, 17), dtype=dtype, shared=False)
    _dot_test(op, (3, 2, 21, 19), dtype)


def test_warp_identity_and_subpixel_shift():
    x = torch.arange(40.0).reshape(1, 1, 5, 8)
    same = Warp(np.eye(3), (5, 8), (5, 8)).apply(x)
    torch.testing.assert_close(same, x)
    shifted = Warp(np.array([[1, 0, 0.25], [0, 1, 0], [0, 0, 1.0]]), (5, 8), (5, 8)).apply(x)
    torch.testing.assert_close(shifted[..., :-1], x[..., :-1] + 0.25)   # bilinear on a ramp is exact
    assert float(shifted[..., -1].abs().max()) < float(x.max())          # the last column reads zeros in part


@pytest.mark.parametrize('dtype', DTYPES)
@pytest.mark.parametrize('mode', ['valid', 'same'])
@pytest.mark.parametrize('kernel', ['gauss', 'random_odd', 'random_even'])
def test_blur_adjoint(dtype, mode, kernel):
    g = torch.Generator().manual_seed(1)
    k = {'gauss': gaussian_psf(1.2, 1), 'random_odd': torch.rand(5, 3, generator=g),
         'random_even': torch.rand(4, 6, generator=g)}[kernel]
    _dot_test(Blur(k, mode=mode), (2, 3, 17, 23), dtype)


def test_blur_is_a_convolution():
    k = torch.zeros(3, 3)
    k[0, 0] = 1.0   # the PSF h(d) is non-zero at offset d = (-1, -1) only; y(c) = sum_d h(d) x(c - d) = x(c + 1)
    x = torch.rand(1, 1, 6, 6)
    y = Blur(k, mode='same').apply(x)
    torch.testing.assert_close(y[0, 0, :-1, :-1], x[0, 0, 1:, 1:])


@pytest.mark.parametrize('dtype', DTYPES)
@pytest.mark.parametrize('factor', [2, 3, 4])
def test_decimate_adjoint(dtype, factor):
    _dot_test(Decimate(factor, (17, 23)), (2, 3, 17, 23), dtype)
    z = Decimate(factor, (8, 8)).adjoint(torch.ones(1, 1, *[-(-8 // factor)] * 2))
    assert float(z.sum()) == (-(-8 // factor)) ** 2          # zero filling: D^T keeps the values, adds zeros


@pytest.mark.parametrize('dtype', DTYPES)
@pytest.mark.parametrize('factor', [2, 3, 4])
@pytest.mark.parametrize(('separable', 'impl'), [(True, 'slices'), (True, 'conv'), (False, 'auto')])
def test_blur_decimate_adjoint_and_fusion(dtype, factor, separable, impl):
    g = torch.Generator().manual_seed(factor)
    k = gaussian_psf(0.5 * factor, factor) if separable else torch.rand(factor + 2, factor + 4, generator=g)
    op = BlurDecimate(k, factor, impl=impl)
    assert op.conv.separable == separable
    hr = op.hr_shape((7, 9))
    _dot_test(op, (2, 3, *hr), dtype)
    x = torch.randn(2, 3, *hr, dtype=dtype, generator=g)
    fused = op.apply(x)
    assert fused.shape[-2:] == (7, 9)
    two_step = Decimate(factor, (1, 1)).apply(Blur(k).apply(x))
    torch.testing.assert_close(fused, two_step)


@pytest.mark.parametrize('dtype', DTYPES)
def test_crop_and_mask_adjoint(dtype):
    _dot_test(Crop(2, 3, (5, 6), (10, 12)), (2, 1, 10, 12), dtype)
    m = (torch.rand(1, 1, 10, 12) > 0.5).to(dtype)
    _dot_test(Mask(m), (2, 3, 10, 12), dtype)
    with pytest.raises(ValueError, match='leaves'):
        Crop(8, 0, (5, 6), (10, 12))


@pytest.mark.parametrize('dtype', DTYPES)
@pytest.mark.parametrize('factor', [2, 3, 4])
def test_composition_dbw_adjoint(dtype, factor):
    """A_k = D B W_k R (explicit composition, one frame, then the batched observation operator)."""
    rng = np.random.default_rng(factor)
    psf = gaussian_psf(0.5 * factor, factor, dtype=dtype)
    hr_grid = BlurDecimate(psf, factor).hr_shape((6, 7))
    tile = (12 * factor, 10 * factor)
    w = Warp(_homography(rng, 5, 5)[None], tile, hr_grid, dtype=dtype)
    blurred = (hr_grid[0] - psf.shape[0] + 1, hr_grid[1] - psf.shape[1] + 1)
    d = Decimate(factor, blurred)
    a = Compose([Mask((torch.rand(1, 1, 6, 7) > 0.3).to(dtype)), d, Blur(psf), w])
    _dot_test(a, (1, 2, *tile), dtype)
    _dot_test(d @ Blur(psf) @ w, (1, 2, *tile), dtype)


@pytest.mark.parametrize('device', DEVICES)
@pytest.mark.parametrize('dtype', DTYPES)
@pytest.mark.parametrize('factor', [2, 3, 4])
def test_observation_operator_adjoint(dtype, factor, device):
    rng = np.random.default_rng(10 + factor)
    tile = (9, 11)
    frames = [torch.rand(3, 14, 15, dtype=dtype, device=device) for _ in range(4)]
    mats = [_homography(rng, 5, 4) for _ in frames]
    psf = gaussian_psf(0.5 * factor, factor, dtype=dtype, device=device)
    stack = build_frame_stack(frames, mats, tile, factor, psf)
    assert stack is not None
    assert stack.y.shape[0] == 4 and stack.mask.sum() > 0
    _dot_test(stack.operator, (1, 3, tile[0] * factor, tile[1] * factor), dtype, device=device)


@pytest.mark.parametrize('factor', [2, 3, 4])
def test_grid_convention_on_a_ramp(factor):
    """LR frame pixel i sees the HR tile at s i + (s - 1) / 2: a linear ramp comes out exactly there."""
    s = factor
    tile = (10, 12)
    hr = torch.arange(tile[1] * s, dtype=torch.float64).expand(1, 1, tile[0] * s, tile[1] * s)
    frame = torch.zeros(1, *tile, dtype=torch.float64)
    stack = build_frame_stack([frame], [np.eye(3)], tile, s, gaussian_psf(0.5 * s, s, dtype=torch.float64))
    assert stack is not None
    y0, x0, h, w = stack.windows[0]
    y = stack.operator.apply(hr)[0, 0, :h, :w]
    m = stack.mask[0, 0, :h, :w] > 0
    assert bool(m.any())
    expected = (s * torch.arange(x0, x0 + w, dtype=torch.float64) + (s - 1) / 2).expand(h, w)
    torch.testing.assert_close(y[m], expected[m])
    # and the matrices agree with that convention
    np.testing.assert_allclose(lr_H_hr(s) @ hr_H_lr(s), np.eye(3), atol=1e-12)
    np.testing.assert_allclose((hr_H_lr(s) @ [0.0, 0.0, 1.0])[:2], [(s - 1) / 2] * 2)


def test_mask_keeps_only_pixels_whose_psf_stays_inside_the_tile():
    tile = (10, 10)
    psf = gaussian_psf(1.0, 2)
    frame = torch.rand(1, 20, 20)
    shift = np.array([[1, 0, -5.0], [0, 1, -5.0], [0, 0, 1]])   # frame pixel (5, 5) is tile pixel (0, 0)
    stack = build_frame_stack([frame], [shift], tile, 2, psf)
    assert stack is not None
    y0, x0, h, w = stack.windows[0]
    assert y0 <= 5 and x0 <= 5 and y0 + h >= 15 and x0 + w >= 15   # the window holds the tile's footprint
    m = stack.mask[0, 0]
    rows = torch.nonzero(m.sum(dim=1)).ravel() + y0
    cols = torch.nonzero(m.sum(dim=0)).ravel() + x0
    # PSF side 8 HR px: taps 3.5 HR px each side of the LR centre 2 (i - 5) + 0.5 must lie in [0, 19],
    # so tile rows 2 .. 7, frame rows 7 .. 12.
    assert rows.tolist() == list(range(7, 13)) and cols.tolist() == list(range(7, 13))


def test_frame_window_none_when_disjoint():
    far = np.array([[1, 0, 500.0], [0, 1, 0], [0, 0, 1]])
    assert frame_window(far, (20, 20), (10, 10)) is None
    assert build_frame_stack([torch.rand(1, 20, 20)], [far], (10, 10), 2, gaussian_psf(1.0, 2)) is None


def test_psf_parity_and_normalisation():
    for s in (1, 2, 3, 4):
        k = gaussian_psf(0.6 * s, s)
        assert k.shape[0] % 2 == s % 2 and k.shape[0] == psf_kernel_size(0.6 * s, s)
        assert abs(float(k.sum()) - 1.0) < 1e-6
        torch.testing.assert_close(k, k.flip(0).flip(1))
    with pytest.raises(ValueError, match='parity'):
        gaussian_psf(1.0, 2, size=5)
    with pytest.raises(ValueError, match='2-D'):
        Blur(torch.ones(3))


def test_warp_refuses_bad_shapes():
    with pytest.raises(ValueError, match='3, 3'):
        Warp(np.eye(2), (5, 5), (5, 5))
    op = Warp(np.stack([np.eye(3)] * 3), (5, 5), (5, 5))
    with pytest.raises(ValueError, match='batch'):
        op.apply(torch.rand(2, 1, 5, 5))
