"""Offline re-anchoring of a georeferenced mosaic on the smoothed poses of all its frames.

Live, the mosaic plane is anchored by the first frame's pose and held by drift control; the
chain itself is far more precise than any single pose (consecutive frames agree to hundredths of a
pixel, while an attitude error of 0.5 degree moves the footprint by ~0.9 m at 100 m). What remains in the
mosaic is therefore mostly a similarity of the whole: an offset, a small rotation (the first
yaw's error) and a scale (the first height above ground's error). With every frame's smoothed
pose, the least-squares similarity between the chained frame corners and the pose-predicted
corners estimates it from the whole flight, and the raster's geotransform absorbs it (the
mosaic's pixels do not move; mosaic.png and mosaic.tif stay one grid).
"""
from __future__ import annotations

import numpy as np

__all__ = ['fit_similarity']


def fit_similarity(src: np.ndarray, dst: np.ndarray, *, rotation_and_scale: bool = True,
                   from_a_line: bool = False) -> np.ndarray:
    """(3, 3) least-squares similarity S (scale, rotation, translation; no reflection) with
    dst ~ S @ src, for point sets src, dst (N, 2) (Umeyama 1991, eq. 40-42); translation only
    when rotation_and_scale is False or the points do not span two dimensions, unless
    ``from_a_line``: then points on one line give the rotation and scale too (without reflection
    the line's direction fixes the rotation), and only coincident points a translation."""
    src = np.asarray(src, dtype=np.float64).reshape(-1, 2)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 2)
    if len(src) != len(dst) or len(src) == 0:
        msg = f'fit_similarity needs two non-empty point sets of the same size, got {len(src)} and {len(dst)}.'
        raise ValueError(msg)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float((xs ** 2).sum()) / len(src)
    out = np.eye(3)
    sv = np.linalg.svd(xs, compute_uv=False) if len(src) >= 2 else np.zeros(2)
    flat = sv[0] <= 1e-9 if from_a_line else sv[-1] <= 1e-9 * max(sv[0], 1.0)
    if not rotation_and_scale or len(src) < (2 if from_a_line else 3) or flat:
        out[:2, 2] = mu_d - mu_s
        return out
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.diag([1.0, np.sign(np.linalg.det(u) * np.linalg.det(vt)) or 1.0])
    r = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign)) / var_s
    out[:2, :2] = scale * r
    out[:2, 2] = mu_d - scale * r @ mu_s
    return out
