"""SR of a straight edge and a lane marking without a periodic error pattern (core/sr/ringing.py, sr.clamp)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from srmosaic_ros.core.sr.operators import hr_H_lr, lr_H_hr
from srmosaic_ros.core.sr.reconstruct import SRConfig, SRError, reconstruct_tile
from srmosaic_ros.core.sr.fallback import super_resolve_or_fallback
from srmosaic_ros.core.sr.psf_select import TileFrames, choose_psf_sigma
from srmosaic_ros.core.sr.ringing import lr_range_on_hr, resolve_clamp
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile

FACTOR = 2
BORDER = 8  # HR pixels left out of the figures at the tile's edge


def edge_and_lane(n: int = 320, k: int = 4) -> np.ndarray:
    """(n, n, 3) float32 ground: a straight edge 12 deg off vertical (0.3 | 0.6) crossed by a lane
    marking 3 px wide (0.9), 7 deg off horizontal; drawn k times finer and area-reduced."""
    y, x = np.mgrid[0:n * k, 0:n * k] / k
    img = np.full((n * k, n * k), 0.3, np.float32)
    a, b = np.deg2rad(12.0), np.deg2rad(-7.0)
    img[(x - n / 2) * np.cos(a) + (y - n / 2) * np.sin(a) > 0] = 0.6
    img[np.abs((y - n * 0.35) * np.cos(b) - (x - n / 2) * np.sin(b)) < 1.5] = 0.9
    img = cv2.resize(img, (n, n), interpolation=cv2.INTER_AREA)
    return np.repeat(img[:, :, None], 3, axis=2)


def lr_nyquist_peak(err: np.ndarray) -> float:
    """Spectral density of ``err`` (H, W) in the band around the LR grid's Nyquist (0.25 cycles per HR
    pixel, +-0.05, along either axis) over its mean density elsewhere below the HR Nyquist: > 1 a
    peak there, the period of ringing that follows an edge across the LR grid."""
    e = err - err.mean()
    power = np.abs(np.fft.fft2(e)) ** 2
    fy, fx = np.meshgrid(np.abs(np.fft.fftfreq(e.shape[0])), np.abs(np.fft.fftfreq(e.shape[1])), indexing='ij')
    band = (np.abs(fx - 0.25) < 0.05) | (np.abs(fy - 0.25) < 0.05)
    rest = ~band & (fx < 0.45) & (fy < 0.45) & ((fx > 0) | (fy > 0))
    return float(power[band].mean() / power[rest].mean())


def psnr(err: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean(err.astype(np.float64) ** 2)))


@pytest.fixture(scope='module')
def sharp_tile():
    """Frames sharper than the solver's PSF (sigma 0.3 against its 0.5 LR px): the over-estimated PSF
    whose deconvolution rings."""
    return make_synthetic_tile(edge_and_lane(), (96, 64), (48, 64), FACTOR, 5, psf_sigma=0.3, noise_sigma=1.0, seed=3)


def sr_error(tile, **settings) -> np.ndarray:
    res = reconstruct_tile(tile.frames, tile.tile_H_frames, tile.tile_shape, FACTOR, device='cpu', psf_sigma=0.5,
                           **settings)
    sr = res.image.cpu().numpy()[0]
    return (sr - tile.truth[..., 0])[BORDER:-BORDER, BORDER:-BORDER]


def frame_bicubic_error(tile) -> np.ndarray:
    """The reference-free baseline: frame 0 upsampled bicubically onto the HR tile."""
    up = cv2.resize(tile.frames[0].astype(np.float32) / 255, None, fx=FACTOR, fy=FACTOR, interpolation=cv2.INTER_CUBIC)
    hr_H = hr_H_lr(FACTOR) @ tile.tile_H_frames[0] @ lr_H_hr(FACTOR)
    h, w = tile.truth.shape[:2]
    bic = cv2.warpPerspective(up, hr_H, (w, h), flags=cv2.INTER_CUBIC)[..., 0]
    return (bic - tile.truth[..., 0])[BORDER:-BORDER, BORDER:-BORDER]


def test_an_over_estimated_psf_rings_without_the_clamp_and_not_with_it(sharp_tile) -> None:
    """Unclamped, the error peaks at the LR Nyquist (a dark and a bright line along every edge) and
    SR falls below the frame's own bicubic; clamped to the frames' local range it does neither. The
    ringing is shown with the former defaults (least squares, lambda_gamma 0.1); the robust data term
    and the stronger prior damp the peak, but unclamped SR still falls below the frame's bicubic."""
    off = sr_error(sharp_tile, clamp='off', lambda_gamma=0.1, robust_pixels='off', reweight_at=(3,))
    off_default = sr_error(sharp_tile, clamp='off')
    on = sr_error(sharp_tile)  # the default
    bicubic = frame_bicubic_error(sharp_tile)
    assert SRConfig().clamp == 'auto'   # a PSF given, as here: the cell clamp
    assert lr_nyquist_peak(off) > 1.5 and psnr(off) < psnr(bicubic), (lr_nyquist_peak(off), psnr(off), psnr(bicubic))
    assert psnr(off_default) < psnr(bicubic), (psnr(off_default), psnr(bicubic))
    assert lr_nyquist_peak(on) < 1.0, lr_nyquist_peak(on)
    assert psnr(on) > psnr(bicubic) + 2.0, (psnr(on), psnr(bicubic))


def test_with_the_right_psf_the_clamp_keeps_the_gain() -> None:
    tile = make_synthetic_tile(edge_and_lane(), (96, 64), (48, 64), FACTOR, 5, psf_sigma=0.5, noise_sigma=1.0, seed=3)
    on = sr_error(tile)
    assert lr_nyquist_peak(on) < 1.0, lr_nyquist_peak(on)
    assert psnr(on) > psnr(frame_bicubic_error(tile)) + 2.0


def test_with_the_psf_chosen_from_the_frames_the_unclamped_tile_neither_rings_nor_loses_detail() -> None:
    """`process --sr`'s path: the PSF chosen by predicting held-out frames, then `sr.clamp: auto`, which is
    off for a chosen PSF, and the fallback's check. The edge and the lane come out without a peak at the
    LR Nyquist, above the frame's bicubic, and above the same tile clamped to the cell (which cuts the
    lane's peak, and with it the check's prediction: the clamped tile may even fall back to the frame)."""
    true_sigma = 0.5   # between two rungs of the ladder
    tile = make_synthetic_tile(edge_and_lane(), (96, 64), (48, 64), FACTOR, 5, psf_sigma=true_sigma, noise_sigma=1.0,
                               seed=3)
    config = SRConfig(device='cpu')
    sigma = choose_psf_sigma([TileFrames(tile.frames, tile.tile_H_frames, tile.tile_shape)], FACTOR, config,
                             config.psf_ladder, holdouts=2).sigma
    assert sigma <= true_sigma                             # not the over-estimated PSF that rings
    shown = {}
    for clamp in (resolve_clamp('auto', psf_chosen=True), 'cell'):
        out = super_resolve_or_fallback(tile.frames, tile.tile_H_frames, tile.tile_shape, FACTOR,
                                        SRConfig(device='cpu', psf_sigma=sigma, clamp=clamp), reference=0)
        shown[clamp] = (out.image[..., 0] - tile.truth[..., 0])[BORDER:-BORDER, BORDER:-BORDER]
    bicubic = frame_bicubic_error(tile)
    assert lr_nyquist_peak(shown['off']) < 1.0, lr_nyquist_peak(shown['off'])
    assert psnr(shown['off']) > psnr(bicubic) + 2.0, (psnr(shown['off']), psnr(bicubic))
    assert psnr(shown['off']) > psnr(shown['cell']) + 0.5, (psnr(shown['off']), psnr(shown['cell']))


@pytest.mark.parametrize('mode, reach', [('cell', 0), ('wide', 1)])
def test_each_hr_pixel_is_bounded_by_the_lr_pixels_around_its_lr_point(mode: str, reach: int) -> None:
    rng = np.random.default_rng(1)
    lr = rng.random((2, 5, 7))
    lo, hi = lr_range_on_hr(torch.as_tensor(lr), torch.as_tensor(lr), FACTOR, mode)
    assert lo.shape == hi.shape == (1, 2, 10, 14)
    for v in range(10):
        for u in range(14):
            pu, pv = (u + 0.5) / FACTOR - 0.5, (v + 0.5) / FACTOR - 0.5
            cols = np.clip(np.arange(int(np.floor(pu)) - reach, int(np.floor(pu)) + 2 + reach), 0, 6)
            rows = np.clip(np.arange(int(np.floor(pv)) - reach, int(np.floor(pv)) + 2 + reach), 0, 4)
            cell = lr[:, rows][:, :, cols]
            np.testing.assert_allclose(lo[0, :, v, u].numpy(), cell.min(axis=(1, 2)))
            np.testing.assert_allclose(hi[0, :, v, u].numpy(), cell.max(axis=(1, 2)))


def test_an_unknown_clamp_is_refused() -> None:
    with pytest.raises(SRError, match='clamp=.*must be one of'):
        SRConfig(clamp='soft')
