"""The peer of bench/sr_video.py (bench/peer_sr.py: median shift-and-add + Wiener) is a real method:
on synthetic frames with exact registration and the right PSF it beats a single frame's bicubic."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from srmosaic_ros.core.sr.fallback import frame_upsampled
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile

from sr_tiles import psnr, world01

TILE = (32, 32)


@pytest.fixture(scope='module')
def peer():
    path = Path(__file__).resolve().parents[3] / 'bench' / 'peer_sr.py'
    spec = importlib.util.spec_from_file_location('peer_sr', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(('seed', 'origin'), [(4, (150, 480)), (3, (120, 440))])
def test_the_peer_beats_one_frame_and_its_deconvolution_counts(peer, seed, origin) -> None:
    st = make_synthetic_tile(world01(), origin, TILE, 2, 8, noise_sigma=1.0, seed=seed)
    inner = (slice(4, -4), slice(4, -4))
    out = peer.peer_sr(st.frames, st.tile_H_frames, TILE, 2, 0.5)
    fused = peer.median_shift_and_add(st.frames, st.tile_H_frames, TILE, 2)
    one = frame_upsampled(st.frames[0], st.tile_H_frames[0], TILE, 2)
    assert out.shape == (64, 64, 3) and 0.0 <= out.min() and out.max() <= 1.0
    assert psnr(out[inner], st.truth[inner]) > psnr(fused[inner], st.truth[inner]) + 1.5 > psnr(one[inner], st.truth[inner]) + 1.5
    # no deconvolution for a PSF of 0
    np.testing.assert_array_equal(peer.wiener_deconvolve(fused, 0.0), fused)
