"""What real footage carries, turned into the core's types: fixes, camera attitudes, intrinsics.

One adapter per carrier, over the parsers of io/ (exif.py, klv.py, dji_srt.py, gpmf.py): each
yields ``GeoFix`` and ``CameraAttitude`` items in time order and sets each ``Frame.camera`` it can,
and keeps a :class:`MetadataSummary` (source, fields used, frames covered, problems counted) for
report.json's ``metadata``. The core never learns where a value came from.

Angle conventions of the carriers (converted by core/georef/frames.py):
- DJI XMP and SRT gimbal angles: absolute yaw (clockwise from north), pitch (-90 nadir), roll;
- MISB KLV: platform heading/pitch/roll composed with the sensor's relative azimuth/elevation/roll;
- GoPro Karma GPMF: the drone's yaw (clockwise from north) with the gimbal's tilt from the horizon,
  the gimbal levelling the camera (gpmf.py says how that reading was established).
"""
from __future__ import annotations

import bisect
import logging
import math
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.georef.chain_mount import horizon_words
from ..core.georef.frames import R_enu_from_cam_aviation, R_enu_from_cam_platform_sensor
from ..core.georef.georeferencer import MIN_AXIS_DEPRESSION_DEG
from ..core.types import CameraAttitude, CameraIntrinsics, Frame, GeoFix

__all__ = ['MetadataSummary', 'camera_from_fov', 'klv_items', 'KlvVideoSource', 'srt_items', 'gpmf_items']

_LOG = logging.getLogger(__name__)

#: A gimbal within this many degrees of nadir counts as nadir: its GPS position is the frame centre's.
NADIR_TOLERANCE_DEG = 10.0
#: Attitude uncertainty of recorded gimbal / turret angles when the carrier gives none (deg).
RECORDED_ATTITUDE_SIGMA_DEG = 1.0
#: Uncertainty of the ground height a KLV record implies (m): small, because its frame centre and corners
#: are computed on that ground, and at kilometres of slant range registrations cannot tell the height.
KLV_GROUND_SIGMA_M = 1.0


@dataclass
class MetadataSummary:
    """What an input's metadata provided, for report.json ``metadata`` and `srmosaic inspect`."""

    source: str = 'none'
    fields: list[str] = field(default_factory=list)
    frames: int = 0
    frames_with_position: int = 0
    frames_with_attitude: int = 0
    frames_with_intrinsics: int = 0
    problems: Counter[str] = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)
    intrinsics_source: str = ''
    ground_altitude_m: float = float('nan')  # a ground height the metadata implies (KLV frame centre, DJI take-off)
    ground_altitude_sigma_m: float = float('nan')
    ground_altitude_source: str = ''
    centres: dict[int, tuple[float, float]] = field(default_factory=dict, repr=False)  # stamp_ns -> (lat, lon)

    def use(self, name: str) -> None:
        if name not in self.fields:
            self.fields.append(name)

    def problem(self, kind: str, message: str) -> None:
        """Count a bad record; log its kind once (the report has the count)."""
        if kind not in self.problems:
            _LOG.warning('%s (further ones are counted in report.json metadata.problems[%r]).', message, kind)
        self.problems[kind] += 1

    def note(self, text: str) -> None:
        kind = text.split(' by ')[0] if text.startswith('camera clock is') else text
        if not any((n.split(' by ')[0] if n.startswith('camera clock is') else n) == kind for n in self.notes):
            self.notes.append(text)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            'source': self.source, 'fields': list(self.fields), 'frames': self.frames,
            'frames_with_position': self.frames_with_position, 'frames_with_attitude': self.frames_with_attitude,
            'frames_with_intrinsics': self.frames_with_intrinsics, 'intrinsics_source': self.intrinsics_source,
            'problems': dict(self.problems), 'notes': list(self.notes),
        }
        if math.isfinite(self.ground_altitude_m):
            out['ground_altitude'] = {'m': round(self.ground_altitude_m, 2), 'sigma_m': self.ground_altitude_sigma_m,
                                      'source': self.ground_altitude_source}
        return out


def camera_from_fov(width: int, height: int, hfov_deg: float, vfov_deg: float | None = None) -> CameraIntrinsics:
    """Pinhole of a (width x height) frame from its fields of view (deg): f = (size / 2) / tan(fov / 2).

    Without a usable vertical FOV the pixels are square (fy = fx).
    """
    fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    fy = fx
    if vfov_deg is not None and math.isfinite(vfov_deg) and 0.0 < vfov_deg < 180.0:
        fy = (height / 2.0) / math.tan(math.radians(vfov_deg) / 2.0)
        if not 0.8 < fy / fx < 1.25:  # non-square pixels beyond 25 %: the two FOVs disagree, trust the horizontal
            fy = fx
    return CameraIntrinsics(width=width, height=height, fx=fx, fy=fy, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0)


def _finite(*values: Any) -> bool:
    return all(isinstance(v, (int, float)) and math.isfinite(v) for v in values)


# -- MISB KLV -----------------------------------------------------------------------------------
def klv_camera_attitude(fields: dict[str, Any], *, ground_altitude_m: float = float('nan')) -> np.ndarray | None:
    """R_enu_from_cam of a KLV record, or None when its angles are missing.

    The line of sight points from the sensor to the record's frame centre when it has one and
    ``ground_altitude_m`` (the frame centre's height) is known: the frame centre and corners are the
    georeference KLV users see, and a turret's angles can disagree with them (aphill_short.ts's
    azimuth by 1.47 deg, the UTM grid convergence there). Otherwise the angles as sent.
    """
    f = fields
    R = _klv_angles_attitude(f)
    names = ('sensor_latitude_deg', 'sensor_longitude_deg', 'sensor_altitude_m',
             'frame_center_latitude_deg', 'frame_center_longitude_deg')
    vals = [f.get(n) for n in names]
    if R is None or not _finite(*vals, ground_altitude_m):
        return R
    from ..core.georef.geodetic import LocalTangentPlane

    ltp = LocalTangentPlane(vals[0], vals[1], vals[2])
    los = np.asarray(ltp.enu_from_geodetic(vals[3], vals[4], ground_altitude_m), dtype=np.float64).ravel()
    if not np.all(np.isfinite(los)) or los[2] >= 0.0:
        return R
    los /= np.linalg.norm(los)
    azimuth = math.degrees(math.atan2(los[0], los[1]))
    elevation = math.degrees(math.asin(los[2]))
    roll = f.get('sensor_roll_deg')
    return R_enu_from_cam_aviation(azimuth, elevation, roll if _finite(roll) else 0.0)


def _klv_angles_attitude(f: dict[str, Any]) -> np.ndarray | None:
    """R_enu_from_cam of the record's angles alone (absolute EG0104 ones, or ST0601 platform + sensor)."""
    absolute = [f.get(n) for n in ('sensor_azimuth_deg', 'sensor_elevation_deg')]
    if _finite(*absolute):  # EG0104 sends the line of sight's absolute angles (to north, to the horizon)
        roll = f.get('sensor_roll_deg')
        return R_enu_from_cam_aviation(*absolute, roll if _finite(roll) else 0.0)
    names = ('platform_heading_deg', 'platform_pitch_deg', 'platform_roll_deg',
             'sensor_rel_azimuth_deg', 'sensor_rel_elevation_deg')
    vals = [f.get(n) for n in names]
    if not _finite(*vals):
        return None
    rel_roll = f.get('sensor_rel_roll_deg')
    return R_enu_from_cam_platform_sensor(*vals, rel_roll if _finite(rel_roll) else 0.0)


class KlvVideoSource:
    """Frames of a video with MISB KLV: each frame gets the fix, camera attitude and intrinsics of the
    KLV record nearest its presentation time (within half a frame interval, else the latest before it
    if at most 1 s old).

    Wraps a VideoReader (``frame_count``, ``skipped`` and the video attributes pass through).
    """

    def __init__(self, reader: Any, track: Any, *, use_fov: bool = True) -> None:
        self.reader = reader
        self.track = track
        self.use_fov = use_fov and reader.camera is None
        self.summary = MetadataSummary(source=f'MISB KLV ({", ".join(sorted(track.standards))})')
        self._recs = [r for r in track.records if r.pts_ns is not None]
        self._pts = [r.pts_ns for r in self._recs]
        timed = [r for r in track.records if _finite(r.fields.get('precision_time_us'))]
        if not self._recs and timed:
            # an asynchronous stream (no presentation times): the packets' own clock, its first
            # packet taken at the first frame
            t0 = timed[0].fields['precision_time_us']
            self._recs = sorted(timed, key=lambda r: r.fields['precision_time_us'])
            self._pts = [round((r.fields['precision_time_us'] - t0) * 1000) for r in self._recs]
            self.summary.note('asynchronous KLV: packets placed by their precision time stamps, the first at the '
                              'first frame')
        if track.bad_checksum:
            self.summary.problems['klv_bad_checksum'] = int(track.bad_checksum)
            _LOG.warning('%s: %d KLV packets failed their checksum and were left out.', reader.path, track.bad_checksum)
        if len(self._recs) < len(track.records):
            self.summary.problems['klv_no_pts'] = len(track.records) - len(self._recs)
        for rec in self._recs[:1]:
            klv_ground_hint(rec.fields, self.summary)

    def __getattr__(self, name: str) -> Any:  # the reader's counters and video attributes
        return getattr(self.__dict__['reader'], name)

    @property
    def frame_count(self) -> int | None:
        return self.reader.frame_count

    def _record_for(self, stamp_ns: int) -> Any:
        if not self._pts:
            return None
        i = bisect.bisect_left(self._pts, stamp_ns)
        fps = self.reader.fps if math.isfinite(self.reader.fps) and self.reader.fps > 0 else 30.0
        half = int(0.5e9 / fps)
        best = min((j for j in (i - 1, i) if 0 <= j < len(self._pts)), key=lambda j: abs(self._pts[j] - stamp_ns))
        if abs(self._pts[best] - stamp_ns) <= half:
            return self._recs[best]
        before = bisect.bisect_right(self._pts, stamp_ns) - 1
        if before >= 0 and stamp_ns - self._pts[before] <= 1_000_000_000:
            return self._recs[before]
        return None

    def __iter__(self) -> Iterator[Frame | GeoFix | CameraAttitude]:
        s = self.summary
        for frame in self.reader:
            s.frames += 1
            rec = self._record_for(frame.stamp_ns)
            if rec is None:
                s.problem('klv_no_record', f'{self.reader.path}: frame at {frame.stamp_ns} ns has no KLV packet '
                          'within 1 s; it is registered without metadata')
                yield frame
                continue
            yield from klv_items(rec.fields, frame.stamp_ns, s, ground_altitude_m=s.ground_altitude_m)
            if self.use_fov and _finite(rec.fields.get('sensor_hfov_deg')) and rec.fields['sensor_hfov_deg'] > 0:
                frame.camera = camera_from_fov(frame.image.shape[1], frame.image.shape[0], rec.fields['sensor_hfov_deg'],
                                               rec.fields.get('sensor_vfov_deg'))
                s.use('intrinsics (sensor field of view)')
                s.intrinsics_source = 'KLV sensor horizontal/vertical field of view'
            if frame.camera is not None:
                s.frames_with_intrinsics += 1
            yield frame


def klv_items(fields: dict[str, Any], stamp_ns: int, summary: MetadataSummary, *,
              ground_altitude_m: float = float('nan')) -> list[GeoFix | CameraAttitude]:
    """The fix and camera attitude one KLV record gives at ``stamp_ns`` (counted in ``summary``)."""
    out: list[GeoFix | CameraAttitude] = []
    f = fields
    lat, lon, alt = f.get('sensor_latitude_deg'), f.get('sensor_longitude_deg'), f.get('sensor_altitude_m')
    if _finite(lat, lon, alt) and (lat, lon) != (0.0, 0.0):
        out.append(GeoFix(stamp_ns, float(lat), float(lon), float(alt), status=0))
        summary.frames_with_position += 1
        summary.use('sensor position')
    else:
        summary.problem('klv_no_position', 'a KLV packet lacks the sensor latitude, longitude or altitude')
    R = klv_camera_attitude(f, ground_altitude_m=ground_altitude_m)
    if R is not None:
        out.append(CameraAttitude(stamp_ns, R, math.radians(RECORDED_ATTITUDE_SIGMA_DEG)))
        summary.frames_with_attitude += 1
        summary.use('platform attitude + sensor relative angles')
    else:
        summary.problem('klv_no_attitude', 'a KLV packet lacks platform or sensor angles: no camera attitude')
    clat, clon = f.get('frame_center_latitude_deg'), f.get('frame_center_longitude_deg')
    if _finite(clat, clon):
        summary.centres[stamp_ns] = (float(clat), float(clon))
        summary.use('frame centre')
    return out


def klv_ground_hint(fields: dict[str, Any], summary: MetadataSummary) -> None:
    """The ground height one KLV record implies, as the filter's prior (set in ``summary`` once)."""
    if math.isfinite(summary.ground_altitude_m):
        return
    f = fields
    alt, elev, slant = f.get('sensor_altitude_m'), f.get('frame_center_elevation_m'), f.get('slant_range_m')
    R = _klv_angles_attitude(f)
    if _finite(elev) and _finite(alt):
        # the ground plane at the frame centre, in the sensor altitude's datum (MSL)
        summary.use('frame centre elevation')
        summary.ground_altitude_m = float(elev)
        summary.ground_altitude_source = 'KLV frame centre elevation of the first record'
    elif _finite(slant, alt) and R is not None and slant > 0:
        # the line of sight's end: the sensor altitude less the slant range times the sine of the depression
        summary.use('slant range')
        summary.ground_altitude_m = float(alt) + float(slant) * float(R[2, 2])
        summary.ground_altitude_source = 'KLV slant range along the line of sight of the first record'
    else:
        return
    summary.ground_altitude_sigma_m = KLV_GROUND_SIGMA_M


# -- DJI SRT ------------------------------------------------------------------------------------
def srt_items(track: Any, summary: MetadataSummary, *, say: bool = True) -> list[GeoFix | CameraAttitude]:
    """Fixes (and gimbal attitudes when the SRT has them) of a DJI SRT track, on the video's clock.
    ``say``: log the blocks left out (per reason), naming the file."""
    out: list[GeoFix | CameraAttitude] = []
    summary.source = f'DJI SRT ({track.format})'
    for kind, n in track.skipped.items():
        summary.problems[f'srt_{kind}'] += int(n)
    if say and track.skipped:
        _LOG.warning('DJI SRT %s: %d of its %d subtitle blocks left out (%s); the other %d are used (report.json '
                     'metadata.problems srt_*).', track.path.name, sum(track.skipped.values()), track.blocks,
                     ', '.join(f'{k}: {n}' for k, n in sorted(track.skipped.items())), len(track.samples))
    ground: list[float] = []
    for smp in track.samples:
        alt = smp.altitude_m
        if not math.isfinite(alt) and math.isfinite(smp.relative_altitude_m):
            alt = smp.relative_altitude_m  # height above take-off: a datum of its own, consistent within the flight
        if not _finite(smp.latitude_deg, smp.longitude_deg, alt):
            continue
        out.append(GeoFix(smp.start_ns, smp.latitude_deg, smp.longitude_deg, alt, status=0))
        summary.frames_with_position += 1
        if math.isfinite(smp.altitude_m) and math.isfinite(smp.relative_altitude_m):
            ground.append(smp.altitude_m - smp.relative_altitude_m)
        if smp.gimbal_ypr_deg is not None and _finite(*smp.gimbal_ypr_deg):
            yaw, pitch, roll = smp.gimbal_ypr_deg
            out.append(CameraAttitude(smp.start_ns, R_enu_from_cam_aviation(yaw, pitch, roll),
                                      math.radians(RECORDED_ATTITUDE_SIGMA_DEG)))
            summary.frames_with_attitude += 1
            summary.use('gimbal attitude')
            if abs(pitch + 90.0) <= NADIR_TOLERANCE_DEG:
                summary.centres[smp.start_ns] = (smp.latitude_deg, smp.longitude_deg)
    summary.frames = len(track.samples)
    if out:
        summary.use('gps position')
    if ground:
        summary.ground_altitude_m = float(np.median(ground))
        summary.ground_altitude_sigma_m = 5.0
        summary.ground_altitude_source = 'DJI SRT absolute minus relative altitude (the take-off point)'
    out.sort(key=lambda item: item.stamp_ns)
    return out


# -- GoPro GPMF ---------------------------------------------------------------------------------
#: GNSS horizontal sigma per unit of dilution of precision (m): a consumer receiver's UERE.
GPMF_UERE_M = 2.5
#: GPS5 samples with a worse dilution of precision are left out (GoPro's own guidance: below 5 is good).
GPMF_MAX_DOP = 5.0


#: Karma gimbal roll and pan beyond this (deg) are not the levelled, heading-following camera whose
#: reading gpmf.py documents: such samples are left out rather than guessed.
KARMA_GIMBAL_LEVEL_DEG = 1.0


def gpmf_items(track: Any, summary: MetadataSummary) -> list[GeoFix | CameraAttitude]:
    """Fixes of a GoPro GPMF track (3D fixes with a usable DOP), with their DOP as covariance, and
    a Karma drone's camera attitudes (see :func:`karma_attitudes`), in time order."""
    summary.source = f'GoPro GPMF ({track.device or "unknown camera"})'
    for kind, n in track.skipped.items():
        summary.problems[f'gpmf_{kind}'] += int(n)
    out: list[GeoFix] = []
    for smp in track.gps:
        if smp.fix < 2:
            summary.problem('gpmf_no_fix', 'GPMF GPS samples without a fix left out')
            continue
        if not (math.isfinite(smp.dop) and smp.dop <= GPMF_MAX_DOP):
            summary.problem('gpmf_high_dop', f'GPMF GPS samples with DOP above {GPMF_MAX_DOP:g} left out')
            continue
        sh = GPMF_UERE_M * max(smp.dop, 1.0)
        cov = np.diag([sh**2, sh**2, (2.0 * sh) ** 2])
        out.append(GeoFix(smp.stamp_ns, smp.latitude_deg, smp.longitude_deg, smp.altitude_m, status=0,
                          position_covariance_m2=cov, covariance_type=2))
    if out:
        summary.use('gps position')
    summary.frames_with_position = len(out)
    takeoff = [alt - rel for _, (alt, rel) in track.heights]
    if takeoff and track.gps_source == 'GPRI':  # both above mean sea level (MAVLink): the fixes' datum
        summary.ground_altitude_m = float(np.median(takeoff))
        summary.ground_altitude_sigma_m = 5.0
        summary.ground_altitude_source = 'Karma GPMF altitude minus its height above take-off (the take-off point)'
    attitudes = karma_attitudes(track, summary)
    if not attitudes and not track.gimbal_angles:
        summary.note('no camera attitude in the GPMF (a HERO8 or later writes CORI, relative to the camera at '
                     'its start, not to north; a Karma drone writes its attitude and gimbal angles): attitude unknown')
    return sorted([*out, *attitudes], key=lambda item: item.stamp_ns)


def karma_attitudes(track: Any, summary: MetadataSummary) -> list[CameraAttitude]:
    """Camera attitudes of a GoPro on a Karma drone: at each gimbal sample (CYTS) the drone's yaw
    (ATTD, interpolated; clockwise from north) and the gimbal's tilt from the horizon, roll 0 (the
    gimbal levels the camera). Samples outside the drone's attitude record or with the gimbal
    rolled or panned (KARMA_GIMBAL_LEVEL_DEG) are left out and counted."""
    if not track.gimbal_angles or not track.platform_attitude:
        if track.gimbal_angles or track.platform_attitude:
            summary.note('Karma GPMF with only one of the drone attitude (ATTD) and the gimbal angles (CYTS): '
                         'no camera attitude')
        return []
    t = np.array([s for s, _ in track.platform_attitude], dtype=np.float64)
    yaw = np.unwrap([a[2] for _, a in track.platform_attitude])
    margin = 1.5 * float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    out: list[CameraAttitude] = []
    tilts: list[float] = []
    for stamp, (roll, pan, tilt) in track.gimbal_angles:
        if not (t[0] - margin <= stamp <= t[-1] + margin):
            summary.problem('gpmf_gimbal_without_drone_attitude', 'Karma gimbal samples outside the drone attitude '
                            'record left out')
            continue
        if max(abs(roll), abs(pan)) > math.radians(KARMA_GIMBAL_LEVEL_DEG):
            summary.problem('gpmf_gimbal_not_level', f'Karma gimbal samples rolled or panned by more than '
                            f'{KARMA_GIMBAL_LEVEL_DEG:g} deg left out (their angles are not documented)')
            continue
        heading = math.degrees(float(np.interp(stamp, t, yaw)))
        out.append(CameraAttitude(int(stamp), R_enu_from_cam_aviation(heading, math.degrees(tilt), 0.0),
                                  math.radians(RECORDED_ATTITUDE_SIGMA_DEG)))
        tilts.append(math.degrees(tilt))
    if out:
        summary.use('Karma drone attitude and gimbal tilt')
        summary.frames_with_attitude = len(out)
        low, high = min(tilts), max(tilts)
        summary.note(f'Karma camera attitude: {len(out)} samples, the line of sight {horizon_words(low, 1)} to '
                     f'{horizon_words(high, 1)}' + (' (at the horizon: the filter cannot place frames by it, no ground '
                                                 'plane is in view there)' if high > -MIN_AXIS_DEPRESSION_DEG else ''))
    return out



def merge_by_time(frames: Iterable[Frame], telemetry: list[Any]) -> Iterator[Any]:
    """Interleave telemetry (sorted by stamp) before the frames that follow it in time."""
    i = 0
    for frame in frames:
        while i < len(telemetry) and telemetry[i].stamp_ns <= frame.stamp_ns:
            yield telemetry[i]
            i += 1
        yield frame
    yield from telemetry[i:]
