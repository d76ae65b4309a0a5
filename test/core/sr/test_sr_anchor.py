"""The anchoring threshold (core/sr/anchor.py): white residuals are noise, correlated ones structure."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from srmosaic_ros.core.sr.anchor import RHO_STRUCTURE, neighbour_correlation, structure_threshold


def _t(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, np.float32))[None, None]


def test_white_noise_is_uncorrelated_and_compression_like_noise_is_not() -> None:
    rng = np.random.default_rng(4)
    white = rng.normal(0, 1, (64, 64)).astype(np.float32)
    smooth = cv2.GaussianBlur(white, (0, 0), 1.0)  # what a DCT quantiser leaves: low-frequency blotches
    ones = _t(np.ones((64, 64)))
    assert abs(neighbour_correlation(_t(white), ones)) < 0.05
    assert neighbour_correlation(_t(smooth), ones) > 0.5
    # pairs with an unobserved pixel do not count: a ramp where the mask is 0 changes nothing
    mask = np.ones((64, 64), np.float32)
    mask[:, 40:] = 0
    ramp = white.copy()
    ramp[:, 40:] = np.arange(24, dtype=np.float32) * 10
    assert neighbour_correlation(_t(ramp), _t(mask)) == pytest.approx(neighbour_correlation(_t(white[:, :40]),
                                                                                              _t(mask[:, :40])))
    assert neighbour_correlation(_t(white[:2, :2]), _t(np.ones((2, 2)))) == 0.0  # too few pairs


def test_the_threshold_falls_with_the_residuals_correlation() -> None:
    assert structure_threshold(2.0, 1.0, 0.8) == 2.0              # noise: the whole threshold
    assert structure_threshold(2.0, 1.0, 2.0) == pytest.approx(0.5)  # power 4x the noise: a quarter
    assert structure_threshold(2.0, 1.0, 0.8, rho=-0.2) == 2.0
    assert structure_threshold(2.0, 1.0, 0.8, rho=RHO_STRUCTURE / 2) == pytest.approx(1.0)
    assert structure_threshold(2.0, 1.0, 0.8, rho=RHO_STRUCTURE) == 0.0
    assert structure_threshold(2.0, 1.0, 2.0, rho=0.9) == 0.0
