"""SR never worse than the best frame (core/sr/fallback.py): a tile SR cannot improve shows that frame upsampled."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.core.sr import SRConfig
from srmosaic_ros.core.sr.fallback import HELD_OUT_TOLERANCE, frame_upsampled, held_out_against_frame, super_resolve_or_fallback
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile

from sr_tiles import psnr, world01

TILE = (32, 32)     # LR; the HR tile is 64 x 64 at factor 2


@pytest.fixture(scope='module')
def world() -> np.ndarray:
    return world01()


@pytest.fixture(scope='module')
def tile(world):
    return make_synthetic_tile(world, (150, 480), TILE, 2, 6, noise_sigma=1.0, seed=4)


def test_frame_upsampled_is_the_reference_frame_bicubic_on_the_tile_grid(tile) -> None:
    """A frame that is the tile itself (identity homography) upsampled: OpenCV's bicubic resize, whose
    pixel convention (HR u at LR (u + 0.5) / s - 0.5) is the tiles'."""
    import cv2

    lr = (tile.frames[0][6:38, 6:38]).copy()
    up = frame_upsampled(lr, np.eye(3), TILE, 2)
    ref = cv2.resize(lr.astype(np.float32) / 255.0, (64, 64), interpolation=cv2.INTER_CUBIC)
    assert up.shape == (64, 64, 3)
    np.testing.assert_allclose(up[4:-4, 4:-4], np.clip(ref, 0, 1)[4:-4, 4:-4], atol=1e-5)


def test_sr_is_kept_where_it_predicts_held_out_frames_better_than_the_best_frame(tile) -> None:
    """Frames made with the PSF SR assumes: SR predicts the held-out frame about as well as the reference
    frame does (within the tolerance; both far better than the LR mosaic), so the tile is SR, and it is
    closer to the truth than that frame's bicubic."""
    config = SRConfig(device='cpu', psf_sigma=0.5)
    sums = held_out_against_frame(tile.frames, tile.tile_H_frames, TILE, 2, config)
    assert sums is not None and sums['n'] > 500 and sums['sr'] < HELD_OUT_TOLERANCE**2 * sums['frame'] < sums['mosaic']
    out = super_resolve_or_fallback(tile.frames, tile.tile_H_frames, TILE, 2, config)
    assert out.fallback == '' and out.result is not None
    best = frame_upsampled(tile.frames[out.reference], tile.tile_H_frames[out.reference], TILE, 2)
    assert psnr(out.image, tile.truth) > psnr(best, tile.truth) + 1.0


def test_a_tile_sr_makes_worse_falls_back_to_the_best_frame_upsampled(tile) -> None:
    """A PSF three times too wide, unclamped: the estimate rings, predicts the held-out frame worse than
    the best frame upsampled, and the tile shows that frame upsampled exactly, with the reason."""
    config = SRConfig(device='cpu', psf_sigma=1.6, clamp='off')
    out = super_resolve_or_fallback(tile.frames, tile.tile_H_frames, TILE, 2, config)
    assert out.fallback == 'held_out_worse_than_frame' and out.result is None
    assert out.held_out_rms['sr'] > 2 * out.held_out_rms['frame'] and 'worse than the best frame' in out.detail
    best = frame_upsampled(tile.frames[out.reference], tile.tile_H_frames[out.reference], TILE, 2)
    np.testing.assert_array_equal(out.image, best)
    # without the check the ringing tile would have been shown, and it is worse than the fallback on the truth
    ringing = super_resolve_or_fallback(tile.frames, tile.tile_H_frames, TILE, 2, config, holdouts=0)
    assert ringing.fallback == '' and psnr(ringing.image, tile.truth) < psnr(best, tile.truth)


def test_a_tile_whose_frames_disagree_falls_back_instead_of_being_left_out(world) -> None:
    """Frames of three different places: SR refuses the tile (consistency), and it shows the reference upsampled."""
    frames, mats = [], []
    for k, origin in enumerate([(120, 440), (400, 100), (700, 300)]):
        st = make_synthetic_tile(world, origin, TILE, 2, 1, noise_sigma=1.0, seed=k)
        frames += st.frames
        mats += st.tile_H_frames
    out = super_resolve_or_fallback(frames, mats, TILE, 2, SRConfig(device='cpu', iterations=5), holdouts=0)
    assert out.fallback == 'frames_disagree' and 'disagree' in out.detail
    np.testing.assert_array_equal(out.image, frame_upsampled(frames[out.reference], mats[out.reference], TILE, 2))
