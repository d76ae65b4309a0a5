"""Georeferencing a mosaic by its frames' geotags, when the camera's intrinsics are unknown.

Survey stills (and videos with a flight log but no calibration) carry a GNSS position per frame
but no usable camera model: without the focal length the filter of georeferencer.py cannot turn
a pose into a footprint. The mosaic itself is rigid, though (its frames are chained by
homographies to a fraction of a pixel), so what is missing is one similarity of the whole: where
the mosaic plane lies on the map (offset), which way is north (rotation) and how many metres a
pixel is (scale). With a nadir camera over flat ground the centre of each frame shows the ground
under the camera, so the frame centres (mosaic pixels) and the geotags (UTM) are N matched points
and the least-squares similarity between them (Umeyama 1991, anchoring.fit_similarity) is the
georeferencing. Fitted robustly: a geotag off by more than 3 robust sigmas (1.4826 x the median
absolute residual, at least 1 m) is left out and the fit repeated.

A camera tilted from nadir puts the frame centre d tan(tilt) away from the geotag (5 degrees at
70 m: 6 m): with the frames' attitudes (Imu orientation, a flight log's roll, pitch and yaw) that
offset is modelled and the height d fitted with the similarity (``ground_offsets_per_m``); without
them the camera is taken as nadir, and footage whose frame centres do not follow the track (an
oblique camera: its centres lie ahead of the aircraft or at the centre of its orbit) is refused
rather than misplaced (MAX_RESIDUAL_TO_EXTENT). What it does not know: the mosaic plane is the first frame's
image plane, so a first frame tilted by t leaves a scale gradient of about tan(t) per height above
ground across the mosaic (3 degrees at 100 m: 5 % over 100 m), which a similarity cannot take
out: the method is for gimbal-stabilised nadir stills (the real surveys here: 0.1 degree).
Heights are not used (flat ground).
Accuracy: the GNSS noise averaged over the frames, as a similarity over the mosaic's extent
(report: residual RMS, and the fitted scale's relative uncertainty, residual RMS / (extent
sqrt(N))).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..homography import corner_depth_ratio
from .anchoring import fit_similarity
from .chain_mount import MountEstimate
from .georeferencer import GeoRaster, utm_epsg
from .pose_check import MOUNT_TOLERANCE_DEG, mount_axis_angle_deg

__all__ = ['GEOTAG_MIN_EXTENT_M', 'GeotagFit', 'check_mount_nadir', 'check_views_nadir', 'fit_mosaic_to_geotags',
           'view_depth_ratios']

MIN_FRAMES = 3
#: Geotags must span this much (m RMS from their mean), four times a consumer receiver's noise,
#: to set a mosaic's scale and rotation.
GEOTAG_MIN_EXTENT_M = 10.0
MIN_SIGMA_M = 1.0      # residual floor of the outlier test (consumer GNSS is not better)
REJECT_SIGMAS = 3.0
#: A fit whose residual RMS exceeds this fraction of the geotags' extent (the similarity explains
#: less than half of the track's spread, 1 - 0.7^2) is refused: the frame centres do not follow the
#: track, as those of a camera looking obliquely (ahead of the aircraft, or at the centre of an orbit)
#: do not. Nadir footage stays far below it: the real stills here 0.10 and 0.15, consumer GNSS noise
#: (2-D 7 m at 5 m a coordinate) over the least extent accepted (GEOTAG_MIN_EXTENT_M) 0.7; the
#: simulated oblique orbit of test_sim_unmeasured_attitude 0.97 (its fit was 178 m off on the map).
MAX_RESIDUAL_TO_EXTENT = 0.7
#: The median frame of a mosaic fitted to its geotags may see the mosaic plane at most this
#: obliquely (the depth of its farthest corner over its nearest, view_depth_ratios). Frames parallel
#: to the mosaic plane (nadir footage chained in its first frame's plane) have 1 up to their tilt
#: (2 deg gusts with a 60 deg lens: about 1.05); the simulated orbit's median is 2.1 and most of
#: karma.mp4's frames reach past the plane's horizon (infinite).
MAX_MEDIAN_DEPTH_RATIO = 1.5


@dataclass(frozen=True)
class GeotagFit:
    """The similarity mosaic pixel -> UTM of :func:`fit_mosaic_to_geotags`, as a GeoRaster of the
    mosaic's pixel grid, with its figures (metres unless said)."""

    raster: GeoRaster
    residuals_m: np.ndarray          # (N,) distance of each frame centre from its geotag after the fit
    used: np.ndarray                 # (N,) bool: kept by the outlier test
    extent_m: float                  # RMS distance of the used geotags from their mean
    height_m: float | None = None    # height above ground fitted with the attitudes (None: nadir assumed)

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_m[self.used] ** 2)))

    @property
    def scale_rel_sigma(self) -> float:
        """Relative standard deviation of the fitted scale (and, in radians, of the rotation)."""
        n = int(self.used.sum())
        return float(self.rms_m / (self.extent_m * math.sqrt(max(n - 2, 1)))) if self.extent_m > 0 else math.inf

    def figures(self) -> dict[str, float | int | str]:
        return {'method': 'geotags', 'frames_used': int(self.used.sum()),
                'frames_rejected': int((~self.used).sum()), 'geotag_residual_rms_m': round(self.rms_m, 3),
                'geotag_residual_max_m': round(float(self.residuals_m[self.used].max()), 3),
                'extent_m': round(self.extent_m, 1), 'scale_rel_sigma': round(self.scale_rel_sigma, 5),
                'rotation_deg': round(math.degrees(self.raster.rotation_rad), 3),
                'tilt_corrected': self.height_m is not None,
                **({'height_above_ground_m': round(self.height_m, 2)} if self.height_m is not None else {})}


def _fit(src: np.ndarray, utm: np.ndarray, offsets: np.ndarray | None) -> tuple[np.ndarray, float | None]:
    """(S (3, 3) with utm ~ S @ src + h * offsets, h or None): the similarity alone (Umeyama), or
    jointly with the height h when ``offsets`` (N, 2) are given, as the linear least squares
    a x - b y + tx - h dx = e, b x + a y + ty - h dy = n (S = [[a, -b, tx], [b, a, ty]]). h is
    kept only when it is determined (positive, standard error under half of it); else None."""
    S = fit_similarity(src, utm, from_a_line=True)  # a straight flight places its mosaic too
    if offsets is None or len(src) < 4:
        return S, None
    n = len(src)
    A = np.zeros((2 * n, 5))
    A[0::2] = np.c_[src[:, 0], -src[:, 1], np.ones(n), np.zeros(n), -offsets[:, 0]]
    A[1::2] = np.c_[src[:, 1], src[:, 0], np.zeros(n), np.ones(n), -offsets[:, 1]]
    b = utm.reshape(-1)
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    dof = max(2 * n - 5, 1)
    sigma2 = float(np.sum((A @ x - b) ** 2)) / dof
    try:
        se_h = math.sqrt(sigma2 * float(np.linalg.inv(A.T @ A)[4, 4]))
    except np.linalg.LinAlgError:
        return S, None
    h = float(x[4])
    if not (h > 0 and se_h < 0.5 * h):
        return S, None
    return np.array([[x[0], -x[1], x[2]], [x[1], x[0], x[3]], [0.0, 0.0, 1.0]]), h


def view_depth_ratios(plane_H_frames: list[np.ndarray], sizes: list[tuple[int, int]]) -> np.ndarray:
    """(N,) how obliquely each frame (w, h) sees the mosaic plane: homography.corner_depth_ratio of
    its plane_H_frame (1 parallel to it, inf past its horizon)."""
    return np.array([corner_depth_ratio(m, w, h) for m, (w, h) in zip(plane_H_frames, sizes, strict=True)])


def check_views_nadir(plane_H_frames: list[np.ndarray], sizes: list[tuple[int, int]]) -> None:
    """Raise ValueError (with the reason and a way out) when the median frame of a mosaic chained in
    its first frame's plane sees that plane obliquely (MAX_MEDIAN_DEPTH_RATIO): the frames are not
    parallel to one another, so neither the first frame nor the later ones look straight down, and
    a fit to the geotags (which takes each frame centre to lie under the camera) would misplace it."""
    ratios = view_depth_ratios(plane_H_frames, sizes)
    if len(ratios) == 0:
        return
    median = float(np.median(ratios))
    if median > MAX_MEDIAN_DEPTH_RATIO:
        beyond = int(np.isinf(ratios).sum())
        seen = ('the median frame reaches past the mosaic plane\'s horizon' if math.isinf(median) else
                f'the median frame\'s far corners lie {median:.1f} times as deep in the mosaic plane as its near ones')
        msg = (f'its frames do not look straight down: {seen} ({beyond} of {len(ratios)} frames reach past that '
               'horizon), where frames of a nadir camera lie parallel to the plane. The geotags are where the aircraft was, '
               'not where the camera looked, and a fit to them would misplace the mosaic. To place it, give the '
               'camera\'s intrinsics and its attitude or the mount it is fixed at (an Imu orientation, gimbal '
               'angles, georef.gimbal_elevation_deg and georef.gimbal_azimuth_deg)')
        raise ValueError(msg)


def check_mount_nadir(shown: MountEstimate | None) -> None:
    """Raise ValueError (with the reason and a way out) when the frames' chain shows a camera more
    than pose_check.MOUNT_TOLERANCE_DEG off nadir (chain_mount.py): a constant tilt keeps the frames
    parallel to one another, which check_views_nadir cannot see, and moves every frame centre
    height * tan(tilt) from its geotag."""
    if shown is None:
        return
    off = mount_axis_angle_deg((0.0, -90.0), (shown.azimuth_deg, shown.elevation_deg))
    if off > MOUNT_TOLERANCE_DEG:
        msg = (f'its frames do not look straight down: their chain shows the camera {shown.line_of_sight()} '
               '(report.json pose_placement.frames_mount). The geotags are where the aircraft was, not where the camera looked, '
               'and a fit to them would misplace the mosaic. To place it through the filter, let the run use that '
               f'mount (georef.mount_from_frames: true, offline) or set it (georef.gimbal_elevation_deg: '
               f'{shown.elevation_deg:.1f}, georef.gimbal_azimuth_deg: {shown.azimuth_deg:.1f}), or give the attitude')
        raise ValueError(msg)


def fit_mosaic_to_geotags(centres_px: np.ndarray, lonlat_deg: np.ndarray,
                          ground_offsets_per_m: np.ndarray | None = None) -> GeotagFit:
    """Fit mosaic pixels -> UTM from frame centres (N, 2; mosaic pixels, y down) and their geotags
    (N, 2; longitude, latitude in degrees). Raises ValueError with the reason when the geotags
    cannot fix a similarity (fewer than 3 frames, or all at one spot) or the frame centres do not
    follow them (MAX_RESIDUAL_TO_EXTENT: an oblique camera).

    ground_offsets_per_m: (N, 2) where each frame's optical axis meets the ground, east and north of
    the camera, per metre of height (-r_xy / r_z of the axis r in ENU, from the attitude), NaN
    where unknown. Given, the frame centre is matched with geotag + h * offset, h (the height
    above ground, unknown without intrinsics) fitted with the similarity: the tilt of a camera that
    is not stabilised (2 degrees at 100 m: 3.5 m between the frame centre and the geotag, slowly
    varying with the gusts, which biases a plain similarity by 15 % in scale on a 120 m line) is
    taken out."""
    from pyproj import Transformer

    centres = np.asarray(centres_px, dtype=np.float64).reshape(-1, 2)
    lonlat = np.asarray(lonlat_deg, dtype=np.float64).reshape(-1, 2)
    if len(centres) != len(lonlat):
        msg = f'{len(centres)} frame centres but {len(lonlat)} geotags.'
        raise ValueError(msg)
    offsets = None if ground_offsets_per_m is None else np.asarray(ground_offsets_per_m, dtype=np.float64).reshape(-1, 2)
    good = np.all(np.isfinite(centres), axis=1) & np.all(np.isfinite(lonlat), axis=1)
    if offsets is not None:
        known = np.all(np.isfinite(offsets), axis=1)
        if (good & known).sum() >= max(MIN_FRAMES + 1, 0.8 * good.sum()):
            good &= known   # the few frames without an attitude are left out of the fit
        else:
            offsets = None  # most frames without an attitude: the plain similarity for all
    if good.sum() < MIN_FRAMES:
        msg = f'{int(good.sum())} frame(s) with a geotag; at least {MIN_FRAMES} are needed to place the mosaic.'
        raise ValueError(msg)
    lon0, lat0 = np.median(lonlat[good], axis=0)
    epsg = utm_epsg(float(lat0), float(lon0))
    e, n = Transformer.from_crs(4326, epsg, always_xy=True).transform(lonlat[:, 0], lonlat[:, 1])
    utm = np.stack([np.asarray(e), np.asarray(n)], axis=1)
    # Mosaic pixel (x, y down) -> (x, -y): a similarity without reflection then maps it to UTM.
    flip = np.diag([1.0, -1.0, 1.0])
    base = GeoRaster(epsg, 1.0, 0.0, 0.0, 0.0)   # utm_H_raster = flip
    src = centres * np.array([1.0, -1.0])
    used = good.copy()
    for _ in range(10):
        spread = utm[used] - utm[used].mean(axis=0)
        extent = float(np.sqrt(np.mean(np.sum(spread**2, axis=1))))
        if extent < 3.0 * MIN_SIGMA_M:
            msg = (f'the geotags of the {int(used.sum())} frames lie within {extent:.1f} m RMS of each other: too '
                   'close to fix the mosaic\'s scale and rotation (hovering, or one position repeated).')
            raise ValueError(msg)
        S, h = _fit(src[used], utm[used], None if offsets is None else offsets[used])  # utm ~ S @ (x, -y)
        target = utm if h is None else utm + h * offsets
        res = np.linalg.norm(src @ S[:2, :2].T + S[:2, 2] - target, axis=1)
        sigma = max(1.4826 * float(np.median(res[used])), MIN_SIGMA_M)
        keep = good & (res <= REJECT_SIGMAS * sigma)
        if keep.sum() < MIN_FRAMES:
            keep = used
        if np.array_equal(keep, used):
            break
        used = keep
    fit = GeotagFit(base.transformed(flip @ S @ flip), res, used, extent, h)  # utm_H_raster = S @ flip
    if fit.rms_m > MAX_RESIDUAL_TO_EXTENT * extent:
        msg = (f'the frame centres do not follow their geotags: {fit.rms_m:.1f} m RMS from them after the best fit, '
               f'over a track of {extent:.1f} m RMS (a nadir camera\'s centres follow its track to the GNSS noise). The '
               'camera looks obliquely (ahead of the aircraft, or at the centre of an orbit), and the fit would '
               'misplace the mosaic. To place it, give the camera\'s intrinsics and its attitude or the mount it is '
               'fixed at (an Imu orientation, gimbal angles, georef.gimbal_elevation_deg and georef.gimbal_azimuth_deg)')
        raise ValueError(msg)
    return fit


def geotags_at(fix_stamps_ns: np.ndarray, fix_lonlat_deg: np.ndarray, stamps_ns: np.ndarray,
               max_gap_s: float = 2.0) -> np.ndarray:
    """(M, 2) longitude, latitude at each of ``stamps_ns`` (M,): a fix at that stamp, or linearly
    interpolated between the two fixes around it when they are at most ``max_gap_s`` apart; NaN
    where no fix is that close (fix_stamps_ns (N,) ascending, fix_lonlat_deg (N, 2))."""
    ts = np.asarray(fix_stamps_ns, dtype=np.int64)
    ll = np.asarray(fix_lonlat_deg, dtype=np.float64).reshape(-1, 2)
    out = np.full((len(stamps_ns), 2), np.nan)
    if len(ts) == 0:
        return out
    gap = int(max_gap_s * 1e9)
    for i, t in enumerate(np.asarray(stamps_ns, dtype=np.int64)):
        j = int(np.searchsorted(ts, t))
        if j < len(ts) and ts[j] == t:
            out[i] = ll[j]
        elif 0 < j < len(ts) and ts[j] - ts[j - 1] <= gap:
            a = (t - ts[j - 1]) / (ts[j] - ts[j - 1])
            out[i] = (1.0 - a) * ll[j - 1] + a * ll[j]
    return out
