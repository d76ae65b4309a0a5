"""The survey solve's data and its homography parametrisation.

A frame's ground homography G (normalised image coordinates -> ground metres, east and north) is
solved as its eight free entries h = (g00, g01, g02, g10, g11, g12, g20, g21), g22 = 1 (:func:`h8`,
:func:`h8_matrix`); :func:`apply_h8` maps points through many of them at once and
:func:`point_jacobian` gives the derivatives the solve needs. The dataclasses are what the solve
takes (pairs, priors, ground control) and gives (:class:`SurveySolution`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['apply_h8', 'attitude_ground_H', 'control_residuals', 'FLIP', 'GroundControl', 'h8', 'h8_matrix',
           'h8_scale', 'h8_scale_jacobian', 'PairConstraint', 'point_jacobian', 'SHAPE_POINTS', 'SurveyPriors',
           'SurveySolution']


FLIP = np.diag([1.0, -1.0, 1.0])


@dataclass(frozen=True)
class PairConstraint:
    """One registered pair: i_H_j maps frame j's normalised coordinates to frame i's; points_j (M, 2)
    normalised coordinates of frame j inside the overlap; sigma (M,) sd of each transferred point,
    normalised units; inliers of the registration."""

    i: int
    j: int
    i_H_j: np.ndarray
    points_j: np.ndarray
    sigma: np.ndarray
    inliers: int = 0


@dataclass(frozen=True)
class SurveyPriors:
    """What the metadata says. position_m (N, 2): ground point of each frame's principal ray,
    metres east/north on the survey's plane (NaN: unknown); position_sigma_m (N,); scale_m: the
    frames' nominal scale (height above ground for a nadir camera, metres per normalised unit);
    track_rad (N,): direction of flight at each frame, counter-clockwise from east (NaN: unknown);
    shape: frame -> (ground_H_frame (3, 3) its attitude and height predict, sd in metres of the
    predicted corner offsets from the centre): where the camera's attitude is known (gimbal angles),
    the footprint's turn, scale and tilt are known to about that (see attitude_ground_H)."""

    position_m: np.ndarray
    position_sigma_m: np.ndarray
    scale_m: float
    track_rad: np.ndarray | None = None
    shape: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)
    shape_sigma: float = 0.05
    perspective_sigma: float = 0.2
    scale_rel_sigma: float = 0.25


@dataclass(frozen=True)
class GroundControl:
    """Observations of surveyed targets. frame (M,) int: the frame each is seen in; point_n (M, 2):
    where, in that frame's normalised coordinates; ground_m (M, 2): the target's surveyed position,
    metres east and north on the survey's plane; sigma_n (M,): sd of the pick, normalised units
    (pixels over the focal length); target (M,): target names; use (M,) bool: the observations that
    constrain the solve (the others, check points and contradicting picks, only get residuals);
    sigma_ground_m: sd of the surveyed positions."""

    frame: np.ndarray
    point_n: np.ndarray
    ground_m: np.ndarray
    sigma_n: np.ndarray
    target: tuple[str, ...]
    use: np.ndarray
    sigma_ground_m: float = 0.02


@dataclass
class SurveySolution:
    """ground_H_frame (N, 3, 3): normalised frame coordinates -> ground metres (NaN: not placed);
    placed_by (N,): 'registration', 'pose' or ''; pair_rms_sigma (P,): RMS residual of each pair
    in its standard deviations; pair_used (P,) bool; figures: counts and residuals for the report;
    control_used (M,) bool: the ground control observations the final solve kept (None: no control)."""

    ground_H_frame: np.ndarray
    placed_by: list[str]
    pair_rms_sigma: np.ndarray
    pair_used: np.ndarray
    figures: dict = field(default_factory=dict)
    control_used: np.ndarray | None = None


def control_residuals(ground_H_frame: np.ndarray, control: GroundControl) -> np.ndarray:
    """(M, 2) G_k(x) - X of every control observation, metres east and north (NaN where frame k
    is not placed)."""
    out = np.full((len(control.frame), 2), np.nan)
    for m, (k, x) in enumerate(zip(control.frame, control.point_n)):
        G = ground_H_frame[int(k)]
        if np.all(np.isfinite(G)):
            q = G @ np.array([x[0], x[1], 1.0])
            out[m] = q[:2] / q[2] - control.ground_m[m]
    return out


def apply_h8(h: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(E, N, den) of homographies h (P, 8) applied to points pts (P, 2)."""
    x, y = pts[:, 0], pts[:, 1]
    den = h[:, 6] * x + h[:, 7] * y + 1.0
    e = (h[:, 0] * x + h[:, 1] * y + h[:, 2]) / den
    n = (h[:, 3] * x + h[:, 4] * y + h[:, 5]) / den
    return e, n, den


def point_jacobian(h: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d(E)/dh and d(N)/dh, each (P, 8)."""
    x, y = pts[:, 0], pts[:, 1]
    e, n, den = apply_h8(h, pts)
    z = np.zeros_like(x)
    je = np.stack([x, y, np.ones_like(x), z, z, z, -e * x, -e * y], axis=1) / den[:, None]
    jn = np.stack([z, z, z, x, y, np.ones_like(x), -n * x, -n * y], axis=1) / den[:, None]
    return je, jn


def h8_scale(h: np.ndarray) -> np.ndarray:
    """(P,) sqrt|det| of the linear parts of homographies h (P, 8): metres per normalised unit."""
    return np.sqrt(np.maximum(np.abs(h[:, 0] * h[:, 4] - h[:, 1] * h[:, 3]), 1e-12))


def h8_scale_jacobian(h: np.ndarray) -> np.ndarray:
    """(P, 8) derivative of h8_scale."""
    det = h[:, 0] * h[:, 4] - h[:, 1] * h[:, 3]
    g = np.sign(det) / (2.0 * h8_scale(h))
    out = np.zeros((len(h), 8))
    out[:, 0], out[:, 4], out[:, 1], out[:, 3] = g * h[:, 4], g * h[:, 0], -g * h[:, 3], -g * h[:, 1]
    return out


SHAPE_POINTS = np.array([[-0.5, -0.4], [0.5, -0.4], [0.5, 0.4], [-0.5, 0.4]])


def attitude_ground_H(R_enu_from_cam: np.ndarray, centre_m: np.ndarray, height_m: float) -> np.ndarray:
    """(3, 3) ground_H_frame of a camera (normalised coordinates -> ground metres) whose optical centre
    is ``height_m`` above the flat ground and whose principal ray meets it at ``centre_m`` (east,
    north), looking along R_enu_from_cam's z axis (eqs. 4.23-4.29 for a single pose). A ray
    d = R (x, y, 1) from C meets the ground at C_xy - C_z d_xy / d_z, i.e. the homography rows
    (C_xy R_2 - C_z R_01) over R_2, normalised to g22 = 1."""
    R = np.asarray(R_enu_from_cam, dtype=np.float64)
    axis = R[:, 2]
    C = np.array([centre_m[0] + height_m * axis[0] / axis[2], centre_m[1] + height_m * axis[1] / axis[2], height_m])
    G = np.vstack([C[0] * R[2] - C[2] * R[0], C[1] * R[2] - C[2] * R[1], R[2]])
    return G / G[2, 2]


def h8(H: np.ndarray) -> np.ndarray:
    H = H / H[2, 2]
    return H.ravel()[:8].copy()


def h8_matrix(h: np.ndarray) -> np.ndarray:
    return np.append(h, 1.0).reshape(3, 3)
