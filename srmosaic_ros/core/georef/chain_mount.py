"""The camera mount a chain of frames shows, from its homographies alone (no attitude measured).

A camera translating over a plane sees it through homographies ``K_i^-1 H_i<-0 K_0 ~ R_i + t_i n^T``
(Hartley & Zisserman 13.1; the dissertation's 4.6 chain): ``n`` the plane's normal in the first
frame's camera axes over its distance, ``t_i`` the translation, ``R_i`` the rotation between the
two views. Each homography decomposes into up to four (R, t, n); two keep the plane in front of
both cameras, and only the true normal is the same in every frame of the chain, so the normal
that the frames agree on is the ground's, seen from the first camera. With the ground taken as
level and the body's nose along the travel (as the filter assumes when no attitude is measured),
the normal and the travel direction give the mount: the optical axis's elevation above the
horizon and its azimuth from the travel, counter-clockwise (frames.R_body_from_cam's angles).

Each decomposition comes with its mirror, ``(R, -t, -n)``: the same homography seen as a floor
approached or as a ceiling left behind. The ground lies in the lower part of an upright camera's
frame, so the one kept is the plane the bottom centre of the first frame looks at (the optical axis
itself misses it when the camera looks at or above the ground's horizon: karma.mp4, levelled at the
horizon, read as 2 deg below it and flying backwards by the axis).

Needs translation (a hovering or only rotating camera gives ``t ~ 0`` and no normal) and a wide
enough view (a zoomed camera sees an affine patch): None otherwise.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ['MAX_SPREAD_DEG', 'MIN_BASELINE', 'MIN_FRAMES', 'MIN_HFOV_DEG', 'MountEstimate', 'horizon_words',
           'mount_from_chain']

#: Smallest translation over the plane's distance (|t| / d) a frame needs to say where the normal is.
MIN_BASELINE = 0.08
#: Fewest frames with that baseline that decide (their normals must agree).
MIN_FRAMES = 3
#: Narrowest horizontal field of view that shows the ground's normal: the normal's tilt is seen in
#: how the translation's motion varies across the frame, ~tan(fov / 2); a zoomed camera (KLV's
#: aphill_short.ts, 0.8 deg) sees an affine patch and its homographies' projective terms are noise
#: (there the frames "showed" 0.6 deg below the horizon, its KLV says 37).
MIN_HFOV_DEG = 15.0
#: Largest median angle between the frames' normals and the one they agree on: more, and the
#: chain does not show one plane (aphill at 0.8 deg: 4.8 deg; simulated lines 0.03-0.17, karma 0.4).
MAX_SPREAD_DEG = 2.0


@dataclass(frozen=True)
class MountEstimate:
    """``elevation_deg`` of the optical axis above the horizon (-90 nadir; positive: the axis misses
    the ground, seen in the lower part of the frame only), ``azimuth_deg`` from the travel
    direction counter-clockwise (0 when within 1 deg of nadir), ``spread_deg`` the median angle
    between the frames' normals and theirs combined, over ``frames`` frames."""

    elevation_deg: float
    azimuth_deg: float
    spread_deg: float
    frames: int

    def line_of_sight(self) -> str:
        """'69 deg below the horizon, 7 deg from the direction of travel' (whole degrees)."""
        return f'{horizon_words(self.elevation_deg)}, {self.azimuth_deg:.0f} deg from the direction of travel'


def horizon_words(elevation_deg: float, decimals: int = 0) -> str:
    """'2 deg below the horizon' / '3 deg above the horizon' of an elevation in degrees."""
    return f'{abs(elevation_deg):.{decimals}f} deg {"below" if elevation_deg < 0 else "above"} the horizon'


def mount_from_chain(first_H_frames: Sequence[np.ndarray], Ks: Sequence[np.ndarray]) -> MountEstimate | None:
    """The mount of a chain: ``first_H_frames[i]`` (3, 3) maps frame i's pixels to the first
    frame's (``first_H_frames[0]`` the identity), ``Ks[i]`` (3, 3) frame i's intrinsics. None when
    fewer than MIN_FRAMES frames have moved MIN_BASELINE of the plane's distance from the first,
    the first frame is narrower than MIN_HFOV_DEG, or the frames' normals disagree (MAX_SPREAD_DEG)."""
    K0 = np.asarray(Ks[0], dtype=np.float64)
    w, h = 2.0 * K0[0, 2], 2.0 * K0[1, 2]
    if 2.0 * math.degrees(math.atan(w / 2.0 / K0[0, 0])) < MIN_HFOV_DEG:
        return None
    axis = np.linalg.inv(K0) @ np.array([w / 2.0, h / 2.0, 1.0])  # the first frame's centre ray
    bottom = np.linalg.inv(K0) @ np.array([w / 2.0, h, 1.0])  # its bottom centre's: an upright camera sees ground there
    candidates: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = []  # per frame: (normal, centre, R)
    for H, K in zip(first_H_frames[1:], Ks[1:], strict=True):
        G = np.linalg.inv(np.asarray(K, dtype=np.float64)) @ np.linalg.inv(np.asarray(H, dtype=np.float64)) @ K0
        kept = []
        for R, t, n in _decompose(G * np.sign((G @ axis)[2])):  # the centre's depth ratio > 0
            if np.linalg.norm(t) < MIN_BASELINE:
                continue
            # the plane n.X = 1 in front of the first camera below its frame's centre (the bottom
            # centre's ray meets it ahead; not every corner: an oblique camera's frame may reach past
            # the ground's horizon) and of frame i's (its normal R n at distance 1 + n.(R^T t) > 0)
            if n @ bottom > 0 and 1.0 + float(n @ (R.T @ t)) > 0:
                kept.append((n / np.linalg.norm(n), -R.T @ t, R))  # frame i's centre in the first camera's axes
        if kept:
            candidates.append(kept)
    if len(candidates) < MIN_FRAMES:
        return None
    chosen, spread = _agreed(candidates)
    if spread > MAX_SPREAD_DEG:
        return None
    normal = np.mean([n for n, _, _ in chosen], axis=0)
    normal /= np.linalg.norm(normal)
    up = -normal  # the plane lies along +n from the camera: up is -n
    # Each frame's own attitude against the level ground and its own travel (the chord through its
    # neighbours' centres: an orbit turns the course 17 deg in 3 s), taken into its axes by its
    # rotation from the first, R_i; their mean is the mount, the body's sway (gusts) averaging out.
    centres = [np.zeros(3)] + [c for _, c, _ in chosen]
    rotations = [np.eye(3)] + [R for _, _, R in chosen]
    elevations, azimuths = [], []
    for k, R in enumerate(rotations):
        travel = centres[min(k + 1, len(centres) - 1)] - centres[max(k - 1, 0)]
        fwd = travel - (travel @ up) * up
        if np.linalg.norm(fwd) < 1e-9:
            continue
        up_i, fwd_i = R @ up, R @ (fwd / np.linalg.norm(fwd))
        left_i = np.cross(up_i, fwd_i)
        elevations.append(math.asin(float(np.clip(up_i[2], -1.0, 1.0))))
        azimuths.append(complex(fwd_i[2], left_i[2]))
    if not elevations:
        return None
    elevation = math.degrees(float(np.mean(elevations)))
    azimuth = math.degrees(float(np.angle(np.mean(azimuths)))) if elevation > -89.0 else 0.0
    return MountEstimate(elevation, azimuth, spread, len(candidates))


def _decompose(G: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The four (R, t, n) with ``G / sigma_2(G) = R + t n^T`` (Ma, Soatto, Kosecka & Sastry, An
    Invitation to 3-D Vision, 5.3.3: from the SVD of G^T G). OpenCV's decomposeHomographyMat gives
    NaN for an exact translation (its minors vanish); this one is exact there. None (empty) when
    the homography is a rotation (no translation to tell the plane by)."""
    H = G / np.linalg.svd(G, compute_uv=False)[1]
    _, s2, Vt = np.linalg.svd(H.T @ H)
    V = Vt.T * np.sign(np.linalg.det(Vt))  # a rotation: the cross products below assume it
    if s2[0] - s2[2] < 1e-12:
        return []
    v1, v2, v3 = V[:, 0], V[:, 1], V[:, 2]
    a, b, c = math.sqrt(max(1.0 - s2[2], 0.0)), math.sqrt(max(s2[0] - 1.0, 0.0)), math.sqrt(s2[0] - s2[2])
    out = []
    for u in ((a * v1 + b * v3) / c, (a * v1 - b * v3) / c):
        U = np.column_stack([v2, u, np.cross(v2, u)])
        W = np.column_stack([H @ v2, H @ u, np.cross(H @ v2, H @ u)])
        R = W @ U.T
        n = np.cross(v2, u)
        t = (H - R) @ n
        out += [(R, t, n), (R, -t, -n)]
    return out


def _agreed(candidates: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]]
            ) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], float]:
    """Each frame's decomposition whose normal is nearest the one they agree on best (tried from
    every candidate: the median angle to the others' nearest), and that median angle (deg)."""
    best: tuple[float, list[int]] | None = None
    for frame in candidates:
        for seed, _, _ in frame:
            picks = [int(np.argmax([c[0] @ seed for c in other])) for other in candidates]
            score = float(np.median([_angle_deg(other[k][0], seed) for other, k in zip(candidates, picks, strict=True)]))
            if best is None or score < best[0]:
                best = (score, picks)
    assert best is not None
    return [other[k] for other, k in zip(candidates, best[1], strict=True)], best[0]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (deg) between unit vectors."""
    return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))
