"""Exposure gains (core/mosaic/exposure.py): frames of one ground with planted exposures and white
balances are brought back to one exposure; a frame that overlaps none keeps gain 1."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.core.mosaic.exposure import exposure_gains


def _ground(seed: int = 0) -> np.ndarray:
    """(240, 480, 3) float ground texture in [40, 200]."""
    import cv2

    rng = np.random.default_rng(seed)
    g = cv2.GaussianBlur(rng.uniform(0, 1, (240, 480, 3)).astype(np.float32), (0, 0), 3)
    g = (g - g.min()) / (g.max() - g.min())
    return 40 + 160 * g


def _frames(exposure: list[np.ndarray], step: int = 60, size: int = 120) -> tuple[list, list]:
    """Frames size x size cut along the ground every ``step`` px, each times its exposure (3,)."""
    ground = _ground()
    thumbs, Hs = [], []
    for k, e in enumerate(exposure):
        x0 = k * step
        crop = ground[60:60 + size, x0:x0 + size] * e
        thumbs.append(np.clip(np.round(crop), 0, 255).astype(np.uint8))
        Hs.append(np.array([[1.0, 0, x0], [0, 1.0, 60], [0, 0, 1]]))  # thumb px -> ground px
    return thumbs, Hs


def test_planted_exposures_and_white_balance_are_undone() -> None:
    exposure = [np.array(e) for e in ([1, 1, 1], [0.8, 0.8, 0.8], [1.1, 0.95, 0.85], [1, 1, 1], [1.2, 1.2, 1.2])]
    thumbs, Hs = _frames(exposure)
    gains = exposure_gains(thumbs, Hs, 'channels')
    assert gains.shape == (5, 3)
    # every frame brought to one exposure (up to the common level the prior leaves): the products
    # gain x planted exposure agree per channel to 1.5 %
    product = gains * np.array(exposure)
    assert np.all(np.abs(product / product.mean(axis=0) - 1) < 0.015), product
    # one gain per frame: the exposure is undone, the colour cast is not
    grey = exposure_gains(thumbs, Hs, 'gain')
    assert np.allclose(grey, grey[:, :1])
    assert abs(grey[1, 0] * 0.8 / (grey[0, 0] * 1.0) - 1) < 0.015
    assert np.all(exposure_gains(thumbs, Hs, 'none') == 1)


def test_a_frame_that_overlaps_none_and_frames_left_out_keep_gain_one() -> None:
    exposure = [np.array(e) for e in ([1, 1, 1], [0.7, 0.7, 0.7], [1.3, 1.3, 1.3])]
    thumbs, Hs = _frames(exposure)
    Hs[2] = Hs[2] @ np.array([[1.0, 0, 5000], [0, 1, 0], [0, 0, 1]])  # far from the others
    gains = exposure_gains(thumbs + [None], Hs + [None], 'channels')
    assert np.allclose(gains[2], 1.0, atol=1e-3) and np.all(gains[3] == 1.0)
    assert abs(gains[1, 0] * 0.7 / gains[0, 0] - 1) < 0.015
    assert np.all(exposure_gains(thumbs[:1], Hs[:1]) == 1.0)


def test_bad_arguments_are_refused() -> None:
    thumbs, Hs = _frames([np.ones(3)] * 2)
    with pytest.raises(ValueError, match='exposure mode'):
        exposure_gains(thumbs, Hs, 'auto')
    with pytest.raises(ValueError, match='2 thumbnails but 1'):
        exposure_gains(thumbs, Hs[:1])


def test_a_frame_whose_overlap_disagrees_does_not_bend_the_others() -> None:
    """Four frames in a row plus one over the first three with a truck the others do not see: the
    gains of the four stay as their exposures say."""
    exposure = [np.array(e) for e in ([1, 1, 1], [0.8, 0.8, 0.8], [1.0, 1.0, 1.0], [1.15, 1.15, 1.15])]
    thumbs, Hs = _frames(exposure)
    odd = (thumbs[1] / 0.8).astype(np.uint8)
    odd[:, :20] = 245  # a white truck over a third of its overlap with frame 0
    thumbs.append(odd)
    Hs.append(Hs[1].copy())
    gains = exposure_gains(thumbs, Hs, 'gain')[:4, 0]
    product = gains * np.array([e[0] for e in exposure])
    assert np.all(np.abs(product / product.mean() - 1) < 0.02), product
