"""core/mosaic/blend.py's OpenCV arithmetic gives the bytes of numpy's operators: multiband_blend
and feather_divide against the numpy formulas they replaced, for 1, 3 and 4 channels."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.mosaic.blend import (SEAM_NEAR, SEAM_RAMP, feather_divide, multiband_blend, seam_distance)


def _numpy_multiband(feather: np.ndarray, seam_image: np.ndarray, labels: np.ndarray, bands: int,
                     coarsest_by_seams: bool = False) -> np.ndarray:
    """The numpy formulation of multiband_blend (before its arithmetic moved to OpenCV)."""
    diff = (seam_image - feather).astype(np.float32, copy=False)
    if not diff.any():
        return feather.copy()
    dist = seam_distance(labels)

    def down(img: np.ndarray) -> np.ndarray:
        return cv2.pyrDown(img).reshape(((img.shape[0] + 1) // 2, (img.shape[1] + 1) // 2, *img.shape[2:]))

    def up(img: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        return cv2.pyrUp(img, dstsize=(shape[1], shape[0])).reshape(shape)

    def region_weight(lev: int, shape: tuple[int, ...]) -> np.ndarray:
        if np.isinf(dist).all():
            return np.ones(shape[:2], np.float32)
        d = dist if lev == 0 else cv2.resize(dist, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
        return np.clip((d / float(2**lev) - SEAM_NEAR) / SEAM_RAMP, 0.0, 1.0).astype(np.float32)

    gauss = [diff]
    for _ in range(bands):
        gauss.append(down(gauss[-1]))
    levels = len(gauss) - 1
    top = gauss[levels]
    acc = top * region_weight(levels, top.shape)[..., None] if coarsest_by_seams else None
    for lev in range(levels - 1, -1, -1):
        g = gauss[lev]
        band = (g - up(gauss[lev + 1], g.shape)) * region_weight(lev, g.shape)[..., None]
        acc = band if acc is None else band + up(acc, g.shape)
    return feather + acc


def _composites(channels: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    h, w = 173, 211
    labels = np.full((h, w), -1, np.int32)
    labels[10:160, 5:120] = 0
    labels[20:170, 100:200] = 1
    labels[60:100, 60:150] = 2
    seam = rng.random((h, w, channels), dtype=np.float32) * (labels >= 0)[..., None]
    feather = np.where((labels >= 0)[..., None], seam * np.float32(0.9) + np.float32(0.05), 0).astype(np.float32)
    wsum = np.where(labels >= 0, rng.random((h, w), dtype=np.float32) + np.float32(0.01), 0).astype(np.float32)
    acc = (feather * wsum[..., None]).astype(np.float32)
    return feather, seam, labels, acc, wsum


@pytest.mark.parametrize('channels', [1, 3, 4])
@pytest.mark.parametrize('coarsest_by_seams', [False, True])
def test_multiband_blend_gives_the_bytes_of_the_numpy_formula(channels: int, coarsest_by_seams: bool) -> None:
    feather, seam, labels, _, _ = _composites(channels, seed=channels)
    for bands in (1, 3, 5):
        got = multiband_blend(feather, seam, labels, bands, coarsest_by_seams=coarsest_by_seams)
        want = _numpy_multiband(feather, seam, labels, bands, coarsest_by_seams)
        assert got.dtype == np.float32 and got.shape == feather.shape
        assert np.array_equal(got, want), (bands, float(np.abs(got - want).max()))
        assert not np.array_equal(got, feather)  # the seams were blended (the test can tell)


@pytest.mark.parametrize('channels', [1, 3, 4])
def test_feather_divide_gives_the_bytes_of_numpy_and_keeps_uncovered_pixels(channels: int) -> None:
    _, _, labels, acc, wsum = _composites(channels, seed=10 + channels)
    out = np.full(acc.shape, 0.25, np.float32)
    covered = feather_divide(acc, wsum, out)
    want = np.full(acc.shape, 0.25, np.float32)
    np.divide(acc, wsum[..., None], out=want, where=(wsum > 0)[..., None])
    assert np.array_equal(covered, labels >= 0)
    assert np.array_equal(out, want)  # uncovered pixels kept (0.25), covered ones IEEE quotients
