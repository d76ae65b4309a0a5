"""TorchRegistrar and its pieces against ground truth: DLT, RANSAC, LM, covariance, features, pairs."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from srmosaic_ros.errors import RegistrationError
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.registration import Registrar, RegistrationConfig
from srmosaic_ros.core.registration.covariance import homography_covariance_ut
from srmosaic_ros.core.registration.torch_features import (
    FeatureOptions,
    build_pyramid,
    detect_and_describe,
    image_to_gray_tensor,
)
from srmosaic_ros.core.registration.torch_matching import mutual_ratio_matches, transfer_points
from srmosaic_ros.core.registration.torch_ransac import (
    dlt_homography,
    homography_from_4,
    ransac_homography,
    refine_lm,
)
from srmosaic_ros.core.registration.torch_refine import PhotometricOptions
from srmosaic_ros.core.registration.torch_registrar import TorchRegistrar, TorchRegistrarOptions

from imagery import similarity, translation, view, world_rgb

W, H = 320, 240
F64 = torch.float64
H_TRUE = torch.tensor([[1.03, 0.06, 12.3], [-0.05, 0.98, -7.1], [2e-5, -1.5e-5, 1.0]], dtype=F64)

DEVICES = ['cpu', pytest.param('cuda', marks=pytest.mark.skipif(not torch.cuda.is_available(), reason='no CUDA GPU'))]


@pytest.fixture(params=DEVICES)
def device(request) -> torch.device:
    return torch.device(request.param)


@pytest.fixture(scope='module')
def cpu_registrar() -> TorchRegistrar:
    return TorchRegistrar(device='cpu')


def _points(n: int, seed: int, width: float = 640.0, height: float = 480.0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 2, generator=g, dtype=F64) * torch.tensor([width, height], dtype=F64)


def _pair(delta: np.ndarray, *, noise: float = 2.0, width: int = W, height: int = H):
    """prev frame at world offset (200, 150); cur = prev moved by delta (cur pixels -> prev pixels)."""
    world_H_prev = translation(200.0, 150.0)
    world_H_cur = world_H_prev @ delta
    prev = view(world_H_prev, width, height, noise=noise, seed=1)
    cur = view(world_H_cur, width, height, noise=noise, seed=2)
    return prev, cur, np.linalg.inv(world_H_prev) @ world_H_cur


# --- estimation pieces -------------------------------------------------------------------------

def test_dlt_exact_correspondences(device):
    src = _points(30, 0).to(device)
    dst = transfer_points(H_TRUE.to(device), src)
    est = dlt_homography(src, dst).cpu()
    assert est.shape == (3, 3)
    assert torch.allclose(est, H_TRUE, rtol=0, atol=1e-8 * H_TRUE.abs().max())
    # Batched, and the minimal 4-point solver.
    batch = dlt_homography(torch.stack([src, src + 1.0]), torch.stack([dst, dst]))
    assert batch.shape == (2, 3, 3)
    h4, ok = homography_from_4(src[None, :4], dst[None, :4])
    assert bool(ok[0])
    assert torch.allclose(h4[0].cpu(), H_TRUE, atol=1e-8 * H_TRUE.abs().max())


def test_dlt_refuses_too_few_points():
    with pytest.raises(ValueError, match='N >= 4'):
        dlt_homography(torch.zeros(3, 2), torch.zeros(3, 2))


def test_minimal_solver_flags_collinear_sample():
    src = torch.tensor([[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]], dtype=F64)
    _, ok = homography_from_4(src, src * 2.0)
    assert not bool(ok[0])


def test_ransac_recovers_h_with_planted_outliers(device):
    n_in, n_out = 240, 160           # 40% outliers
    src_in = _points(n_in, 1)
    g = torch.Generator().manual_seed(2)
    dst_in = transfer_points(H_TRUE, src_in) + 0.3 * torch.randn(n_in, 2, generator=g, dtype=F64)
    src_out = _points(n_out, 3)
    dst_out = _points(n_out, 4)
    src = torch.cat([src_in, src_out]).to(device)
    dst = torch.cat([dst_in, dst_out]).to(device)
    gen = torch.Generator(device=device).manual_seed(0)
    res = ransac_homography(src, dst, threshold_px=1.5, confidence=0.999, max_iterations=5000, generator=gen)
    assert res.dst_H_src is not None
    inl = res.inliers.cpu()
    assert inl[:n_in].float().mean() > 0.97
    assert inl[n_in:].float().mean() < 0.02
    # Adaptive count: far fewer than max_iterations at 60% inliers, at least the first round.
    assert 256 <= res.iterations <= 1024
    refined = refine_lm(src[res.inliers], dst[res.inliers], res.dst_H_src)
    assert corner_error_px(refined.cpu().numpy(), H_TRUE.numpy(), 640, 480) < 0.15


def test_ransac_gives_up_without_consensus():
    src, dst = _points(60, 5), _points(60, 6)
    res = ransac_homography(src, dst, threshold_px=1.5, confidence=0.999, max_iterations=2000,
                            generator=torch.Generator().manual_seed(0))
    assert res.iterations == 2000
    assert int(res.inliers.sum()) < 15


def test_lm_minimises_reprojection_error_like_opencv():
    src = _points(200, 7)
    g = torch.Generator().manual_seed(8)
    dst = transfer_points(H_TRUE, src) + 0.7 * torch.randn(200, 2, generator=g, dtype=F64)
    start = dlt_homography(src, dst)
    lm = refine_lm(src, dst, start, iterations=20)

    def cost(h: torch.Tensor) -> float:
        return float(((transfer_points(h, src) - dst) ** 2).sum())

    cv_h, _ = cv2.findHomography(src.numpy(), dst.numpy(), 0)   # LS + LM on the reprojection error
    assert cost(lm) <= cost(start)
    assert cost(lm) <= cost(torch.from_numpy(cv_h)) * (1 + 1e-6)
    batched = refine_lm(src[None].expand(3, -1, -1), dst[None].expand(3, -1, -1), start[None].expand(3, -1, -1))
    assert batched.shape == (3, 3, 3)
    assert torch.allclose(batched[1], lm, atol=1e-8)


# --- covariance ---------------------------------------------------------------------------------

def test_covariance_matches_monte_carlo():
    n = 120
    src = _points(n, 9)
    g = torch.Generator().manual_seed(10)
    dst = transfer_points(H_TRUE, src) + 0.4 * torch.randn(n, 2, generator=g, dtype=F64)
    est = refine_lm(src, dst, dlt_homography(src, dst), iterations=20)
    ut = homography_covariance_ut(est, src, dst)
    assert ut.covariance.shape == (8, 8)
    assert ut.samples == 4 * n + 1
    # Monte Carlo: the fitted points perturbed by the residual noise (sigma**2 / 2 per coordinate,
    # 4.41), each re-estimated to convergence.
    trials = 3000
    fit = transfer_points(est, src)
    noise = torch.randn(trials, n, 2, generator=g, dtype=F64) * (ut.sigma_px / math.sqrt(2.0))
    hs = refine_lm(src[None].expand(trials, n, 2), fit[None] + noise, est[None].expand(trials, 3, 3), iterations=8)
    h8 = (hs / hs[:, 2:3, 2:3]).reshape(trials, 9)[:, :8]
    mc = torch.cov(h8.T)
    ratio = ut.covariance.diagonal() / mc.diagonal()
    assert torch.all((ratio > 0.8) & (ratio < 1.2)), ratio
    # Whole matrix: whitened by the Monte Carlo estimate, all eigenvalues within 20% of 1.
    li = torch.linalg.inv(torch.linalg.cholesky(mc))
    eig = torch.linalg.eigvalsh(li @ ut.covariance @ li.T)
    assert torch.all((eig > 0.8) & (eig < 1.2)), eig
    # The one-step sigma-point fits agree with fully iterated ones at this noise level.
    ut_lm = homography_covariance_ut(est, src, dst, iterations=4)
    assert torch.allclose(ut_lm.covariance.diagonal(), ut.covariance.diagonal(), rtol=0.02)


def test_covariance_needs_inliers():
    with pytest.raises(ValueError, match='at least 5'):
        homography_covariance_ut(torch.eye(3, dtype=F64), torch.zeros(4, 2), torch.zeros(4, 2))


# --- features and matching ----------------------------------------------------------------------

def test_keypoints_subpixel_on_a_blob(device):
    yy, xx = np.mgrid[0:120, 0:160].astype(np.float64)
    x0, y0 = 71.3, 52.7
    img = 0.2 + 0.6 * np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * 3.0**2))
    kps = detect_and_describe(image_to_gray_tensor(img.astype(np.float32), device), 0, FeatureOptions(detect_level=0))
    assert len(kps) >= 1
    best = int(kps.response.argmax())
    err = (kps.xy[best].cpu().double() - torch.tensor([x0, y0], dtype=F64)).norm()
    assert err < 0.1
    assert kps.descriptors.shape == (len(kps), 128)
    assert torch.allclose(kps.descriptors.norm(dim=1), torch.ones(len(kps), device=device), atol=1e-5)


def test_descriptors_survive_rotation_and_scale():
    prev, cur, prev_H_cur = _pair(similarity(25.0, 1.3, 10.0, -5.0, W / 2, H / 2))
    opts = FeatureOptions(detect_level=0)
    dev = torch.device('cpu')
    kp = detect_and_describe(image_to_gray_tensor(prev, dev), 0, opts)
    kc = detect_and_describe(image_to_gray_tensor(cur, dev), 0, opts)
    pi, ci, _ = mutual_ratio_matches(kp.descriptors, kc.descriptors, ratio=0.8)
    err = (transfer_points(torch.from_numpy(prev_H_cur), kc.xy[ci].double()) - kp.xy[pi].double()).norm(dim=1)
    assert len(pi) >= 40
    assert float((err < 1.5).float().mean()) > 0.8


def test_gray_conversion_matches_image_ops():
    rgb = view(translation(0, 0), 64, 48)
    t = image_to_gray_tensor(rgb, torch.device('cpu'))[0, 0].numpy()
    ref = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    assert t.shape == (48, 64)
    assert np.abs(t - ref).max() < 1.0 / 255.0
    pyr = build_pyramid(torch.from_numpy(ref)[None, None], 3)
    assert [p.shape[-2:] for p in pyr] == [(48, 64), (24, 32), (12, 16)]


# --- the registrar ------------------------------------------------------------------------------

@pytest.mark.parametrize('delta', [
    translation(12.3, -7.6),
    similarity(6.0, 1.0, 20.0, 10.0, W / 2, H / 2),
    similarity(-4.0, 1.15, -15.0, 25.0, W / 2, H / 2),
])
def test_registers_known_motion_subpixel(cpu_registrar, delta):
    prev, cur, prev_H_cur = _pair(delta)
    reg = cpu_registrar.register(cpu_registrar.describe(prev), cpu_registrar.describe(cur))
    assert reg.ok, reg.reason
    assert reg.inliers >= 30
    assert corner_error_px(reg.prev_H_cur, prev_H_cur, W, H) < 0.1
    assert reg.extras['refined'] == 1.0
    cov = reg.covariance
    assert cov is not None and cov.shape == (8, 8)
    assert np.allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > -1e-12 * np.abs(cov).max())


def test_large_motion_640x480(cpu_registrar):
    delta = similarity(10.0, 1.2, 60.0, -20.0, 320.0, 240.0)
    prev, cur, prev_H_cur = _pair(delta, width=640, height=480)
    reg = cpu_registrar.register(cpu_registrar.describe(prev), cpu_registrar.describe(cur))
    assert reg.ok, reg.reason
    assert corner_error_px(reg.prev_H_cur, prev_H_cur, 640, 480) < 0.1


def test_scale_change_of_1_5_stays_subpixel():
    """At a zoom of 1.5 the feature estimate is 1 to 4 px off at the frame corners (features near the
    end of the detector's scale range, extrapolated); the converged photometric refinement, which
    still explains the feature inliers, is trusted beyond max_refine_shift_px and brings it back."""
    world = world_rgb(0.5)  # 1000 x 750: 640 x 480 frames at about the world's own resolution
    world_H_prev = similarity(10.0, 1.0, 150.0, 200.0)
    world_H_cur = world_H_prev @ similarity(-8.0, 1.5, 10.0, -5.0, 320.0, 240.0)
    prev = view(world_H_prev, 640, 480, noise=2.0, seed=1, image=world)
    cur = view(world_H_cur, 640, 480, noise=2.0, seed=2, image=world)
    prev_H_cur = np.linalg.inv(world_H_prev) @ world_H_cur
    errors = {}
    for name, options in (('trusted', TorchRegistrarOptions()),
                          ('2 px cap, 8 iterations', TorchRegistrarOptions(
                              photometric=PhotometricOptions(max_iterations=8), max_refine_shift_converged_px=2.0))):
        reg = TorchRegistrar(device='cpu', options=options)
        r = reg.register(reg.describe(prev), reg.describe(cur))
        assert r.ok, r.reason
        errors[name] = (corner_error_px(r.prev_H_cur, prev_H_cur, 640, 480), r.extras['refine_shift_px'])
    assert errors['trusted'][1] > 2.0, errors                      # the feature estimate was that far off
    assert errors['trusted'][0] < 0.1 < 1.0 < errors['2 px cap, 8 iterations'][0], errors


def test_ir_like_single_channel_with_gain_change(cpu_registrar):
    prev, cur, prev_H_cur = _pair(similarity(3.0, 1.05, -8.0, 6.0, W / 2, H / 2), noise=0.0)

    def ir(rgb: np.ndarray, gain: float, seed: int) -> np.ndarray:
        g = 1.0 - cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float64) / 255.0
        v = 0.5 + gain * (0.6 * g**1.5 - 0.25)
        v = v + np.random.default_rng(seed).normal(0.0, 2.0 / 255.0, v.shape)
        return np.clip(v * 255.0 + 0.5, 0, 255).astype(np.uint8)

    reg = cpu_registrar.register(cpu_registrar.describe(ir(prev, 1.0, 1)), cpu_registrar.describe(ir(cur, 1.08, 2)))
    assert reg.ok, reg.reason
    assert corner_error_px(reg.prev_H_cur, prev_H_cur, W, H) < 0.1


def test_registers_tensors_and_prev_features_are_reused(cpu_registrar):
    prev, cur, prev_H_cur = _pair(translation(4.0, 3.0))
    fp = cpu_registrar.describe(torch.from_numpy(prev).permute(2, 0, 1).float()[None] / 255.0)
    fc = cpu_registrar.describe(cur)
    first = cpu_registrar.register(fp, fc)
    again = cpu_registrar.register(fp, fc)        # cached features, same (seeded) result
    assert first.ok and again.ok
    assert np.array_equal(first.prev_H_cur, again.prev_H_cur)
    assert fp.keypoints_px.shape == (len(fp), 2) and fp.descriptors.shape == (len(fp), 128)
    assert fp.pyramid[0].shape[-2:] == (H, W)


def test_textureless_frame_fails_explicitly(cpu_registrar):
    prev, _, _ = _pair(translation(5, 5))
    rng = np.random.default_rng(3)
    flat = np.full_like(prev, 128)
    sea = np.clip(128 + rng.normal(0, 2, prev.shape), 0, 255).astype(np.uint8)   # flat + sensor noise
    for frame in (flat, sea):
        reg = cpu_registrar.register(cpu_registrar.describe(prev), cpu_registrar.describe(frame))
        assert not reg.ok
        assert 'too few' in reg.reason
    reg = cpu_registrar.register(cpu_registrar.describe(sea), cpu_registrar.describe(sea[::-1].copy()))
    assert not reg.ok


def test_unrelated_frames_fail(cpu_registrar):
    prev = view(translation(10, 10), W, H, noise=2)
    other = view(translation(600, 450), W, H, noise=2)
    reg = cpu_registrar.register(cpu_registrar.describe(prev), cpu_registrar.describe(other))
    assert not reg.ok
    assert reg.reason


def test_feature_only_mode_and_config_honoured():
    reg_ = TorchRegistrar(RegistrationConfig(max_features=200), device='cpu',
                          options=TorchRegistrarOptions(photometric=None, covariance=False))
    prev, cur, prev_H_cur = _pair(translation(7.5, -3.25))
    fp, fc = reg_.describe(prev), reg_.describe(cur)
    assert len(fp) <= 200 and not fc.templates
    reg = reg_.register(fp, fc)
    assert reg.ok and reg.covariance is None and reg.extras['refined'] == 0.0
    assert corner_error_px(reg.prev_H_cur, prev_H_cur, W, H) < 0.5


def test_failed_pair_is_retried_with_more_keypoints():
    reg_ = TorchRegistrar(RegistrationConfig(max_features=300), device='cpu',
                          options=TorchRegistrarOptions(features=FeatureOptions(max_keypoints=8)))
    prev, cur, prev_H_cur = _pair(translation(6.0, 4.0))
    fp, fc = reg_.describe(prev), reg_.describe(cur)
    assert len(fp) == 8
    reg = reg_.register(fp, fc)
    assert reg.ok, reg.reason
    assert reg.extras['retry_keypoints'] > 8
    assert len(fp) > 8 and fp.keypoints_px.shape == (len(fp), 2)     # cached features were extended
    assert corner_error_px(reg.prev_H_cur, prev_H_cur, W, H) < 0.1


def test_refuses_foreign_features_and_bad_options():
    ocv = Registrar()
    feats = ocv.describe(view(translation(0, 0), W, H))
    with pytest.raises(RegistrationError, match='TorchRegistrar.describe'):
        TorchRegistrar(device='cpu').register(feats, feats)
    with pytest.raises(ValueError, match='ransac_batch'):
        TorchRegistrarOptions(ransac_batch=1)
    with pytest.raises(ValueError, match='max_keypoints'):
        FeatureOptions(max_keypoints=2)
    with pytest.raises(ValueError, match='one entry per level'):
        PhotometricOptions(levels=(1, 0), points=(100,))
    with pytest.raises(ValueError, match='device'):
        TorchRegistrar(device='tpu')


def test_runs_on_device(device):
    reg_ = TorchRegistrar(device=device)
    prev, cur, prev_H_cur = _pair(similarity(2.0, 1.0, 5.0, 5.0, W / 2, H / 2))
    fp = reg_.describe(prev)
    assert fp.keypoints.xy.device.type == device.type
    assert fp.pyramid[0].device.type == device.type
    reg = reg_.register(fp, reg_.describe(cur))
    assert reg.ok, reg.reason
    assert corner_error_px(reg.prev_H_cur, prev_H_cur, W, H) < 0.1


def test_inverse_covariance_matches_monte_carlo():
    from srmosaic_ros.core.registration.torch_refine import inverse_covariance

    H = H_TRUE.numpy()
    rng = np.random.default_rng(4)
    a = rng.normal(size=(8, 8)) * np.array([1e-4, 1e-4, 0.05, 1e-4, 1e-4, 0.05, 1e-7, 1e-7])[:, None]
    cov = a @ a.T
    samples = rng.multivariate_normal((H / H[2, 2]).reshape(-1)[:8], cov, 20000)
    inv = np.array([np.linalg.inv(np.r_[s, 1.0].reshape(3, 3)) for s in samples])
    inv8 = (inv / inv[:, 2:3, 2:3]).reshape(-1, 9)[:, :8]
    ratio = np.diag(inverse_covariance(H, cov)) / np.diag(np.cov(inv8.T))
    assert np.all((ratio > 0.9) & (ratio < 1.1)), ratio


def test_refined_covariance_is_the_photometric_one_and_honest(cpu_registrar):
    """The returned (photometrically refined) homography carries its own Gauss-Newton covariance:
    much tighter than the feature covariance, and its corner sigma within a factor 2 of the
    errors of repeated noisy registrations of the same pair."""
    from srmosaic_ros.core.georef.ukf import corner_jacobian

    delta = similarity(2.0, 1.02, 9.3, -5.7, W / 2, H / 2)
    feature_only = TorchRegistrar(device='cpu', options=TorchRegistrarOptions(photometric=None))
    errs, sig_ph, sig_feat = [], [], []
    for seed in range(12):
        world_H_prev = translation(200.0, 150.0)
        prev = view(world_H_prev, W, H, noise=2.0, seed=100 + seed)
        cur = view(world_H_prev @ delta, W, H, noise=2.0, seed=200 + seed)
        reg = cpu_registrar.register(cpu_registrar.describe(prev), cpu_registrar.describe(cur))
        assert reg.ok and reg.extras['refined'] == 1.0 and reg.extras.get('covariance_from') == 1.0
        feat = feature_only.register(feature_only.describe(prev), feature_only.describe(cur))
        c = np.array([[0.0, 0.0], [W - 1.0, 0.0], [W - 1.0, H - 1.0], [0.0, H - 1.0]])
        for cov, out in ((reg.covariance, sig_ph), (feat.covariance, sig_feat)):
            J = corner_jacobian(reg.prev_H_cur, c)
            out.append(math.sqrt(np.trace(J @ cov @ J.T) / 8.0))
        errs.append(corner_error_px(reg.prev_H_cur, delta, W, H) / math.sqrt(math.pi / 2.0))  # ~ sigma per coordinate
    sigma_ph, sigma_true = float(np.median(sig_ph)), float(np.sqrt(np.mean(np.square(errs))))
    assert 0.5 < sigma_ph / sigma_true < 2.0, (sigma_ph, sigma_true)
    assert np.median(sig_feat) > 2.0 * sigma_ph


# --- fixed shapes (static_describe.py) ------------------------------------------------------------

def _textured_pair(seed: int = 0):
    world = world_rgb(0.5)
    world_H_prev = similarity(10.0, 1.0, 150.0, 200.0)
    world_H_cur = world_H_prev @ similarity(4.0, 1.1, 25.0, -10.0, 320.0, 240.0)
    return (view(world_H_prev, 640, 480, noise=2.0, seed=seed, image=world),
            view(world_H_cur, 640, 480, noise=2.0, seed=seed + 1, image=world),
            np.linalg.inv(world_H_prev) @ world_H_cur)


def test_static_shapes_describe_gives_the_data_dependent_features():
    """With fixed shapes (topk instead of nonzero, what a CUDA graph records) describe gives the same
    candidates, keypoints, descriptors and templates, hence the same registration."""
    prev, cur, prev_H_cur = _textured_pair()
    plain = TorchRegistrar(device='cpu')
    fixed = TorchRegistrar(device='cpu', options=TorchRegistrarOptions(static_shapes=True))
    assert plain._static is None and fixed._static is not None  # the CPU default: data-dependent
    a, b = plain.describe(cur), fixed.describe(cur)
    assert 100 < len(a.candidates) == len(b.candidates) < fixed.options.static_candidates
    np.testing.assert_array_equal(a.keypoints_px, b.keypoints_px)
    np.testing.assert_array_equal(a.descriptors, b.descriptors)
    torch.testing.assert_close(a.candidates.xy, b.candidates.xy, rtol=0, atol=0)
    for ta, tb in zip(a.templates, b.templates, strict=True):
        torch.testing.assert_close(ta.sd, tb.sd, rtol=0, atol=0)
    ra = plain.register(plain.describe(prev), a)
    rb = fixed.register(fixed.describe(prev), b)
    assert ra.ok and rb.ok
    np.testing.assert_allclose(rb.prev_H_cur, ra.prev_H_cur, rtol=1e-12, atol=1e-12)
    assert corner_error_px(rb.prev_H_cur, prev_H_cur, 640, 480) < 0.1
    # more keypoints for a hard pair come from the same (trimmed) candidates
    assert a.extend(400) and b.extend(400)
    np.testing.assert_array_equal(a.keypoints_px, b.keypoints_px)
    assert len(b.keypoints) == 400


def test_static_shapes_describe_has_a_single_host_synchronisation():
    """nonzero (a data-dependent size) waits for a GPU to drain; the fixed-shape describe has none,
    and reads one number at the end (how many candidates are real)."""
    from torch.profiler import ProfilerActivity, profile

    _, cur, _ = _textured_pair()
    counts = {}
    for name, static in (('plain', False), ('fixed', True)):
        reg = TorchRegistrar(device='cpu', options=TorchRegistrarOptions(static_shapes=static))
        reg.describe(cur)
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            reg.describe(cur)
        counts[name] = {e.key: e.count for e in prof.key_averages()
                        if e.key in ('aten::nonzero', 'aten::_local_scalar_dense')}
    # the template's (the scale-space maxima are found by cv2.findNonZero on the CPU)
    assert counts['plain'].get('aten::nonzero', 0) >= 1, counts
    assert counts['fixed'].get('aten::nonzero', 0) == 0 and counts['fixed'].get('aten::_local_scalar_dense') == 1, counts


@pytest.mark.skipif(not torch.cuda.is_available(),
                    reason='CUDA graphs need a CUDA GPU; run on a lent one by bench/device_check.sh')
def test_cuda_graph_describe_matches_eager_and_registers():
    """On a GPU describe is recorded as a CUDA graph (per frame size) and replayed: same features as
    running the fixed-shape operations one by one, and each frame's outputs survive the next replay."""
    prev, cur, prev_H_cur = _textured_pair()
    graphed = TorchRegistrar(device='cuda', options=TorchRegistrarOptions(cuda_graphs=True))
    eager = TorchRegistrar(device='cuda')  # fixed shapes, operation by operation (the GPU default)
    assert eager._static is not None and not eager._static.cuda_graphs
    fp, fc = graphed.describe(prev), graphed.describe(cur)
    assert graphed._static.graph_failures == 0
    ep, ec = eager.describe(prev), eager.describe(cur)
    np.testing.assert_allclose(fp.keypoints_px, ep.keypoints_px, atol=1e-4)
    np.testing.assert_allclose(fc.keypoints_px, ec.keypoints_px, atol=1e-4)
    reg = graphed.register(fp, fc)
    assert reg.ok and corner_error_px(reg.prev_H_cur, prev_H_cur, 640, 480) < 0.1
