"""The canvas's sampling rule (core/mosaic/resolution.py): the zoom of ``first`` and ``finest``, its caps,
and the frames' scale on the plane it is computed from."""
from __future__ import annotations

import math

import numpy as np
import pytest

from srmosaic_ros.core.mosaic.resolution import FINEST_QUANTILE, MAX_ZOOM, MIN_REFINEMENT, canvas_zoom, frame_scale, zoom_homography


def _zoom(mode: str, oversample: float, scales: list[float], *, area: float = 320 * 240.0, bound: int = 0) -> float:
    return canvas_zoom(mode, oversample, scales, first_area_px=area, tile_size=256, max_tiles_in_memory=bound)


def test_frame_scale_is_the_linear_scale_where_the_frame_is_finest() -> None:
    assert frame_scale(np.diag([2.0, 2.0, 1.0]), 320, 240) == pytest.approx(2.0)
    assert frame_scale(3.0 * np.diag([0.5, 0.5, 1.0]), 320, 240) == pytest.approx(0.5)  # any scale of m
    m = np.array([[1.1, 0.05, 3.0], [-0.02, 0.9, -7.0], [4e-4, -3e-4, 1.0]])

    def f(p: np.ndarray) -> np.ndarray:
        q = m @ np.r_[p, 1.0]
        return q[:2] / q[2]

    def scale_at(c: np.ndarray) -> float:
        e = 1e-4
        J = np.stack([(f(c + d) - f(c - d)) / (2 * e) for d in (np.array([e, 0.0]), np.array([0.0, e]))], axis=1)
        return math.sqrt(abs(np.linalg.det(J)))

    u, v = np.meshgrid(np.linspace(-0.5, 319.5, 33), np.linspace(-0.5, 239.5, 25))
    finest = min(scale_at(np.array([x, y])) for x, y in zip(u.ravel(), v.ravel()))
    assert frame_scale(m, 320, 240) == pytest.approx(finest, rel=1e-6)
    assert frame_scale(m, 320, 240) < scale_at(np.array([159.5, 119.5]))
    assert frame_scale(-2.0 * m, 320, 240) == pytest.approx(frame_scale(m, 320, 240))  # any scale and sign of m
    assert math.isnan(frame_scale(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 0]]), 320, 240))  # degenerate


def test_first_is_the_oversample_and_finest_follows_the_sharpest_frames() -> None:
    assert _zoom('first', 1.0, [1.0, 0.5, 0.4]) == 1.0
    assert _zoom('first', 1.5, [1.0, 0.5]) == 1.5
    # frames getting coarser (a climb, a zoom out): the first frame's sampling
    assert _zoom('finest', 1.0, [1.0, 1.2, 1.5, 2.0]) == 1.0
    scales = list(np.linspace(1.0, 0.5, 11))  # the frames get up to twice finer (a zoom in)
    z = _zoom('finest', 1.0, scales)
    assert z == pytest.approx(1.0 / np.quantile(scales, FINEST_QUANTILE))
    assert 1.8 < z < 2.0
    assert _zoom('finest', 1.5, scales) == pytest.approx(1.5 * z)
    # relative to the first frame's own scale on the plane (mosaic.max_width scales it below 1)
    assert _zoom('finest', 1.0, [0.5 * s for s in scales]) == pytest.approx(z)
    assert _zoom('finest', 1.0, [1.0, math.nan, 0.5, 0.5]) == pytest.approx(2.0)  # a degenerate placement ignored
    # a steady flight: the frames' scale wanders a little, the first frame's sampling stays
    assert _zoom('finest', 1.0, [1.0, 0.97, 1.02, 0.95]) == 1.0
    assert _zoom('finest', 1.0, [1.0] + [1.0 / (MIN_REFINEMENT + 0.01)] * 9) == pytest.approx(MIN_REFINEMENT + 0.01)


def test_the_zoom_is_capped_by_max_zoom_and_by_the_tiles_in_memory() -> None:
    assert _zoom('finest', 2.0, [1.0, 0.1, 0.1]) == MAX_ZOOM
    # bound 64 tiles of 256 px: a frame may cover a quarter, 16 tiles: (16 * 256^2 / (320 * 240))^0.5 = 3.7
    assert _zoom('finest', 1.0, [1.0, 0.25, 0.25], bound=64) == pytest.approx(math.sqrt(16 * 256**2 / (320 * 240)))
    assert _zoom('first', 3.0, [], area=4000 * 3000.0, bound=64) == 1.0  # never coarser than the plane
    with pytest.raises(ValueError, match='mosaic.resolution'):
        _zoom('best', 1.0, [1.0])
    with pytest.raises(ValueError, match='mosaic.oversample'):
        _zoom('first', 0.5, [1.0])
    np.testing.assert_array_equal(zoom_homography(1.5), np.diag([1.5, 1.5, 1.0]))
