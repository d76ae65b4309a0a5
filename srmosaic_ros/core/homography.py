"""Points through a plane homography: the one implementation the package uses.

Convention: H (3, 3) maps homogeneous (x, y, 1) to (x', y', w'); the image of (x, y) is
(x' / w', y' / w'). Points are float64 arrays of shape (..., 2).
"""
from __future__ import annotations

import numpy as np

__all__ = ['apply_homography', 'corner_depth_ratio', 'corner_depths', 'corner_shift_px', 'h8_jacobian', 'homography_power',
           'project_points', 'translation']


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


def corner_depths(H: np.ndarray, width: int, height: int) -> np.ndarray:
    """(4,) homogeneous w of the outer corners of a width x height frame (pixel edges at -0.5 and
    size - 0.5) under H: how deep each corner lies in the plane H maps into."""
    u = np.array([[-0.5, -0.5, 1.0], [width - 0.5, -0.5, 1.0], [width - 0.5, height - 0.5, 1.0],
                  [-0.5, height - 0.5, 1.0]])
    return u @ np.asarray(H, dtype=np.float64)[2]


def corner_depth_ratio(H: np.ndarray, width: int, height: int) -> float:
    """The frame's farthest corner depth over its nearest under H (corner_depths; the sign of H does
    not matter): 1 for a frame parallel to the target plane, growing with the angle between them;
    inf when a corner lies on or past the plane's horizon."""
    depth = corner_depths(H, width, height)
    depth = depth * np.sign(depth[np.argmax(np.abs(depth))])
    return float(depth.max() / depth.min()) if depth.min() > 0 else float('inf')


#: (row, column) of the 8 free entries h00..h21 of a homography with h22 = 1
_ROWS, _COLS = np.divmod(np.arange(8), 3)


def h8_jacobian(A: np.ndarray, B: np.ndarray, F0: np.ndarray) -> np.ndarray:
    """(8, 8) Jacobian d h8(F) / d p of a homography F(p) whose derivative along parameter k is
    A E_k B (A, B (3, 3); E_k the unit matrix of entry k of h00..h21), at F(0) = F0, with
    h8(F) = the first 8 entries of F / F[2, 2]. Exact (no finite differences):
    d(F / F22) = dF / F22 - F dF22 / F22^2.
    E.g. F = t X(h) t^-1: A = t, B = t^-1; F = X(h)^-1: A = -X^-1, B = X^-1."""
    dF = A[:, _ROWS].T[:, :, None] * B[_COLS, :][:, None, :]                        # (8, 3, 3)
    f22 = F0[2, 2]
    dN = dF / f22 - F0[None] * (dF[:, 2, 2] / f22**2)[:, None, None]
    return dN.reshape(8, 9)[:, :8].T


def translation(dx: float, dy: float) -> np.ndarray:
    """(3, 3) homography of a shift by (dx, dy) px."""
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def homography_power(H: np.ndarray, r: float) -> np.ndarray | None:
    """H**r (3, 3), scaled to [2, 2] = 1: the motion H continued at its own rate over r times its
    interval (H = expm(A) up to scale, H**r = expm(r A); r = 2 is H @ H). None when H has no real
    logarithm (det <= 0: a reflection; a half turn)."""
    H = np.asarray(H, dtype=np.float64)
    det = float(np.linalg.det(H))
    if not np.isfinite(det) or det <= 0.0:
        return None
    M = H / np.cbrt(det)  # det 1: the scale H is defined up to is left out of the log
    # In units where the shift is at most 1/8 (a similarity: (S M S^-1)**r = S M**r S^-1), a video
    # pair's motion is close to the identity and the log and exp series converge in a few terms
    # (scipy's logm takes about a millisecond of Python for a 3 x 3).
    s = max(1.0, 8.0 * float(np.abs(M[:2, 2]).max()))
    M = M.copy()
    M[:2, 2] /= s
    M[2, :2] *= s
    log = _log_near_identity(M)
    if log is None:
        from scipy.linalg import logm

        log = logm(M)
        if np.iscomplexobj(log):
            if float(np.abs(log.imag).max()) > 1e-9:
                return None
            log = log.real
    out = _exp(float(r) * log)
    out[:2, 2] *= s
    out[2, :2] /= s
    return out / out[2, 2] if np.all(np.isfinite(out)) and abs(out[2, 2]) > 1e-12 else None


def _log_near_identity(M: np.ndarray) -> np.ndarray | None:
    """log(M) by its series sum (-1)^(k+1) X^k / k, X = M - I, when |X| < 0.5 (else None)."""
    X = M - np.eye(3)
    if float(np.linalg.norm(X)) >= 0.5:
        return None
    out, power = X.copy(), X
    for k in range(2, 80):
        power = power @ X
        term = power / k
        out = out - term if k % 2 == 0 else out + term
        if float(np.abs(term).max()) < 1e-17:
            break
    return out


def _exp(L: np.ndarray) -> np.ndarray:
    """expm(L) by its Taylor series when |L| < 1, else scipy's."""
    if float(np.linalg.norm(L)) >= 1.0:
        from scipy.linalg import expm

        return expm(L)
    out, term = np.eye(3) + L, L
    for k in range(2, 40):
        term = term @ L / k
        out = out + term
        if float(np.abs(term).max()) < 1e-17:
            break
    return out
