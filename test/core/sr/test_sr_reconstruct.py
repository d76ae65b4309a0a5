"""reconstruct_tile on real aerial texture with known HR ground truth (synthetic LR frames)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from srmosaic_ros.core.sr import SRConfig, SRError, SRFramesDisagree, reconstruct_tile
from srmosaic_ros.core.sr.self_check import SRNotBetterThanMosaic, held_out_errors, reconstruct_checked_tile
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile, perturb_homography

from sr_tiles import hwc, psnr, world01

TILE = (32, 32)     # LR; the HR tile is 64 x 64 at factor 2


@pytest.fixture(scope='module')
def world() -> np.ndarray:
    return world01()


@pytest.fixture(scope='module')
def tile(world):
    # concrete pipes and blocks on soil: edges and texture
    return make_synthetic_tile(world, (120, 440), TILE, 2, 6, noise_sigma=1.0, seed=3)


@pytest.mark.parametrize('solver', ['sd', 'cg', 'lm'])
def test_beats_bicubic_by_a_clear_margin(tile, solver):
    res = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, solver=solver, iterations=10, device='cpu')
    bicubic, sr = psnr(hwc(res.initial), tile.truth), psnr(hwc(res.image), tile.truth)
    assert sr > bicubic + 3.0, (solver, bicubic, sr)
    assert res.image.shape == (3, 64, 64) and res.initial.shape == (3, 64, 64)
    assert res.lr_mosaic.shape == (3, 32, 32) and res.coverage.shape == (32, 32)
    assert float(res.image.min()) >= 0.0 and float(res.image.max()) <= 1.0
    assert len(res.history) == 10 and all(np.isfinite(h.objective) for h in res.history)
    assert set(res.timings) == {'setup', 'initial', 'solve', 'total'}
    np.testing.assert_array_equal(res.frame_weights, np.ones(6))


def test_misregistered_frame_is_down_weighted(tile):
    mats = [h.copy() for h in tile.tile_H_frames]
    mats[2] = np.array([[1.0, 0.0, 1.5], [0.0, 1.0, -1.0], [0.0, 0.0, 1.0]]) @ mats[2]
    # frame 2 is the tile's reference (the frame the mosaic shows): anchored (the default) the tile is
    # left to the mosaic; the weights are measured without anchoring, and without aligning the others
    # to the reference on the tile (sr.local_align), which would carry the tile 1.5 px with it
    with pytest.raises(SRFramesDisagree, match='the frame the mosaic shows'):
        reconstruct_tile(tile.frames, mats, TILE, 2, iterations=10, device='cpu', local_align='off')
    kw = {'iterations': 10, 'device': 'cpu', 'anchor': False, 'local_align': 'off'}
    robust = reconstruct_tile(tile.frames, mats, TILE, 2, **kw)
    plain = reconstruct_tile(tile.frames, mats, TILE, 2, robust=False, consistency=0, **kw)
    gate_only = reconstruct_tile(tile.frames, mats, TILE, 2, robust=False, **kw)
    clean = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu', anchor=False)
    assert robust.reference == 2
    # the consistency test leaves the frame out (1.5 px off: NCC 0.72 with the others, 1.00 among them)
    assert list(gate_only.frame_consistent) == [True, True, False, True, True, True]
    assert gate_only.frame_weights[2] == 0.0
    assert psnr(hwc(gate_only.image), tile.truth) > psnr(hwc(plain.image), tile.truth) + 3.0
    assert robust.frame_weights[2] < 0.1
    assert np.all(np.delete(robust.frame_weights, 2) > 0.9)
    assert robust.frame_rms[2] > 5 * np.median(robust.frame_rms)
    p_robust, p_plain, p_clean = (psnr(hwc(r.image), tile.truth) for r in (robust, plain, clean))
    assert p_robust > p_plain + 3.0
    assert p_robust > p_clean - 0.5          # as if the bad frame were not there


def test_lambda_noise_cap_acts_on_misfit_only(world, tile):
    """Where the model fits, the residual is below the noise and the cap changes nothing; with every
    frame misregistered by 0.5 px (misfit) the residual exceeds the noise and the cap lowers lambda."""
    def last_lambda(mats, **kw):
        return reconstruct_tile(tile.frames, mats, TILE, 2, iterations=5, device='cpu', **kw).history[-1].lam
    fit_on, fit_off = last_lambda(tile.tile_H_frames, lambda_noise_cap=1.0), last_lambda(tile.tile_H_frames, lambda_noise_cap=0)
    assert fit_on == pytest.approx(fit_off, rel=0.2)
    rng = np.random.default_rng(1)
    off = [perturb_homography(h, f.shape[:2], 0.5, rng) for h, f in zip(tile.tile_H_frames, tile.frames, strict=True)]
    # the tile's own alignment (sr.local_align) would take the misfit away
    mis_on, mis_off = (last_lambda(off, lambda_noise_cap=c, consistency=0, local_align='off') for c in (1.0, 0.0))
    assert mis_off > 2 * fit_off       # the misfit raises the residual, so (5.6) raises lambda ...
    assert mis_on < 0.7 * mis_off      # ... and the cap takes most of that back


def test_lambda_noise_floor_keeps_the_prior_on_a_single_frame(world):
    """One noisy frame can be fitted exactly: (5.6)'s lambda falls with the residual and the noise is
    amplified into the tile; with the residual floored at twice the noise lambda stays up, and the
    tile is closer to the truth. (Unclamped, sr.clamp off: the option's effect
    alone; at the lambda_gamma the floor was set against, 0.1: with 0.3 the floor over-smooths.)"""
    st = make_synthetic_tile(world, (150, 480), TILE, 2, 1, noise_sigma=4.0, seed=3)
    runs = {f: reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, iterations=10, device='cpu', consistency=0,
                                anchor=False, lambda_noise_floor=f, clamp='off', lambda_gamma=0.1) for f in (0.0, 2.0)}
    assert runs[2.0].history[-1].lam > 3 * runs[0.0].history[-1].lam
    assert psnr(hwc(runs[2.0].image), st.truth) > psnr(hwc(runs[0.0].image), st.truth)


def test_moving_object_frame_is_down_weighted(world):
    st = make_synthetic_tile(world, (150, 480), TILE, 2, 6, noise_sigma=1.0, seed=4)
    frames = [f.copy() for f in st.frames]
    frames[4][8:28, 10:30] = (255, 40, 40)                  # a red vehicle crossing in one frame only
    res = reconstruct_tile(frames, st.tile_H_frames, TILE, 2, iterations=10, device='cpu')
    assert res.frame_weights[4] < 0.2 and np.all(np.delete(res.frame_weights, 4) > 0.9)
    assert psnr(hwc(res.image), st.truth) > psnr(hwc(res.initial), st.truth) + 2.0


def test_registration_noise_costs_little(world, tile):
    rng = np.random.default_rng(0)
    noisy = [perturb_homography(h, f.shape[:2], 0.05, rng)
             for h, f in zip(tile.tile_H_frames, tile.frames, strict=True)]
    exact = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu')
    approx = reconstruct_tile(tile.frames, noisy, TILE, 2, iterations=10, device='cpu')
    assert psnr(hwc(approx.image), tile.truth) > psnr(hwc(exact.image), tile.truth) - 1.0


def test_mono_frames_tensor_input_and_rgb_mode(tile):
    mono = [torch.from_numpy(f.mean(axis=2).astype(np.float32) / 255.0)[None] for f in tile.frames]
    res = reconstruct_tile(mono, tile.tile_H_frames, TILE, 2, iterations=3, device='cpu')
    assert res.image.shape == (1, 64, 64)
    rgb = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, iterations=5, device='cpu', color='rgb')
    assert rgb.image.shape == (3, 64, 64)
    assert psnr(hwc(rgb.image), tile.truth) > psnr(hwc(rgb.initial), tile.truth) + 2.0
    assert res.to_numpy().shape == (64, 64, 1) and res.to_numpy().dtype == np.uint8


def test_uint16_ir_frames_share_one_stretch(tile):
    """Radiometric IR: uint16 counts in a narrow band; one stretch for all frames keeps them consistent."""
    frames = [(8000 + 16.0 * f.mean(axis=2)).astype(np.uint16) for f in tile.frames]
    res = reconstruct_tile(frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu')
    assert res.image.shape == (1, 64, 64)
    truth = tile.truth.mean(axis=2).ravel()

    def fit_psnr(img: torch.Tensor) -> float:     # PSNR after the best affine map of the truth
        x = img[0].double().cpu().numpy().ravel()
        a, b = np.polyfit(truth, x, 1)
        return psnr(x, a * truth + b) + 20 * np.log10(1.0 / a)    # in the truth's intensity units

    assert fit_psnr(res.image) > fit_psnr(res.initial) + 2.0
    np.testing.assert_array_equal(res.frame_weights, np.ones(6))


def test_callback_sees_initial_then_every_iteration(tile):
    seen: list[int] = []
    first: list[torch.Tensor] = []

    def cb(n: int, img: torch.Tensor) -> None:
        seen.append(n)
        if n == 0:
            first.append(img.clone())

    res = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, iterations=4, tol=0.0, device='cpu',
                           callback=cb)
    assert seen == [0, 1, 2, 3, 4]
    torch.testing.assert_close(first[0], res.initial)


def test_frames_outside_the_tile_get_zero_weight_and_errors(tile):
    far = np.array([[1.0, 0.0, 900.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    res = reconstruct_tile([*tile.frames, tile.frames[0]], [*tile.tile_H_frames, far], TILE, 2, iterations=2,
                           device='cpu')
    assert res.frame_weights[-1] == 0.0 and np.isnan(res.frame_rms[-1])
    with pytest.raises(SRError, match='no frame observes'):
        reconstruct_tile(tile.frames[:1], [far], TILE, 2, device='cpu')
    with pytest.raises(SRError, match='unknown SR settings'):
        reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, device='cpu', sigma=1.0)
    with pytest.raises(SRError, match='parity'):
        reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, device='cpu', psf=np.ones((3, 3)))
    with pytest.raises(SRError, match='solver'):
        SRConfig(solver='adam')
    with pytest.raises(SRError, match='same, non-zero number'):
        reconstruct_tile(tile.frames, tile.tile_H_frames[:2], TILE, 2, device='cpu')


@pytest.mark.skipif(not torch.cuda.is_available(), reason='needs a CUDA GPU')
def test_gpu_matches_cpu(tile):
    cpu = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu')
    gpu = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cuda')
    assert gpu.image.is_cuda
    assert abs(psnr(hwc(gpu.image), tile.truth) - psnr(hwc(cpu.image), tile.truth)) < 0.05
    assert float((gpu.image.cpu() - cpu.image).abs().mean()) < 2e-3


def test_core_sr_imports_no_ros():
    code = ('import sys; import srmosaic_ros.core.sr as m; '
            "bad = [n for n in ('rclpy', 'rosbags') if n in sys.modules]; print(bad); sys.exit(bool(bad))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=False)
    assert out.returncode == 0, out.stdout + out.stderr


def test_anchoring_shows_what_the_reference_frame_shows(world, tile):
    """sr.anchor: what only the reference frame sees (a small object the weights cannot single out) is
    in the anchored tile, as in the mosaic around it; on consistent frames anchoring costs little."""
    plain = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu', anchor=False)
    anchored = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu')
    assert np.isnan(plain.anchor_rms) and 0 < anchored.anchor_rms < 3.0 / 255
    assert psnr(hwc(anchored.image), tile.truth) > psnr(hwc(plain.image), tile.truth) - 0.5
    assert psnr(hwc(anchored.image), tile.truth) > psnr(hwc(anchored.initial), tile.truth) + 3.0

    ref = plain.reference
    frames = [f.copy() for f in tile.frames]
    frames[ref][21:24, 21:24] = np.clip(frames[ref][21:24, 21:24].astype(int) + 80, 0, 255)  # only in the reference
    centre = tile.tile_H_frames[ref] @ np.array([22.0, 22.0, 1.0])
    u, v = (2 * centre[:2] / centre[2] + 0.5).astype(int)  # its HR pixel in the tile
    truth = float(tile.truth[v - 2:v + 3, u - 2:u + 3].mean())
    # every frame admitted (no weights, no gate): the object is in the anchored tile at its full
    # contrast (80 / 255 = 0.31), as in the mosaic; without anchoring it is averaged to a sixth
    admitted = [reconstruct_tile(frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu', anchor=a,
                                 robust=False, consistency=0) for a in (False, True)]
    excess = [float(r.image[:, v - 2:v + 3, u - 2:u + 3].mean()) - truth for r in admitted]
    assert excess[1] > 0.25 and excess[0] < 0.1, excess
    # with the defaults the robust weights set that frame aside: the tile is left to the mosaic,
    # which shows that frame there; not anchored, it is fused from the others
    with pytest.raises(SRFramesDisagree, match='robust weights'):
        reconstruct_tile(frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu')
    fused = reconstruct_tile(frames, tile.tile_H_frames, TILE, 2, iterations=10, device='cpu', anchor=False)
    assert fused.frame_weights[ref] < 0.5 and np.isnan(fused.anchor_rms)


def test_moving_objects_are_kept_out_of_the_data_term(world) -> None:
    """sr.moving: a car (a bright 5 x 3 LR px box) crosses the tile, in a different place in each of
    five of eight frames: too many for the per-frame outlier weights (measured: every frame keeps
    weight 1), so the data term fits it and leaves its trail in the SR tile (trail error 0.014,
    PSNR 37.8 dB; anchoring takes back part of it). With the per-pixel weights (core/sr/moving.py)
    every frame keeps the pixels the car did not cover: the trail's error is no worse than the
    bicubic mosaic's of the frames without cars, and the tile gains 3 dB (measured 0.0077, 40.9 dB).
    Unclamped (sr.clamp off) and least squares (sr.robust_pixels off, whose Huber weights take out part
    of the trail too), so that sr.moving's doing is what is measured."""
    st = make_synthetic_tile(world, (150, 480), TILE, 2, 8, noise_sigma=1.0, seed=6)
    frames = [f.copy() for f in st.frames]
    trail = np.zeros((TILE[0] * 2, TILE[1] * 2), bool)  # HR tile pixels a car covered
    for k, (tx, ty) in zip((1, 4, 6, 2, 7), ((8, 10), (15, 14), (22, 18), (10, 22), (20, 6))):
        frame_H_tile = np.linalg.inv(st.tile_H_frames[k])
        p = frame_H_tile @ np.array([tx, ty, 1.0])
        u, v = int(round(p[0] / p[2])), int(round(p[1] / p[2]))
        frames[k][v - 1:v + 2, u - 2:u + 3] = (250, 240, 40)
        trail[2 * ty - 2:2 * ty + 4, 2 * tx - 4:2 * tx + 6] = True
    truth = st.truth

    def errors(**kw) -> tuple[float, float, float, int]:
        res = reconstruct_tile(frames, st.tile_H_frames, TILE, 2, iterations=10, device='cpu', clamp='off',
                               robust_pixels='off', **kw)
        sr, bic = hwc(res.image).astype(np.float64), hwc(res.initial).astype(np.float64)
        return (float(np.abs(sr - truth)[trail].mean()), float(np.abs(bic - truth)[trail].mean()), psnr(sr, truth),
                res.moving_pixels)

    plain_trail, plain_bicubic, plain_psnr, n0 = errors()
    moving_trail, moving_bicubic, moving_psnr, n1 = errors(moving=0.05)
    clean = reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, iterations=10, device='cpu', clamp='off',
                             robust_pixels='off')
    clean_bicubic = float(np.abs(hwc(clean.initial).astype(np.float64) - truth)[trail].mean())
    assert n0 == 0 and n1 > 0
    assert moving_trail < 0.6 * plain_trail      # the trail is gone from the SR tile
    assert moving_trail <= clean_bicubic * 1.05  # no worse than bicubic of the frames without the car
    assert moving_psnr > plain_psnr + 2.5
    with pytest.raises(SRError, match='moving'):
        SRConfig(moving=1.5)


def test_the_leave_one_out_check_refuses_a_tile_made_to_ring(world) -> None:
    """sr.self_check: the tile is solved without the frame nearest its centre after the reference, and
    that frame predicted from the SR estimate and from the mosaic. With the PSF the frames were made
    with (0.5 LR px) SR predicts it three times better (RMS 1.25 against 3.6 grey levels) and the tile
    is made; with a PSF three times too wide the estimate rings (23 dB against the bicubic mosaic's
    33 on the truth), predicts the frame worse than the mosaic, and the tile is refused. (A PSF
    nearly twice too wide, 0.9, also loses to bicubic on the truth, 26 dB, but still predicts the
    frame better than the mosaic: the check sees in the frames' resolution only.) The tile is made to
    ring unclamped (sr.clamp off): clamped to the frames' range it no longer rings (core/sr/ringing.py)."""
    st = make_synthetic_tile(world, (150, 480), TILE, 2, 6, noise_sigma=1.0, seed=4)
    right = SRConfig(device='cpu', psf_sigma=0.5, self_check=1)
    sse_sr, sse_mosaic, n = held_out_errors(st.frames, st.tile_H_frames, TILE, 2, right)
    assert n > 500 and sse_sr < 0.5 * sse_mosaic
    res = reconstruct_checked_tile(st.frames, st.tile_H_frames, TILE, 2, right)
    assert psnr(hwc(res.image), st.truth) > psnr(hwc(res.initial), st.truth) + 3.0
    ringing = SRConfig(device='cpu', psf_sigma=1.6, self_check=1, clamp='off')
    assert psnr(hwc(reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, config=ringing).image), st.truth) < 30.0
    with pytest.raises(SRNotBetterThanMosaic, match='no better than the mosaic'):
        reconstruct_checked_tile(st.frames, st.tile_H_frames, TILE, 2, ringing)
    # the check off: the ringing tile is made
    reconstruct_checked_tile(st.frames, st.tile_H_frames, TILE, 2, SRConfig(device='cpu', psf_sigma=1.6, self_check=0, clamp='off'))
    # two frames: nothing to hold out, the tile is made
    assert held_out_errors(st.frames[:2], st.tile_H_frames[:2], TILE, 2, right) == (0.0, 0.0, 0)


def test_compression_in_the_reference_is_taken_back_only_when_asked(world, tile):
    """sr.anchor_compression: blotches like those a DCT quantiser leaves (correlated, under two grey
    levels) in the reference frame alone are the recorded frame's, not the ground's. By default the
    anchoring threshold keeps most of them out of the tile; with the option the tile takes them back
    whole: further from the truth, closer to the reference as recorded. (Unclamped, sr.clamp off: the
    option's effect alone.)"""
    import cv2

    kw = {'iterations': 10, 'device': 'cpu', 'robust': False, 'consistency': 0, 'clamp': 'off'}
    ref = reconstruct_tile(tile.frames, tile.tile_H_frames, TILE, 2, **kw).reference
    rng = np.random.default_rng(8)
    h, w = tile.frames[ref].shape[:2]
    blotches = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 1.2)
    blotches *= 1.6 / blotches.std()
    frames = [f.copy() for f in tile.frames]
    add = blotches if frames[ref].ndim == 2 else blotches[..., None]
    frames[ref] = np.clip(frames[ref].astype(np.float32) + add + 0.5, 0, 255).astype(np.uint8)
    plain, taken = (reconstruct_tile(frames, tile.tile_H_frames, TILE, 2, anchor_compression=c, **kw)
                    for c in (False, True))
    assert plain.reference == taken.reference == ref
    # the blotches as the HR tile sees them: HR pixel (u, v) is LR tile point ((u + 0.5) / 2 - 0.5, ...)
    vs, us = np.mgrid[0:TILE[0] * 2, 0:TILE[1] * 2].astype(np.float64)
    q = np.linalg.inv(tile.tile_H_frames[ref]) @ np.stack([(us + 0.5) / 2 - 0.5, (vs + 0.5) / 2 - 0.5, np.ones_like(us)]).reshape(3, -1)
    seen = cv2.remap(blotches, (q[0] / q[2]).reshape(us.shape).astype(np.float32),
                     (q[1] / q[2]).reshape(us.shape).astype(np.float32), cv2.INTER_LINEAR) / 255.0
    recorded = tile.truth + (seen if tile.truth.ndim == 2 else seen[..., None])
    to_truth = [psnr(hwc(r.image), tile.truth) for r in (plain, taken)]
    to_recorded = [psnr(hwc(r.image), recorded) for r in (plain, taken)]
    assert to_truth[0] > to_truth[1] + 0.3, to_truth
    assert to_recorded[1] > to_recorded[0] + 0.3, to_recorded
