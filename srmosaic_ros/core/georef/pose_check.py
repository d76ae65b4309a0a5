"""Whether the fused poses may place a mosaic whose camera attitude nobody measured.

Without an IMU orientation, gimbal angles or KLV sensor angles, the filter's camera orientation is
the configured mount (``georef.gimbal_*``, nadir by default) on a body held near level: an
assumption, not a measurement. Drift control then pulls every chained frame toward the footprint
that assumption predicts. When the footage is not what the mount says (a GoPro looking forward
at the horizon, an orbit looking at its centre), that footprint is wrong in shape, not only in
place, and the pull bends the mosaic frame after frame.

The evidence is what drift control already computes: for each frame, the normalised innovation
squared (NIS) nu^T S^-1 nu of the pose-predicted corners against the chained ones (drift.py),
chi-square with 8 degrees of freedom when the two agree. Measured over the first frames of the
first georeferenced segment (held unpainted while it settles): simulated nadir flights with GPS
only, median 1.8 to 2.1, no frame above 5; the GoPro Karma clip (a camera towards the horizon)
given intrinsics, median 324 to 349 over 29 frames; a simulated orbit 58 degrees below the
horizon, 171 over 5 frames; an oblique line 40 degrees below it, 160 over 6.

The rule: with no attitude measured, when the median NIS of at least ``MIN_INNOVATIONS`` frames
exceeds the filter's own chi-square gate (georef.gate_probability, 8 degrees of freedom: 37.3 at
the default 0.99999), the poses do not place the mosaic; it is chained in its first frame's plane
and georeferenced afterwards as a mosaic without intrinsics (by its geotags). A median, not a
count: a single bad registration does not decide. The UKF's own gate on the registrations is no
earlier witness: on karma it accepted all of the first 30 (the level-attitude prior, 5 degrees,
absorbs them at first) and refused most only after 50 frames, too late for the settling frames.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import chdtri

__all__ = ['MIN_INNOVATIONS', 'PoseCheck', 'check_pose_placement']

#: Fewest drift-control innovations that decide (fewer: the poses place the mosaic, as before).
MIN_INNOVATIONS = 4


@dataclass(frozen=True)
class PoseCheck:
    """The decision and its figures: ``used`` whether the poses place the mosaic; ``median_nis``
    over ``innovations`` frames against ``gate_nis`` (chi-square, 8 dof); ``mount`` the assumed
    camera mount (azimuth, elevation in degrees); ``reason`` one sentence when not used."""

    used: bool
    median_nis: float
    gate_nis: float
    innovations: int
    mount: tuple[float, float]
    reason: str = ''

    def as_dict(self) -> dict[str, Any]:
        """report.json's ``pose_placement``."""
        return {'used': self.used, 'attitude': 'not measured', 'median_nis': round(self.median_nis, 2),
                'gate_nis': round(self.gate_nis, 2), 'innovations': self.innovations,
                'mount_azimuth_deg': self.mount[0], 'mount_elevation_deg': self.mount[1],
                **({'reason': self.reason} if self.reason else {})}


def check_pose_placement(nis: Sequence[float], gate_probability: float,
                         mount: tuple[float, float]) -> PoseCheck | None:
    """The decision for a segment's first frames, from their drift-control NIS values (NaN: no
    pose update that frame, left out); None when fewer than MIN_INNOVATIONS are finite. Call it
    only when the camera attitude is not measured. ``mount``: (azimuth, elevation) in degrees."""
    values = np.asarray([v for v in nis if math.isfinite(v)], dtype=np.float64)
    if len(values) < MIN_INNOVATIONS:
        return None
    gate = float(chdtri(8, 1.0 - gate_probability))
    median = float(np.median(values))
    if median <= gate:
        return PoseCheck(True, median, gate, len(values), mount)
    reason = (f'no camera attitude was measured, so the filter assumed the mount (azimuth {mount[0]:g} deg, '
              f'elevation {mount[1]:g} deg: {"nadir" if mount[1] <= -89.9 else "oblique"}) on a level body, and the '
              f'frames disagree with the footprints that assumption predicts (median normalised innovation '
              f'{median:.0f} over {len(values)} frames, gate {gate:.1f}): the camera does not look the way '
              'the mount says')
    return PoseCheck(False, median, gate, len(values), mount, reason)
