"""Dense per-pixel registration on the tile (core/sr/dense_flow.py) and the displaced warp's adjoint."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from srmosaic_ros.core.sr import reconstruct_tile
from srmosaic_ros.core.sr.dense_flow import dense_flow_to_reference, remap_tile
from srmosaic_ros.core.sr.operators import Warp, dot
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile

from sr_tiles import hwc, psnr, world01

TILE = (48, 48)
KW = {'device': 'cpu', 'anchor': False, 'consistency': 0}


@pytest.fixture(scope='module')
def world() -> np.ndarray:
    return world01()


def _bend(img: np.ndarray, amp: float, seed: int) -> np.ndarray:
    """``img`` resampled along a smooth displacement of ``amp`` LR px (a period of 40 px): what an affine
    correction cannot take out (3-D ground, lens, rolling shutter)."""
    h, w = img.shape[:2]
    ph = np.random.default_rng(seed).uniform(0, 2 * np.pi, 4)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    dx = amp * np.sin(2 * np.pi * yy / 40 + ph[0]) * np.cos(2 * np.pi * xx / 40 + ph[1])
    dy = amp * np.cos(2 * np.pi * xx / 40 + ph[2]) * np.sin(2 * np.pi * yy / 40 + ph[3])
    return cv2.remap(img, (xx + dx).astype(np.float32), (yy + dy).astype(np.float32), cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_REFLECT)


@pytest.mark.parametrize('interpolation', ['bilinear', 'bicubic'])
def test_the_displaced_warp_keeps_an_exact_adjoint(interpolation) -> None:
    g = torch.Generator().manual_seed(0)
    mats = np.stack([np.array([[0.98, 0.05, 3.2], [-0.04, 1.01, 2.7], [1e-4, -2e-4, 1.0]]),
                     np.array([[1.0, 0.0, 1.5], [0.0, 1.0, 0.4], [0.0, 0.0, 1.0]])])
    warp = Warp(mats, (40, 44), (36, 38), dtype=torch.float64, interpolation=interpolation)
    warp.displace(0.8 * torch.randn((2, 36, 38, 2), generator=g, dtype=torch.float64))
    x = torch.randn((1, 1, 40, 44), generator=g, dtype=torch.float64)
    y = torch.randn((2, 1, 36, 38), generator=g, dtype=torch.float64)
    lhs, rhs = float(dot(warp.apply(x), y)), float(dot(x, warp.adjoint(y)))
    assert abs(lhs - rhs) <= 1e-10 * max(abs(lhs), 1.0)
    with pytest.raises(ValueError, match='warp offset'):
        warp.displace(torch.zeros((2, 36, 38)))


def test_a_planted_smooth_displacement_is_recovered(world) -> None:
    ref = np.ascontiguousarray(world[100:172, 400:472].mean(axis=2))
    bent = _bend(ref, 0.5, 1)
    warped = torch.from_numpy(np.stack([ref, bent]))[:, None]
    flow, conf = dense_flow_to_reference(warped, torch.ones_like(warped), 0, preset='fast')
    assert float(flow[0].abs().max()) == 0.0 and float(conf[0].min()) == 1.0
    # the flow superposes the bent frame on the reference: remapped along it, it matches far better
    inner = (slice(None), slice(None), slice(8, -8), slice(8, -8))
    before = float(((warped[1:] - warped[:1])[inner] ** 2).mean())
    after = float(((remap_tile(warped[1:], flow[1:]) - warped[:1])[inner] ** 2).mean())
    assert after < 0.3 * before
    assert float(flow[1].abs().max()) <= 1.0 + 1e-6                 # clipped to max_px
    assert float(conf[1][inner[1:]].mean()) > 0.5                    # the two flows agree on textured ground


def test_dense_flow_beats_the_affine_correction_alone_on_a_bent_tile(world) -> None:
    st = make_synthetic_tile(world, (120, 440), TILE, 2, 8, noise_sigma=1.0, seed=3)
    ref = reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, **KW).reference
    frames = [f if i == ref else _bend(f, 0.5, i) for i, f in enumerate(st.frames)]
    ecc = psnr(hwc(reconstruct_tile(frames, st.tile_H_frames, TILE, 2, dense_flow='off', **KW).image), st.truth)
    dense = psnr(hwc(reconstruct_tile(frames, st.tile_H_frames, TILE, 2, dense_flow='fast', **KW).image), st.truth)
    assert dense > ecc + 0.5
