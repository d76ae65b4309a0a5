"""Points through a plane homography: the one implementation the package uses.

Convention: H (3, 3) maps homogeneous (x, y, 1) to (x', y', w'); the image of (x, y) is
(x' / w', y' / w'). Points are float64 arrays of shape (..., 2).
"""
from __future__ import annotations

import numpy as np

__all__ = ['apply_homography', 'corner_shift_px', 'project_points', 'translation']


def project_points(H: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((..., 2) mapped points, (...,) homogeneous w) of points (..., 2); w <= 0 means the point
    maps through the horizon (behind the camera, for a ground homography)."""
    H = np.asarray(H, dtype=np.float64)
    hom = np.asarray(pts, dtype=np.float64) @ H[:, :2].T + H[:, 2]
    return hom[..., :2] / hom[..., 2:3], hom[..., 2]


def apply_homography(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (..., 2) mapped by the homography H (3, 3); returns (..., 2) float64."""
    return project_points(H, pts)[0]


def corner_shift_px(a: np.ndarray, b: np.ndarray, width: int, height: int) -> float:
    """Largest distance (px, in the plane both map into) between the corners of a width x height
    frame (pixel centres at integers) under the homographies a and b (3, 3)."""
    c = np.array([[0.0, 0.0], [width - 1.0, 0.0], [width - 1.0, height - 1.0], [0.0, height - 1.0]])
    return float(np.linalg.norm(apply_homography(a, c) - apply_homography(b, c), axis=1).max())


def translation(dx: float, dy: float) -> np.ndarray:
    """(3, 3) homography of a shift by (dx, dy) px."""
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])
