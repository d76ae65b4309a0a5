"""Helpers of the SR tests: the ground of the synthetic tiles and how they are scored."""
from __future__ import annotations

import numpy as np
import torch

from imagery import world_rgb


def world01() -> np.ndarray:
    """(H, W, 3) float32 in [0, 1]: the synthetic ground the tiles are cut from."""
    return world_rgb().astype(np.float32) / 255.0


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two images in [0, 1]."""
    return float(10 * np.log10(1.0 / np.mean((a.astype(np.float64) - b) ** 2)))


def hwc(t: torch.Tensor) -> np.ndarray:
    """(C, H, W) tensor -> (H, W, C) numpy."""
    return t.detach().cpu().permute(1, 2, 0).numpy()
