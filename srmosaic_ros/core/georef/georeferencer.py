"""Georeferencer: the pipeline stage that turns telemetry and registrations into poses and a map plane.

    georef = Georeferencer(GeorefConfig(), camera)
    georef.feed_fix(fix); georef.feed_imu(imu)             # any time, in stamp order per sensor
    georef.feed_camera_attitude(att)                       # a measured camera orientation (gimbal, KLV)
    pose = georef.feed_frame(stamp_ns, prev_H_cur, cov)    # one FramePose per frame (fused)
    raster = georef.make_raster(pose)                      # north-up UTM grid, once
    raster_H_frame = georef.raster_H_frame(pose)           # place a frame by its pose (flat ground)
    raster_H_frame = georef.correct(chained_H, pose)       # drift control of a chained homography

Before the first valid fix there is no origin yet (``has_origin`` is false): IMU samples and camera
attitudes are kept for the ``telemetry_buffer_s`` before the newest, and frames get invalid poses
('no GNSS fix yet'), so the Georeferencer can exist from the flight's start.

Frames and units: the local ENU plane is tangent at the first valid fix, with its z = 0 at the
prior ground altitude (``ground_altitude_m``, or the first fix's altitude minus ``nominal_agl_m``);
the filter then estimates the ground plane's height in that frame (see ukf.py). Body x forward,
y left, z up, attitude REP 103 (see frames.py). The raster is north-up in the flight's UTM zone
(WGS84, EPSG 326zz / 327zz): raster pixel (x, y) (x right, y down, pixel centres at integers) is
at easting ``e0 + gsd x``, northing ``n0 - gsd y``. ENU and
UTM differ by the grid convergence and the UTM scale factor; over a UAS flight the map between the
two planes is affine to well under a millimetre (it is fitted once over +-3 km and checked).

Telemetry is buffered and fused at its own stamp between the two frames held by the UKF (see
ukf.py). Unusable inputs (NO_FIX status, NaN fields, stamps out of order or older than the
filter's window, gated outliers) are skipped with one logged warning per kind and counted in
``skipped``; they never raise.

The Georeferencer conducts the fusion; its collaborators each own one job: telemetry.py turns
telemetry into measurements, initialiser.py starts the filter at the first frame, placement.py owns
the raster and drift control, skip_log.py counts what was left out.
"""
from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np

from ..types import FIX_STATUS_NO_FIX, CameraAttitude, CameraIntrinsics, GeoFix, ImuSample
from .frame_pose import FramePose
from .frames import matrix_from_rotvec, rotvec_from_matrix
from .drift import AbsoluteInformation
from .geodetic import LocalTangentPlane
from .georef_config import GeorefConfig
from .ground_homography import camera_pose_from_enu_H_image
from .initialiser import course_velocity, initial_state
from .placement import RasterPlacement, frame_corners
from .raster import GeoRaster, utm_epsg
from .skip_log import SkipLog
from .telemetry import MIN_AXIS_DEPRESSION_DEG, camera_attitude, fix_covariance, imu_attitude, sees_the_ground
from .ukf import GROUND, SLOT_CUR, SLOT_PREV, CameraMount, PoseUkf, corner_jacobian, rts_smooth, wrap_angle

__all__ = [
    'GeorefConfig',
    'FramePose',
    'GeoRaster',
    'Georeferencer',
    'utm_epsg',
    'camera_pose_from_enu_H_image',
    'sees_the_ground',
    'course_velocity',
    'MIN_AXIS_DEPRESSION_DEG',
]

_LOG = logging.getLogger(__name__)
#: Span over which the information rate of the absolute measurements is averaged (FramePose.info_rate).
INFO_RATE_WINDOW_S = 10.0
class Georeferencer:
    """Fuses GNSS, IMU and registrations into one pose per frame; places frames on a UTM raster.

    Args:
        config: the ``georef.`` parameters.
        camera: intrinsics of the frames (may also come with each ``feed_frame``).
    """

    def __init__(self, config: GeorefConfig | None = None, camera: CameraIntrinsics | None = None) -> None:
        self.config = config or GeorefConfig()
        self.camera = camera
        self._prev_camera: CameraIntrinsics | None = None  # the previous frame's: what its registration maps into
        self.ukf = PoseUkf(self.config.ukf_params)
        self.origin: LocalTangentPlane | None = None  # None: no valid fix yet (the filter keeps telemetry meanwhile)
        self.ground_altitude_m: float = float('nan')
        self.placement = RasterPlacement(self.config, self.mount)  # the raster and drift control
        self.log = SkipLog()  # inputs left out, per kind
        self.poses: list[FramePose] = []
        self.updates: Counter[str] = Counter()
        self._pending: list[tuple[int, int, str, np.ndarray, np.ndarray]] = []  # (stamp, seq, kind, z, R)
        self._gyro: list[tuple[int, np.ndarray]] = []  # (stamp, body angular velocity rad/s)
        # per filtered frame: [pose index, x_pred, P_pred, x_post, P_post, F] for the smoother
        self._history: list[list] = []
        self._seq = 0
        self.information = AbsoluteInformation(INFO_RATE_WINDOW_S)  # the fixes and attitudes fused, for FramePose.info_rate

    @property
    def mount(self) -> CameraMount:
        """The camera's mount on the body (``georef.`` parameters)."""
        return self.config.mount

    @property
    def has_origin(self) -> bool:
        """Whether a valid fix has set the local ENU plane: before it, poses are invalid ('no GNSS fix yet')."""
        return self.origin is not None

    @property
    def skipped(self) -> Counter[str]:
        """Inputs left out, per kind (SkipLog)."""
        return self.log.skipped

    @property
    def raster(self) -> GeoRaster | None:
        """The flight's raster (RasterPlacement), None before :meth:`make_raster`."""
        return self.placement.raster

    @property
    def ground_z_m(self) -> float:
        """Current estimate of the ground plane's height in the ENU plane (0 before the first frame)."""
        return self.ukf.ground_z[0] if self.ukf.initialized else 0.0

    # -- telemetry -----------------------------------------------------------------------------
    def feed_fix(self, fix: GeoFix) -> None:
        """A GNSS fix (WGS84). Skipped with a warning: NO_FIX, NaN/out-of-range fields, old stamps."""
        if fix.status <= FIX_STATUS_NO_FIX:
            self.log.skip('fix_no_fix', 'GNSS fix with status NO_FIX ignored')
            return
        if not all(math.isfinite(v) for v in (fix.latitude_deg, fix.longitude_deg, fix.altitude_m)):
            self.log.skip('fix_nan', 'GNSS fix with NaN latitude, longitude or altitude ignored')
            return
        if abs(fix.latitude_deg) >= 90.0 or abs(fix.longitude_deg) > 180.0:
            self.log.skip('fix_range', f'GNSS fix at impossible ({fix.latitude_deg}, {fix.longitude_deg}) ignored')
            return
        if not self.log.in_order('fix', fix.stamp_ns):
            return
        R = fix_covariance(fix, self.config, self.log)
        if self.origin is None:
            self._set_origin(fix)
        assert self.origin is not None
        enu = self.origin.enu_from_geodetic(fix.latitude_deg, fix.longitude_deg, fix.altitude_m)
        self._telemetry('fix', int(fix.stamp_ns), np.asarray(enu, dtype=np.float64), R)

    def feed_imu(self, imu: ImuSample) -> None:
        """An IMU sample: its orientation (body in ENU, REP 145) and its angular velocity (body frame,
        integrated between frames) are fused; the acceleration is not used."""
        if not self.log.in_order('imu', imu.stamp_ns):
            return
        w = np.asarray(imu.angular_velocity_rad_s, dtype=np.float64)
        if w.shape == (3,) and np.all(np.isnan(w)):
            self.log.skipped['imu_no_rate'] += 1  # not provided (flight log, EXIF): orientation only, no gyro update
        elif w.shape == (3,) and np.all(np.isfinite(w)):
            self._gyro.append((int(imu.stamp_ns), w))
            if self.ukf.initialized:
                keep_from = int(self.ukf.t_prev_ns or 0) - int(self.config.gyro_max_gap_s * 1e9)
            else:
                keep_from = int(imu.stamp_ns) - int(self.config.telemetry_buffer_s * 1e9)
            if self._gyro[0][0] < keep_from:
                self._gyro = [g for g in self._gyro if g[0] >= keep_from]
        else:
            self.log.skip('imu_gyro_nan', 'Imu angular velocity with NaN fields ignored')
        measured = imu_attitude(imu, self.config, self.log)
        if measured is not None:
            self._telemetry('imu', int(imu.stamp_ns), *measured)

    def feed_camera_attitude(self, attitude: CameraAttitude) -> None:
        """A measured orientation of the camera (gimbal angles, KLV sensor angles) in ENU.

        It is fused as the body attitude that the configured mount implies
        (``R_enu_from_body = R_enu_from_cam R_body_from_cam^T``), so the filter's camera is the
        measured one whatever the mount; its isotropic sigma (else ``imu_sigma_deg``) is carried
        to roll, pitch and yaw through the Jacobian of that map. Cameras looking at or above the
        horizon (optical axis less than 5 degrees below it) cannot see a ground plane and are skipped.
        """
        if not self.log.in_order('camera_attitude', attitude.stamp_ns):
            return
        measured = camera_attitude(attitude, self.config, self.mount, self.log)
        if measured is not None:
            self._telemetry('imu', int(attitude.stamp_ns), *measured)

    # -- frames --------------------------------------------------------------------------------
    def feed_frame(self, stamp_ns: int, prev_H_cur: np.ndarray | None = None,
                   covariance: np.ndarray | None = None, *, rms_px: float = float('nan'), inliers: int = 0,
                   camera: CameraIntrinsics | None = None, ref_stamp_ns: int | None = None) -> FramePose:
        """Fuse one frame and return its pose.

        Args:
            stamp_ns: the frame's stamp (increasing).
            prev_H_cur: (3, 3) registration of this frame to the *previously fed* frame (current
                pixels -> previous pixels), or None (first frame, failed registration, or a
                registration to an older frame, which the two-pose state cannot use).
            covariance: (8, 8) covariance of (h00 .. h21) of prev_H_cur with h22 = 1 (4.43), or None:
                then an isotropic corner covariance ``(homography_sigma_gain * rms_px)**2``.
            rms_px, inliers: the registration's inlier RMS and count (used when covariance is None).
            camera: the intrinsics of this frame, when they change.
            ref_stamp_ns: the stamp of the frame prev_H_cur maps into, when known: a registration to
                any other frame than the previously fed one is skipped (with a warning) instead of
                being fused as if it were consecutive.
        """
        stamp_ns = int(stamp_ns)
        if camera is not None:
            self.camera = camera
        if self.ukf.initialized and stamp_ns <= int(self.ukf.t_cur_ns or 0):
            self.log.skip('frame_out_of_order', f'frame at {stamp_ns} ns is not after the previous frame; no pose')
            pose = FramePose.invalid(stamp_ns, 'frame out of order')
            self.poses.append(pose)
            return pose
        used_h = False
        if not self.ukf.initialized:
            if not self._initialize(stamp_ns):
                pose = FramePose.invalid(stamp_ns, 'no GNSS fix yet')
                self.poses.append(pose)
                return pose
            self._record(None)
        else:
            bridged = self._bridge(stamp_ns)
            self._close_record()
            self.ukf.advance(stamp_ns)
            self._record(self.ukf.last_F)
            self._update_gyro()
            if prev_H_cur is not None and self.camera is None:
                self.log.skip('homography_no_camera', 'the frames carry no camera model (no intrinsics; stills '
                           'without gimbal angles get none: their geotags place them): registrations are not fused')
            elif prev_H_cur is not None and bridged:
                self.log.skip('homography_after_gap', f'frames more than max_step_s = {self.config.max_step_s} s apart: '
                           'their registration is not fused (the filter bridged the gap on telemetry)')
            elif prev_H_cur is not None and ref_stamp_ns is not None and int(ref_stamp_ns) != self.ukf.t_prev_ns:
                self.log.skip('homography_not_consecutive', 'a registration to a frame other than the previous one '
                           'cannot be fused by the two-pose filter; it was skipped')
            elif prev_H_cur is not None:
                used_h = self._update_homography(prev_H_cur, covariance, rms_px, inliers)
        n_fix, n_imu = self._apply_pending()
        pose = self._pose(SLOT_CUR, stamp_ns, used_h, n_fix, n_imu)
        self.poses.append(pose)
        self._prev_camera = self.camera  # the next registration maps into this frame
        self.placement.check_raster_agl(pose, self.ukf.ground_z[1] if self.ukf.initialized else float('inf'), self.log)
        return pose

    def _bridge(self, stamp_ns: int) -> int:
        """Filter-only steps of ``max_step_s`` up to a frame far after the previous one (a camera
        dropout, a low frame rate): telemetry is interpolated over short spans only. Returns the
        number of steps taken."""
        step = int(self.config.max_step_s * 1e9)
        n = 0
        while stamp_ns - int(self.ukf.t_cur_ns or 0) > 1.5 * step:
            self._close_record()
            self.ukf.advance(int(self.ukf.t_cur_ns or 0) + step)
            self._record(self.ukf.last_F, virtual=True)
            self._update_gyro()
            self._apply_pending()
            n += 1
        return n

    def smoothed_poses(self) -> list[FramePose]:
        """Every frame's pose smoothed with all the data fed so far (Rauch-Tung-Striebel), for
        offline products; aligned with :attr:`poses` (frames without a filtered pose stay invalid,
        as do frames older than ``history_frames``). The filter itself is not changed."""
        out = list(self.poses)
        if not self._history:
            return out
        self._close_record()
        steps = [(h[1], h[2], h[3], h[4], h[5]) for h in self._history]
        for h, (x, P) in zip(self._history, rts_smooth(steps)):
            if h[0] is None:  # a filter-only step across a gap
                continue
            old = self.poses[h[0]]
            out[h[0]] = self._pose_from(x, P, old.stamp_ns, old.homography_used, old.fixes_used, old.imu_used,
                                        old.info_rate)
        return out

    def previous_pose(self) -> FramePose | None:
        """The previous frame's pose as refined by everything fused since (one-frame fixed lag)."""
        if not self.ukf.initialized or self.ukf.t_prev_ns == self.ukf.t_cur_ns:
            return None
        return self._pose(SLOT_PREV, int(self.ukf.t_prev_ns or 0), False, 0, 0)

    # -- raster and placement (RasterPlacement) ------------------------------------------------
    def make_raster(self, pose: FramePose, camera: CameraIntrinsics | None = None, *,
                    gsd_m_per_px: float | None = None, coarsen: float = 1.0) -> GeoRaster:
        """The north-up UTM raster of this flight, created once (:meth:`RasterPlacement.make_raster`)."""
        return self.placement.make_raster(pose, camera or self.camera, gsd_m_per_px=gsd_m_per_px, coarsen=coarsen)

    def refine_raster(self, zoom: float) -> float:
        """Sample the raster about ``zoom`` times finer; the exact zoom (:meth:`RasterPlacement.refine_raster`)."""
        return self.placement.refine_raster(zoom)

    def drop_raster(self) -> None:
        """Forget the raster and the drift controller (:meth:`RasterPlacement.drop_raster`)."""
        self.placement.drop_raster()

    def raster_H_enu(self, raster: GeoRaster | None = None) -> np.ndarray:
        """(3, 3) ENU ground (east, north, 1) -> raster pixel (x, y, 1) (affine)."""
        return self.placement.raster_H_enu(raster)

    def raster_H_frame(self, pose: FramePose, camera: CameraIntrinsics | None = None,
                       raster: GeoRaster | None = None) -> np.ndarray:
        """(3, 3) frame pixels -> raster pixels of the flat ground seen from ``pose`` (normalised)."""
        return self.placement.raster_H_frame(pose, camera or self.camera, raster)

    def correct(self, raster_H_frame_chained: np.ndarray, pose: FramePose,
                camera: CameraIntrinsics | None = None, raster: GeoRaster | None = None, *,
                chain_sigma_px: float | None = None) -> np.ndarray:
        """Drift control of a chained frame -> raster homography (:meth:`RasterPlacement.correct`)."""
        return self.placement.correct(raster_H_frame_chained, pose, camera or self.camera, raster,
                                      chain_sigma_px=chain_sigma_px, fallback_info_rate=self.information.last)

    def corner_sigma_px(self, prev_H_cur: np.ndarray, covariance: np.ndarray | None,
                        camera: CameraIntrinsics | None = None) -> float:
        """RMS corner standard deviation (px) of a registration (:meth:`RasterPlacement.corner_sigma_px`)."""
        return self.placement.corner_sigma_px(prev_H_cur, covariance, camera or self.camera)

    def reset_drift(self, *, new_canvas: bool = False) -> None:
        """A new mosaic segment starts (:meth:`RasterPlacement.reset_drift`)."""
        self.placement.reset_drift(new_canvas=new_canvas)

    @property
    def drift_nis(self) -> float:
        """The normalised innovation squared of the last :meth:`correct` (RasterPlacement.drift_nis)."""
        return self.placement.drift_nis

    @property
    def canvas_similarity(self) -> np.ndarray | None:
        """(3, 3) true raster pixel -> canvas pixel, or None before a chain (RasterPlacement.canvas_similarity)."""
        return self.placement.canvas_similarity

    # -- internals -----------------------------------------------------------------------------

    def _set_origin(self, fix: GeoFix) -> None:
        ground = self.config.ground_altitude_m
        if not math.isfinite(ground):
            ground = fix.altitude_m - self.config.nominal_agl_m
        self.ground_altitude_m = float(ground)
        self.origin = LocalTangentPlane(fix.latitude_deg, fix.longitude_deg, self.ground_altitude_m)
        self.placement.origin = self.origin

    def _telemetry(self, kind: str, stamp_ns: int, z: np.ndarray, R: np.ndarray) -> None:
        ukf = self.ukf
        if ukf.initialized:
            assert ukf.t_prev_ns is not None and ukf.t_cur_ns is not None
            if stamp_ns < ukf.t_prev_ns:
                self.log.skip(f'{kind}_stale', f'{kind} message at {stamp_ns} ns is older than the filter window '
                           f'(from {ukf.t_prev_ns} ns) and was ignored')
                return
            if stamp_ns <= ukf.t_cur_ns:  # late, but inside the window: fuse now
                self._apply(kind, stamp_ns, z, R)
                return
        self._seq += 1
        self._pending.append((stamp_ns, self._seq, kind, z, R))
        horizon = stamp_ns - int(self.config.telemetry_buffer_s * 1e9)
        if self._pending[0][0] >= horizon:
            return
        if not ukf.initialized:  # before the first frame only the latest telemetry matters
            self._pending = [p for p in self._pending if p[0] >= horizon]
            return
        # No frame for telemetry_buffer_s (camera dropout): the filter goes on without frames, in
        # filter-only steps, rather than dropping telemetry. A frame older than the step reached is
        # then out of order (it would be more than telemetry_buffer_s late).
        self._pending.sort(key=lambda p: (p[0], p[1]))
        step = int(self.config.max_step_s * 1e9)
        while self._pending and self._pending[0][0] < horizon:
            self._close_record()
            ukf.advance(int(ukf.t_cur_ns or 0) + step)
            self._record(ukf.last_F, virtual=True)
            self._update_gyro()
            self._apply_pending()

    def _apply(self, kind: str, stamp_ns: int, z: np.ndarray, R: np.ndarray) -> bool:
        if kind == 'fix':
            res = self.ukf.update_position(stamp_ns, z, R)
        else:
            res = self.ukf.update_attitude(stamp_ns, z, R)
        self.updates[f'{kind}_{res.status}'] += 1
        if res.status == 'gated':
            self.log.skip(f'{kind}_gated', f'{kind} at {stamp_ns} ns disagrees with the fused state '
                       f'(squared Mahalanobis distance {res.mahalanobis2:.1f}) and was not fused')
        elif res.status == 'failed':
            self.log.skip(f'{kind}_failed', f'{kind} update at {stamp_ns} ns failed numerically and was skipped')
        if res.accepted:
            self._add_information(kind, stamp_ns, R)
        return res.accepted

    def _add_information(self, kind: str, stamp_ns: int, R: np.ndarray) -> None:
        """Count an absolute measurement fused (a fix: position block; an attitude: attitude block)."""
        self.information.add(kind, stamp_ns, R)

    def information_rate(self, stamp_ns: int) -> np.ndarray:
        """(6, 6) information per second of the absolute measurements fused before ``stamp_ns``
        (AbsoluteInformation.rate; see FramePose.info_rate and drift.InformationRate)."""
        return self.information.rate(stamp_ns)

    def _apply_pending(self) -> tuple[int, int]:
        ukf = self.ukf
        assert ukf.t_prev_ns is not None and ukf.t_cur_ns is not None
        self._pending.sort(key=lambda p: (p[0], p[1]))
        keep, n_fix, n_imu = [], 0, 0
        for item in self._pending:
            stamp, _, kind, z, R = item
            if stamp > ukf.t_cur_ns:
                keep.append(item)
            elif stamp < ukf.t_prev_ns:
                self.log.skip(f'{kind}_stale', f'{kind} message at {stamp} ns is older than the filter window and was '
                           'ignored')
            elif self._apply(kind, stamp, z, R):
                n_fix += kind == 'fix'
                n_imu += kind == 'imu'
        self._pending = keep
        return n_fix, n_imu

    def _initialize(self, stamp_ns: int) -> bool:
        """Start the filter at the first frame that has a fix before it (or the nearest fix)."""
        start = initial_state(self._pending, stamp_ns, self.config, self.log)
        if start is None:
            return False
        self.ukf.initialize(stamp_ns, start.pose, start.covariance, 0.0, start.ground_var_m2)
        self._add_information('fix', start.fix_stamp_ns, start.fix_covariance)
        if start.imu_stamp_ns is not None:
            self._add_information('imu', start.imu_stamp_ns, start.imu_covariance)
        self._pending = [p for p in self._pending if p[0] > stamp_ns]
        return True

    def _update_gyro(self) -> bool:
        """The body rotation between the two frames, integrated from the gyro samples that cover them."""
        ukf, cfg = self.ukf, self.config
        assert ukf.t_prev_ns is not None and ukf.t_cur_ns is not None
        a, b = ukf.t_prev_ns, ukf.t_cur_ns
        gap = int(cfg.gyro_max_gap_s * 1e9)
        samples = [g for g in self._gyro if a - gap <= g[0] <= b + gap]
        self._gyro = [g for g in self._gyro if g[0] >= b - gap]
        if not samples:
            return False
        ts = np.array([g[0] for g in samples], dtype=np.int64)
        if ts[0] > a + gap or ts[-1] < b - gap or (len(ts) > 1 and np.diff(ts).max() > gap):
            self.log.skip('gyro_gap', f'Imu samples do not cover the frames at {a} and {b} ns without a gap over '
                       f'{cfg.gyro_max_gap_s} s: no gyro update there')
            return False
        ws = np.array([g[1] for g in samples])
        grid = np.unique(np.r_[a, ts[(ts > a) & (ts < b)], b]).astype(np.float64)
        mids = 0.5 * (grid[1:] + grid[:-1])
        w_mid = np.stack([np.interp(mids, ts.astype(np.float64), ws[:, i]) for i in range(3)], axis=1)
        R = np.eye(3)
        for dt, w in zip(np.diff(grid) * 1e-9, w_mid):
            R = R @ matrix_from_rotvec(w * dt)
        span = (b - a) * 1e-9
        dt_sample = float(np.median(np.diff(ts))) * 1e-9 if len(ts) > 1 else span
        var = cfg.gyro_sigma_rad_s**2 * span * min(dt_sample, span) + (cfg.gyro_bias_sigma_rad_s * span) ** 2
        res = ukf.update_relative_rotation(rotvec_from_matrix(R), (var + 1e-12) * np.eye(3))
        self.updates[f'gyro_{res.status}'] += 1
        if res.status == 'gated':
            self.log.skip('gyro_gated', f'the gyro rotation between the frames at {a} and {b} ns disagrees with the '
                       f'fused attitudes (squared Mahalanobis distance {res.mahalanobis2:.1f}) and was not fused')
        return res.accepted

    def _update_homography(self, prev_H_cur: np.ndarray, covariance: np.ndarray | None, rms_px: float,
                           inliers: int) -> bool:  # kept for a future rms/inlier model
        cfg = self.config
        H = np.asarray(prev_H_cur, dtype=np.float64)
        if H.shape != (3, 3) or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
            self.log.skip('homography_invalid', 'registration homography with NaN entries or h22 = 0 ignored')
            return False
        H = H / H[2, 2]
        agl = self.mount.camera_pose(self.ukf.x[SLOT_CUR]).center_enu_m[2] - self.ground_z_m
        if agl < cfg.min_agl_m:
            self.log.skip('homography_low', f'camera {agl:.1f} m above the ground plane (< min_agl_m '
                       f'{cfg.min_agl_m}): registrations are not fused')
            return False
        corners = frame_corners(self.camera)
        R = None
        if covariance is not None:
            C = np.asarray(covariance, dtype=np.float64)
            if C.shape == (8, 8) and np.all(np.isfinite(C)):
                J = corner_jacobian(H, corners)
                R = J @ (0.5 * (C + C.T)) @ J.T
            else:
                self.log.skip('homography_covariance_invalid', 'registration covariance not an (8, 8) finite matrix: '
                           'the default from the inlier rms is used')
        if R is None:
            rms = rms_px if (rms_px is not None and math.isfinite(rms_px) and rms_px > 0) else 1.0
            R = (cfg.homography_sigma_gain * rms) ** 2 * np.eye(8)
        R = R + cfg.homography_min_sigma_px**2 * np.eye(8)
        prev_camera = self._prev_camera  # the previous frame's intrinsics (a zoom changes them)
        K_prev = prev_camera.K if prev_camera is not None and prev_camera != self.camera else None
        res = self.ukf.update_homography(H, R, self.camera.K, self.mount, corners, K_prev)
        self.updates[f'homography_{res.status}'] += 1
        if res.status == 'gated':
            self.log.skip('homography_gated', f'a registration disagrees with the fused poses (squared Mahalanobis '
                       f'distance {res.mahalanobis2:.1f}) and was not fused')
        elif res.status == 'failed':
            self.log.skip('homography_failed', 'a homography update failed numerically and was skipped')
        return res.accepted

    def _pose(self, slot: slice, stamp_ns: int, used_h: bool, n_fix: int, n_imu: int) -> FramePose:
        x = self.ukf.x.copy()
        if slot == SLOT_PREV:
            x[SLOT_CUR] = x[SLOT_PREV]
            P = self.ukf.P.copy()
            P[SLOT_CUR, SLOT_CUR] = P[SLOT_PREV, SLOT_PREV]
            return self._pose_from(x, P, stamp_ns, used_h, n_fix, n_imu, self.information.last)
        self.information.last = self.information_rate(stamp_ns)
        return self._pose_from(x, self.ukf.P, stamp_ns, used_h, n_fix, n_imu, self.information.last)

    def _pose_from(self, x: np.ndarray, P: np.ndarray, stamp_ns: int, used_h: bool, n_fix: int,
                   n_imu: int, info_rate: np.ndarray | None = None) -> FramePose:
        """FramePose of the current slot of a state (13,) and covariance (13, 13)."""
        assert self.origin is not None
        y = x[SLOT_CUR].copy()
        y[5] = wrap_angle(y[5])
        lat, lon, alt = self.origin.geodetic_from_enu(y[:3])
        return FramePose(stamp_ns, True, y[:3].copy(), y[3:].copy(), P[SLOT_CUR, SLOT_CUR].copy(), float(lat),
                         float(lon), float(alt), camera=self.mount.camera_pose(y), ground_z_m=float(x[GROUND]),
                         homography_used=used_h, fixes_used=n_fix, imu_used=n_imu, info_rate=info_rate,
                         ground_covariance=np.r_[P[GROUND, SLOT_CUR], P[GROUND, GROUND]])

    def _record(self, F: np.ndarray | None, *, virtual: bool = False) -> None:
        """Moments right after the predict to a new frame (the pose appended next is that frame's;
        ``virtual``: a filter-only step, no pose)."""
        if self.config.history_frames <= 0:
            return
        index = None if virtual else len(self.poses)
        self._history.append([index, self.ukf.x.copy(), self.ukf.P.copy(), None, None, F])
        if len(self._history) > self.config.history_frames:
            del self._history[0]
            self._history[0][5] = None

    def _close_record(self) -> None:
        """Moments right before the next predict: everything fused for the latest frame."""
        if self._history:
            self._history[-1][3] = self.ukf.x.copy()
            self._history[-1][4] = self.ukf.P.copy()

    def _camera(self, camera: CameraIntrinsics | None) -> CameraIntrinsics:
        cam = camera or self.camera
        if cam is None:
            msg = 'no camera intrinsics: pass camera= or construct the Georeferencer with them.'
            raise ValueError(msg)
        return cam





