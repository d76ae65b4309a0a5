"""The robust data term (core/sr/robust_pixels.py): a moving object stops pulling the estimate."""
from __future__ import annotations

import cv2
import pytest
import torch

from srmosaic_ros.core.sr import reconstruct_tile
from srmosaic_ros.core.sr.robust_pixels import pixel_weights
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile

from sr_tiles import hwc, psnr, world01

TILE = (48, 48)
KW = {'device': 'cpu', 'anchor': False, 'consistency': 0, 'reweight_at': (3, 6)}


def test_weights_fall_on_outlying_residuals_only() -> None:
    g = torch.Generator().manual_seed(0)
    r = 0.01 * torch.randn((2, 1, 20, 20), generator=g)
    r[1, 0, 5:8, 5:8] = 0.5
    mask = torch.ones((2, 1, 20, 20))
    mask[0, 0, :, :2] = 0
    for norm in ('huber', 'lorentzian'):
        w = pixel_weights(r * mask, mask, norm=norm, scale=3.0)
        assert float(w[1, 0, 5:8, 5:8].max()) < 0.2
        assert float(w[0, 0, :, 2:].median()) > 0.9
        assert bool((w[0, 0, :, :2] == 1).all())
    with pytest.raises(ValueError, match='robust norm'):
        pixel_weights(r, mask, norm='off')


def test_a_moving_blob_is_down_weighted_and_the_ground_improves() -> None:
    st = make_synthetic_tile(world01(), (120, 440), TILE, 2, 8, noise_sigma=1.0, seed=3)
    ref = reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, **KW).reference
    frames = []
    for i, f in enumerate(st.frames):  # a bright car crossing the tile, in every frame but the reference
        f = f.copy()
        if i != ref:
            cv2.circle(f, (20 + 4 * i, 36), 5, (250, 250, 250), -1)
        frames.append(f)
    # the truth is the static ground: the car belongs to none of it
    plain = psnr(hwc(reconstruct_tile(frames, st.tile_H_frames, TILE, 2, robust_pixels='off', **KW).image), st.truth)
    robust = psnr(hwc(reconstruct_tile(frames, st.tile_H_frames, TILE, 2, robust_pixels='huber',
                                       robust_pixels_scale=3.0, **KW).image), st.truth)
    assert robust > plain + 3.0
    clean_plain = psnr(hwc(reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, robust_pixels='off', **KW).image),
                       st.truth)
    clean_robust = psnr(hwc(reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, robust_pixels='huber',
                                             robust_pixels_scale=3.0, **KW).image), st.truth)
    assert clean_robust > clean_plain - 0.1   # without outliers it costs (almost) nothing
