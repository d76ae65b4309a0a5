"""Candidate pairs of a stills survey from the frames' predicted footprints on the ground.

A survey's overlaps are not only between consecutive stills: the next flight line runs beside
the last one, in the other direction, and a turn ends a chain. Every pair whose predicted
footprints overlap by at least ``min_overlap`` is a candidate; consecutive stills are always
candidates (they are where the GPS-free chain lives).

Footprints are predicted from each still's ground position (GPS, in metres on a local plane) and
its footprint's size on the ground (width x height in metres, from the height above the ground
and the intrinsics). The camera's heading is often unknown (no gimbal angles), so a footprint is
taken as the disc of the same area: the overlap fraction of two discs of radius r whose centres
are d apart is the lens area over the disc area,
    f(d) = (2 r^2 acos(d / 2r) - (d / 2) sqrt(4 r^2 - d^2)) / (pi r^2),  0 <= d <= 2r.
A k-d tree (scipy.spatial.cKDTree) finds the pairs within 2r, so the cost grows with the pairs,
not with the square of the frames.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

__all__ = ['disc_overlap', 'predicted_pairs']


def disc_overlap(distance_m: np.ndarray | float, radius_m: np.ndarray | float) -> np.ndarray:
    """Overlap fraction (0..1) of two discs of radius ``radius_m`` whose centres are ``distance_m``
    apart (the lens area over one disc's area)."""
    d = np.asarray(distance_m, dtype=np.float64)
    r = np.broadcast_to(np.asarray(radius_m, dtype=np.float64), d.shape)
    x = np.clip(d / np.maximum(2.0 * r, 1e-12), 0.0, 1.0)
    lens = 2.0 * r**2 * np.arccos(x) - 0.5 * d * np.sqrt(np.maximum(4.0 * r**2 - d**2, 0.0))
    return np.where(x >= 1.0, 0.0, lens / (math.pi * np.maximum(r, 1e-12) ** 2))


def predicted_pairs(centres_m: np.ndarray, footprint_wh_m: np.ndarray, *, min_overlap: float = 0.2,
                    max_per_frame: int = 0, consecutive: bool = True) -> list[tuple[int, int, float]]:
    """Candidate pairs (i, j, predicted overlap) with i < j, sorted by (j, i).

    Args:
        centres_m: (N, 2) ground position (east, north) of each frame's footprint centre, metres;
            rows with NaN (no position) take part only as consecutive pairs.
        footprint_wh_m: (N, 2) footprint width and height on the ground, metres (NaN: unknown).
        min_overlap: smallest predicted overlap fraction of a pair (0..1).
        max_per_frame: keep a pair only when it is among the ``max_per_frame`` largest predicted
            overlaps of one of its frames (0: all). A small survey seen from high up overlaps
            every frame with dozens; the nearest few hold it together as well, at a fraction of
            the registrations.
        consecutive: also every (i, i + 1), whatever its predicted overlap (NaN when unknown).
    """
    centres = np.asarray(centres_m, dtype=np.float64).reshape(-1, 2)
    wh = np.asarray(footprint_wh_m, dtype=np.float64).reshape(-1, 2)
    if len(centres) != len(wh):
        msg = f'predicted_pairs: {len(centres)} centres but {len(wh)} footprint sizes.'
        raise ValueError(msg)
    if not 0.0 <= min_overlap < 1.0:
        msg = f'min_overlap must be in [0, 1), got {min_overlap!r}.'
        raise ValueError(msg)
    radius = np.sqrt(np.prod(wh, axis=1) / math.pi)  # the disc of the footprint's area
    known = np.flatnonzero(np.all(np.isfinite(centres), axis=1) & np.isfinite(radius) & (radius > 0))
    pairs: dict[tuple[int, int], float] = {}
    if len(known) >= 2:
        tree = cKDTree(centres[known])
        for a, b in tree.query_pairs(r=2.0 * float(radius[known].max()), output_type='ndarray'):
            i, j = sorted((int(known[a]), int(known[b])))
            d = float(np.hypot(*(centres[i] - centres[j])))
            f = float(disc_overlap(d, 0.5 * (radius[i] + radius[j])))
            if f >= min_overlap:
                pairs[(i, j)] = f
    if max_per_frame > 0 and pairs:
        best: dict[int, list[tuple[float, tuple[int, int]]]] = {}
        for key, f in pairs.items():
            for k in key:
                best.setdefault(k, []).append((f, key))
        keep = set()
        for cands in best.values():
            keep.update(key for _, key in sorted(cands, reverse=True)[:max_per_frame])
        pairs = {key: f for key, f in pairs.items() if key in keep}
    if consecutive:
        for i in range(len(centres) - 1):
            if (i, i + 1) not in pairs:
                ok = np.all(np.isfinite(centres[[i, i + 1]])) and np.isfinite(radius[[i, i + 1]]).all()
                d = float(np.hypot(*(centres[i] - centres[i + 1]))) if ok else float('nan')
                pairs[(i, i + 1)] = float(disc_overlap(d, 0.5 * (radius[i] + radius[i + 1]))) if ok else float('nan')
    return sorted(((i, j, f) for (i, j), f in pairs.items()), key=lambda p: (p[1], p[0]))
