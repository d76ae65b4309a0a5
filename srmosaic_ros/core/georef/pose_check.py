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

The NIS misses a tilt the chain can absorb: a straight line 70 deg below the horizon passed it
(median 36.1) and was placed 15 px off in the mosaic, 9 m on the map. The chain itself says how
the camera looks (chain_mount.py: the ground's normal from the frames' homographies, within 1.5
deg on simulated lines), so that is compared with the mount too.

The rule: with no attitude measured, when the median NIS of at least ``MIN_INNOVATIONS`` frames
exceeds the filter's own chi-square gate (georef.gate_probability, 8 degrees of freedom: 37.3 at
the default 0.99999), or the optical axis the frames show is more than ``MOUNT_TOLERANCE_DEG``
from the mount's, the poses do not place the mosaic; it is chained in its first frame's plane
and georeferenced afterwards as a mosaic without intrinsics (by its geotags). A median, not a
count: a single bad registration does not decide. The UKF's own gate on the registrations is no
earlier witness: on karma it accepted all of the first 30 (the level-attitude prior, 5 degrees,
absorbs them at first) and refused most only after 50 frames, too late for the settling frames.

With a measured camera attitude nothing is decided, but the elevation the frames show is compared
with the measured one (:func:`check_measured_attitude`): a gimbal angle read in another convention
than its carrier's (relative to the body, a sign) is said, not silently placed.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import chdtri

from .chain_mount import MountEstimate
from .frames import R_body_from_cam

__all__ = ['MAX_SPREAD_TO_TRY_DEG', 'MIN_DEPRESSION_DEG', 'MIN_INNOVATIONS', 'MOUNT_TOLERANCE_DEG', 'PoseCheck',
           'check_measured_attitude', 'check_pose_placement', 'mount_axis_angle_deg']

#: Fewest drift-control innovations that decide (fewer: the poses place the mosaic, as before).
MIN_INNOVATIONS = 4
#: Largest angle between the optical axis the frames show and the mount's that passes. Simulated
#: lines flown with the nadir mount assumed, the camera 5 / 8 / 10 / 12 / 15 / 20 deg off nadir:
#: 0.40 / 0.70 / 1.34 / 2.55 / 6.05 / 14.9 px, 0.58 / 0.75 / 1.02 / 1.64 / 3.57 / 9.4 m; with the
#: frames' mount 0.3-0.5 px, 1.1-1.8 m. From 12 deg both gain; below, the map would not, and a
#: survey camera over sloping ground shows a few degrees (the caliterra stills, 68.9 deg HFOV: 7-10).
MOUNT_TOLERANCE_DEG = 12.0
#: The highest frame corner must look this far below the horizon through a mount the run may switch
#: to: the filter's footprints, on level ground, then reach at most ~6 heights away.
MIN_DEPRESSION_DEG = 10.0
#: Largest spread of the frames' normals (chain_mount.py) whose mount a run may switch to. A
#: refusal needs less (the chain showing a clearly oblique camera is evidence even when rough),
#: a mount to fly needs a plane the frames agree on: simulated lines 0.03-0.2 deg, corners 0.2 px
#: off per homography 0.3-0.4; over buildings (40 boxes up to 20 m under 80 m, camera 60 deg below
#: the horizon) 0.55-1.45, the elevation shown 35 or 20 deg where it was 60 or 70.
MAX_SPREAD_TO_TRY_DEG = 0.5


@dataclass(frozen=True)
class PoseCheck:
    """The decision and its figures: ``used`` whether the poses place the mosaic; ``median_nis``
    over ``innovations`` frames against ``gate_nis`` (chi-square, 8 dof); ``mount`` the assumed
    camera mount (azimuth, elevation in degrees); ``frames_mount`` the mount the frames show
    (chain_mount.py; None when they cannot tell); ``reason`` one sentence when not used."""

    used: bool
    median_nis: float
    gate_nis: float
    innovations: int
    mount: tuple[float, float]
    reason: str = ''
    frames_mount: MountEstimate | None = None
    mount_to_try: tuple[float, float] | None = None  # when refused: the frames' mount, if the filter can use it

    def as_dict(self) -> dict[str, Any]:
        """report.json's ``pose_placement``."""
        shown = self.frames_mount
        return {'used': self.used, 'attitude': 'not measured', 'median_nis': round(self.median_nis, 2),
                'gate_nis': round(self.gate_nis, 2), 'innovations': self.innovations,
                'mount_azimuth_deg': self.mount[0], 'mount_elevation_deg': self.mount[1],
                **({'frames_mount': {'azimuth_deg': round(shown.azimuth_deg, 1),
                                    'elevation_deg': round(shown.elevation_deg, 1),
                                    'spread_deg': round(shown.spread_deg, 2), 'frames': shown.frames}}
                   if shown is not None else {}),
                **({'reason': self.reason} if self.reason else {})}

    def operator_note(self) -> str:
        """One sentence for a live operator when refused ('' when used): the frames are off the map,
        and the mount to set when the frames show one."""
        if self.used:
            return ''
        shown = self.frames_mount
        if shown is None or self.mount_to_try is None:
            return ('frames not placed on the map: they disagree with the assumed camera mount; give the camera '
                    'attitude (an Imu orientation, gimbal angles) or its mount (georef.gimbal_elevation_deg, '
                    'georef.gimbal_azimuth_deg)')
        return (f'frames not placed on the map: they show the camera {shown.line_of_sight()}, not as the mount '
                'says; restart with '
                f'georef.gimbal_elevation_deg: {self.mount_to_try[1]:g}, georef.gimbal_azimuth_deg: '
                f'{self.mount_to_try[0]:g} (or give the camera attitude)')

    def with_mount_to_try(self, K: np.ndarray) -> PoseCheck:
        """This refusal with ``mount_to_try`` set to the mount the frames show, (azimuth, elevation)
        rounded to 0.1 deg, when their normals agree (MAX_SPREAD_TO_TRY_DEG), it differs from the
        assumed one, and every corner of a frame of intrinsics ``K`` (3, 3) looks at least
        MIN_DEPRESSION_DEG below the horizon through it (the filter's level-ground footprint stays
        bounded); else unchanged."""
        shown = self.frames_mount
        if self.used or shown is None or shown.spread_deg > MAX_SPREAD_TO_TRY_DEG:
            return self
        mount = (round(shown.azimuth_deg, 1), round(shown.elevation_deg, 1))
        if mount_axis_angle_deg(mount, self.mount) <= MOUNT_TOLERANCE_DEG:
            return self
        w, h = 2.0 * K[0, 2], 2.0 * K[1, 2]
        rays = R_body_from_cam(math.radians(mount[0]), math.radians(mount[1])) @ np.linalg.inv(K) @ np.array(
            [[0, w, w, 0], [0, 0, h, h], [1, 1, 1, 1]], dtype=np.float64)
        highest = math.degrees(math.asin(float(np.max(rays[2] / np.linalg.norm(rays, axis=0)))))
        return dataclasses.replace(self, mount_to_try=mount) if highest <= -MIN_DEPRESSION_DEG else self


def check_pose_placement(nis: Sequence[float], gate_probability: float, mount: tuple[float, float],
                         frames_mount: MountEstimate | None = None, attitudes_at_horizon: int = 0) -> PoseCheck | None:
    """The decision for a segment's first frames, from their drift-control NIS values (NaN: no
    pose update that frame, left out) and the mount their chain shows (None: not known); None
    when fewer than MIN_INNOVATIONS NIS values are finite. Call it only when the camera attitude
    is not measured, or only at the horizon (``attitudes_at_horizon`` of them, which the filter
    leaves out). ``mount``: (azimuth, elevation) in degrees."""
    values = np.asarray([v for v in nis if math.isfinite(v)], dtype=np.float64)
    if len(values) < MIN_INNOVATIONS:
        return None
    gate = float(chdtri(8, 1.0 - gate_probability))
    median = float(np.median(values))
    off = None if frames_mount is None else mount_axis_angle_deg(
        mount, (frames_mount.azimuth_deg, frames_mount.elevation_deg))
    if median <= gate and (off is None or off <= MOUNT_TOLERANCE_DEG):
        return PoseCheck(True, median, gate, len(values), mount, frames_mount=frames_mount)
    measured = ('no camera attitude the filter can use was measured (only attitudes at the horizon)'
                if attitudes_at_horizon else 'no camera attitude was measured')
    assumed = (f'{measured}, so the filter assumed the mount (azimuth {mount[0]:g} deg, '
               f'elevation {mount[1]:g} deg: {"nadir" if mount[1] <= -89.9 else "oblique"}) on a level body')
    shown = '' if frames_mount is None else (
        f'; the frames show the camera looking {frames_mount.line_of_sight()} ({off:.0f} deg from the mount)')
    nis = f'median normalised innovation {median:.0f} over {len(values)} frames, gate {gate:.1f}'
    if median > gate and off is not None and off <= MOUNT_TOLERANCE_DEG:
        reason = (f'{assumed}{shown}, but they disagree with the footprints the filter predicts through it ({nis}): '
                  'without a measured attitude its heading (from the course over ground and the homographies) or '
                  'its position does not follow the frames; the attitude itself (an Imu orientation, gimbal angles) '
                  'would place them')
    elif median > gate:
        reason = (f'{assumed}, and the frames disagree with the footprints that assumption predicts ({nis}){shown}: '
                  'the camera does not look the way the mount says')
    else:
        reason = f'{assumed}{shown}: the camera does not look the way the mount says'
    return PoseCheck(False, median, gate, len(values), mount, reason, frames_mount)


def mount_axis_angle_deg(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Angle (deg) between the optical axes of two mounts, each (azimuth, elevation) in degrees."""
    axes = [R_body_from_cam(math.radians(az), math.radians(el))[:, 2] for az, el in (a, b)]
    return math.degrees(math.acos(float(np.clip(axes[0] @ axes[1], -1.0, 1.0))))


def check_measured_attitude(shown: MountEstimate | None, measured_elevations_deg: Sequence[float]
                            ) -> dict[str, Any] | None:
    """report.json ``attitude_check``: the elevation of the optical axis the frames show against the
    measured camera attitudes' (their median over the same frames, deg above the horizon), and
    whether they agree within MOUNT_TOLERANCE_DEG; None when the frames cannot tell or nothing was
    measured."""
    values = [v for v in measured_elevations_deg if math.isfinite(v)]
    if shown is None or not values:
        return None
    measured = float(np.median(values))
    off = abs(shown.elevation_deg - measured)
    return {'frames_elevation_deg': round(shown.elevation_deg, 1), 'measured_elevation_deg': round(measured, 1),
            'difference_deg': round(off, 1), 'agrees': bool(off <= MOUNT_TOLERANCE_DEG),
            'frames': shown.frames, 'spread_deg': round(shown.spread_deg, 2)}
