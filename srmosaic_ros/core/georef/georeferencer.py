"""Georeferencer: the pipeline stage that turns telemetry and registrations into poses and a map plane.

    georef = Georeferencer(GeorefConfig(), camera)
    georef.feed_fix(fix); georef.feed_imu(imu)             # any time, in stamp order per sensor
    georef.feed_camera_attitude(att)                       # a measured camera orientation (gimbal, KLV)
    pose = georef.feed_frame(stamp_ns, prev_H_cur, cov)    # one FramePose per frame (fused)
    raster = georef.make_raster(pose)                      # north-up UTM grid, once
    raster_H_frame = georef.raster_H_frame(pose)           # place a frame by its pose (flat ground)
    raster_H_frame = georef.correct(chained_H, pose)       # drift control of a chained homography

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
"""
from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np

from ..types import FIX_STATUS_NO_FIX, CameraAttitude, CameraIntrinsics, GeoFix, ImuSample
from .frame_pose import FramePose
from .frames import (
    CameraPose,
    R_body_from_cam,
    matrix_from_quat_xyzw,
    matrix_from_rotvec,
    rotvec_from_matrix,
    rpy_from_R_enu_from_body,
)
from .drift import CanvasSimilarity, DriftState, InformationRate, drift_init, drift_step
from .geodetic import LocalTangentPlane
from .georef_config import GeorefConfig
from .ground_homography import apply_H, ground_H_image, normalize_H
from .raster import GeoRaster, _transformers, utm_epsg
from .ukf import GROUND, SLOT_CUR, SLOT_PREV, PoseUkf, corner_jacobian, rts_smooth, wrap_angle

__all__ = [
    'GeorefConfig',
    'FramePose',
    'GeoRaster',
    'Georeferencer',
    'utm_epsg',
    'camera_pose_from_enu_H_image',
    'sees_the_ground',
    'course_velocity',
]

_LOG = logging.getLogger(__name__)
_AFFINE_FIT_HALF_SPAN_M = 3000.0
#: Span over which the information rate of the absolute measurements is averaged (FramePose.info_rate).
INFO_RATE_WINDOW_S = 10.0
#: A measured camera attitude whose optical axis is less than this far below the horizon is not fused.
MIN_AXIS_DEPRESSION_DEG = 5.0


def sees_the_ground(R_enu_from_cam: np.ndarray) -> bool:
    """Whether a camera of this orientation (optical frame in ENU, (3, 3)) looks at least
    MIN_AXIS_DEPRESSION_DEG below the horizon: nearer the horizon the flat-ground model cannot place
    its frames, and the georeferencer leaves the attitude out."""
    return bool(R_enu_from_cam[2, 2] <= -math.sin(math.radians(MIN_AXIS_DEPRESSION_DEG)))


#: A turn is taken from the fixes before the first frame when their track's quadratic term stands
#: this many standard errors above its noise.
TURN_SIGNIFICANCE = 3.0


def course_velocity(t_s: np.ndarray, xy_m: np.ndarray) -> np.ndarray:
    """(2,) horizontal velocity (m/s) at t = 0 of a track of fixes at times ``t_s`` (n,) <= 0 and
    positions ``xy_m`` (n, 2), n >= 6: from a quadratic fit when the track turns significantly
    (its quadratic term above TURN_SIGNIFICANCE standard errors, the noise taken from the fit's
    residuals), else from a straight-line fit. A chord or a line over the window lags a turn by
    half of it (an orbit at 11 deg/s: 30 deg over 5 s); a quadratic's end slope is noisier on a
    straight track (an oblique line's corners 0.26 -> 0.43 px)."""
    A = np.stack([t_s**2, t_s, np.ones_like(t_s)], axis=1)
    coef, *_ = np.linalg.lstsq(A, xy_m, rcond=None)
    dof = len(t_s) - 3
    var = float(np.sum((xy_m - A @ coef) ** 2)) / (2 * dof)  # per coordinate
    sd_quadratic = math.sqrt(var * float(np.linalg.inv(A.T @ A)[0, 0]))
    # |c2| / sd is chi with 2 dof on a straight track: above 3 by chance 1.1 % of the time
    if np.linalg.norm(coef[0]) > TURN_SIGNIFICANCE * max(sd_quadratic, 1e-12):
        return coef[1]
    return np.polyfit(t_s, xy_m, 1)[0]


def camera_pose_from_enu_H_image(K: np.ndarray, enu_H_image: np.ndarray, *,
                                 ground_z_m: float = 0.0) -> CameraPose:
    """Camera pose of a flat-ground homography: the inverse of :func:`ground_H_image`.

    image_H_ground = K R^T [e1, e2, P0 - C] up to scale (P0 = (0, 0, ground_z_m)); the two first
    columns give R (orthonormalised by SVD), the third the centre, with the sign that puts the
    camera above the ground.
    """
    K_inv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    A = K_inv @ np.linalg.inv(np.asarray(enu_H_image, dtype=np.float64))  # K^-1 image_H_ground
    lam = 0.5 * (np.linalg.norm(A[:, 0]) + np.linalg.norm(A[:, 1]))
    best = None
    for sign in (1.0, -1.0):
        B = sign * A / lam
        M = np.c_[B[:, 0], B[:, 1], np.cross(B[:, 0], B[:, 1])]  # columns: R^T e1, R^T e2, R^T e3
        u, _, vt = np.linalg.svd(M)
        Rt = u @ vt  # R_cam_from_enu
        if np.linalg.det(Rt) < 0:
            continue
        R = Rt.T  # R_enu_from_cam
        center = np.array([0.0, 0.0, ground_z_m]) - R @ B[:, 2]
        if center[2] > ground_z_m and best is None:
            best = CameraPose(R, center)
    if best is None:
        msg = 'the homography does not describe a camera above the ground plane.'
        raise ValueError(msg)
    return best


class Georeferencer:
    """Fuses GNSS, IMU and registrations into one pose per frame; places frames on a UTM raster.

    Args:
        config: the ``georef.`` parameters.
        camera: intrinsics of the frames (may also come with each ``feed_frame``).
    """

    def __init__(self, config: GeorefConfig | None = None, camera: CameraIntrinsics | None = None) -> None:
        self.config = config or GeorefConfig()
        self.camera = camera
        self.mount = self.config.mount
        self.ukf = PoseUkf(self.config.ukf_params)
        self.origin: LocalTangentPlane | None = None
        self.ground_altitude_m: float = float('nan')
        self.raster: GeoRaster | None = None
        self.poses: list[FramePose] = []
        self.skipped: Counter[str] = Counter()
        self.updates: Counter[str] = Counter()
        self._warned: set[str] = set()
        self._pending: list[tuple[int, int, str, np.ndarray, np.ndarray]] = []  # (stamp, seq, kind, z, R)
        self._gyro: list[tuple[int, np.ndarray]] = []  # (stamp, body angular velocity rad/s)
        # per filtered frame: [pose index, x_pred, P_pred, x_post, P_post, F] for the smoother
        self._history: list[list] = []
        self._seq = 0
        self._last_stamp: dict[str, int] = {}
        self._utm_affines: dict[int, np.ndarray] = {}
        self._drift: DriftState | None = None
        self._canvas: CanvasSimilarity | None = None
        self._last_info_rate: np.ndarray | None = None
        # absolute measurements fused (R^-1 of the fixes, of the IMU attitudes) for FramePose.info_rate
        self._info = {'fix': InformationRate(3, INFO_RATE_WINDOW_S), 'imu': InformationRate(3, INFO_RATE_WINDOW_S)}

    @property
    def ground_z_m(self) -> float:
        """Current estimate of the ground plane's height in the ENU plane (0 before the first frame)."""
        return self.ukf.ground_z[0] if self.ukf.initialized else 0.0

    # -- telemetry -----------------------------------------------------------------------------
    def feed_fix(self, fix: GeoFix) -> None:
        """A GNSS fix (WGS84). Skipped with a warning: NO_FIX, NaN/out-of-range fields, old stamps."""
        if fix.status <= FIX_STATUS_NO_FIX:
            self._skip('fix_no_fix', 'GNSS fix with status NO_FIX ignored')
            return
        if not all(math.isfinite(v) for v in (fix.latitude_deg, fix.longitude_deg, fix.altitude_m)):
            self._skip('fix_nan', 'GNSS fix with NaN latitude, longitude or altitude ignored')
            return
        if abs(fix.latitude_deg) >= 90.0 or abs(fix.longitude_deg) > 180.0:
            self._skip('fix_range', f'GNSS fix at impossible ({fix.latitude_deg}, {fix.longitude_deg}) ignored')
            return
        if not self._in_order('fix', fix.stamp_ns):
            return
        R = self._fix_covariance(fix)
        if self.origin is None:
            self._set_origin(fix)
        assert self.origin is not None
        enu = self.origin.enu_from_geodetic(fix.latitude_deg, fix.longitude_deg, fix.altitude_m)
        self._telemetry('fix', int(fix.stamp_ns), np.asarray(enu, dtype=np.float64), R)

    def feed_imu(self, imu: ImuSample) -> None:
        """An IMU sample: its orientation (body in ENU, REP 145) and its angular velocity (body frame,
        integrated between frames) are fused; the acceleration is not used."""
        if not self._in_order('imu', imu.stamp_ns):
            return
        w = np.asarray(imu.angular_velocity_rad_s, dtype=np.float64)
        if w.shape == (3,) and np.all(np.isnan(w)):
            self.skipped['imu_no_rate'] += 1  # not provided (flight log, EXIF): orientation only, no gyro update
        elif w.shape == (3,) and np.all(np.isfinite(w)):
            self._gyro.append((int(imu.stamp_ns), w))
            if self.ukf.initialized:
                keep_from = int(self.ukf.t_prev_ns or 0) - int(self.config.gyro_max_gap_s * 1e9)
            else:
                keep_from = int(imu.stamp_ns) - int(self.config.telemetry_buffer_s * 1e9)
            if self._gyro[0][0] < keep_from:
                self._gyro = [g for g in self._gyro if g[0] >= keep_from]
        else:
            self._skip('imu_gyro_nan', 'Imu angular velocity with NaN fields ignored')
        q = imu.orientation_xyzw
        if q is None:
            self._skip('imu_no_orientation', 'Imu messages without orientation (covariance[0] = -1): only their '
                       'angular velocity is used')
            return
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or not 0.5 < np.linalg.norm(q) < 1.5:
            self._skip('imu_nan', 'Imu orientation with NaN fields or not a unit quaternion ignored')
            return
        rpy = np.array(rpy_from_R_enu_from_body(matrix_from_quat_xyzw(q)))
        cov = np.asarray(imu.orientation_covariance, dtype=np.float64)
        default = math.radians(self.config.imu_sigma_deg) ** 2 * np.eye(3)
        cov = cov.reshape(3, 3) if cov.size == 9 else default
        known = np.all(np.isfinite(cov)) and np.trace(cov) > 0.0
        if not (known and np.all(np.linalg.eigvalsh(0.5 * (cov + cov.T)) >= 0.0)):
            cov = default
        self._telemetry('imu', int(imu.stamp_ns), rpy, 0.5 * (cov + cov.T) + 1e-10 * np.eye(3))

    def feed_camera_attitude(self, attitude: CameraAttitude) -> None:
        """A measured orientation of the camera (gimbal angles, KLV sensor angles) in ENU.

        It is fused as the body attitude that the configured mount implies
        (``R_enu_from_body = R_enu_from_cam R_body_from_cam^T``), so the filter's camera is the
        measured one whatever the mount; its isotropic sigma (else ``imu_sigma_deg``) is carried
        to roll, pitch and yaw through the Jacobian of that map. Cameras looking at or above the
        horizon (optical axis less than 5 degrees below it) cannot see a ground plane and are skipped.
        """
        if not self._in_order('camera_attitude', attitude.stamp_ns):
            return
        R_ec = np.asarray(attitude.R_enu_from_cam, dtype=np.float64)
        if R_ec.shape != (3, 3) or not np.all(np.isfinite(R_ec)) or abs(np.linalg.det(R_ec) - 1.0) > 1e-3:
            self._skip('camera_attitude_nan', 'camera attitude with NaN fields or not a rotation ignored')
            return
        if not sees_the_ground(R_ec):
            self._skip('camera_attitude_horizon', 'camera attitude looking at or above the horizon ignored: the '
                       'flat-ground model cannot place such frames')
            return
        sigma = attitude.sigma_rad if math.isfinite(attitude.sigma_rad) and attitude.sigma_rad > 0 \
            else math.radians(self.config.imu_sigma_deg)
        R_cb = R_body_from_cam(self.mount.gimbal_azimuth_rad, self.mount.gimbal_elevation_rad).T

        def rpy_of(dv: np.ndarray) -> np.ndarray:
            return np.array(rpy_from_R_enu_from_body(matrix_from_rotvec(dv) @ R_ec @ R_cb))

        rpy = rpy_of(np.zeros(3))
        J = np.empty((3, 3))  # d rpy / d small rotation of the camera (ENU rotation vector)
        for i in range(3):
            d = np.zeros(3)
            d[i] = 1e-6
            diff = rpy_of(d) - rpy_of(-d)
            J[:, i] = np.array([wrap_angle(v) for v in diff]) / 2e-6
        cov = sigma**2 * J @ J.T
        self._telemetry('imu', int(attitude.stamp_ns), rpy, 0.5 * (cov + cov.T) + 1e-10 * np.eye(3))

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
            self._skip('frame_out_of_order', f'frame at {stamp_ns} ns is not after the previous frame; no pose')
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
                self._skip('homography_no_camera', 'the frames carry no camera model (no intrinsics; stills '
                           'without gimbal angles get none: their geotags place them): registrations are not fused')
            elif prev_H_cur is not None and bridged:
                self._skip('homography_after_gap', f'frames more than max_step_s = {self.config.max_step_s} s apart: '
                           'their registration is not fused (the filter bridged the gap on telemetry)')
            elif prev_H_cur is not None and ref_stamp_ns is not None and int(ref_stamp_ns) != self.ukf.t_prev_ns:
                self._skip('homography_not_consecutive', 'a registration to a frame other than the previous one '
                           'cannot be fused by the two-pose filter; it was skipped')
            elif prev_H_cur is not None:
                used_h = self._update_homography(prev_H_cur, covariance, rms_px, inliers)
        n_fix, n_imu = self._apply_pending()
        pose = self._pose(SLOT_CUR, stamp_ns, used_h, n_fix, n_imu)
        self.poses.append(pose)
        self._prev_camera = self.camera  # the next registration maps into this frame
        self._check_raster_agl(pose)
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

    # -- raster and placement ------------------------------------------------------------------
    def make_raster(self, pose: FramePose, camera: CameraIntrinsics | None = None, *,
                    gsd_m_per_px: float | None = None, coarsen: float = 1.0) -> GeoRaster:
        """The north-up UTM raster of this flight (created once, then returned as is).

        gsd: ``gsd_m_per_px``, else the config's, else the ground sampling of ``pose``'s frame at its
        centre (height above ground / fx) times ``coarsen`` (>= 1: a mosaic coarser than large
        frames), rounded to two significant digits. Pixel (0, 0) is the ground point under the frame
        centre, snapped to the gsd grid.
        """
        if self.raster is not None:
            return self.raster
        cam = self._camera(camera)
        if not pose.valid or self.origin is None:
            msg = 'make_raster needs a valid pose (a GNSS fix must have been fed before the frame).'
            raise ValueError(msg)
        gsd = gsd_m_per_px if gsd_m_per_px is not None else self.config.gsd_m_per_px
        if not (gsd and math.isfinite(gsd) and gsd > 0):
            agl = max(float(pose.camera.center_enu_m[2]) - _ground(pose), self.config.min_agl_m, 1.0) \
                if pose.camera is not None else self.config.nominal_agl_m
            # the depth of the ground under the principal point: the height for a nadir camera,
            # the slant range / sin(depression) along the axis of an oblique one (full resolution across the range)
            down = -float(pose.camera.R_enu_from_cam[2, 2]) if pose.camera is not None else 1.0
            raw = agl / max(down, 0.1) / math.sqrt(cam.fx * cam.fy) * max(coarsen, 1.0)
            gsd = float(f'{raw:.2g}')
            self._raster_agl_m = float(agl)  # checked against the filter's later estimate (_check_raster_agl)
        epsg = utm_epsg(self.origin.lat0_deg, self.origin.lon0_deg)
        utm_A_enu = self._utm_affine(epsg)
        enu_H_frame = self._enu_H_frame(pose, cam)
        centre_en = apply_H(utm_A_enu @ enu_H_frame, np.array([[cam.cx, cam.cy]]))[0]
        e0, n0 = (round(float(v) / gsd) * gsd for v in centre_en)
        self.raster = GeoRaster(epsg, gsd, e0, n0)
        return self.raster

    def drop_raster(self) -> None:
        """Forget the raster and the drift controller: the mosaic is not placed by the poses after
        all (pipeline: pose_check.py); the filter goes on giving poses."""
        self.raster = None
        self.__dict__.pop('_raster_agl_m', None)  # nothing painted at its sampling: no warning about it
        self.reset_drift(new_canvas=True)

    def raster_H_enu(self, raster: GeoRaster | None = None) -> np.ndarray:
        """(3, 3) ENU ground (east, north, 1) -> raster pixel (x, y, 1) (affine)."""
        raster = self._raster(raster)
        return raster.raster_H_utm @ self._utm_affine(raster.epsg)

    def raster_H_frame(self, pose: FramePose, camera: CameraIntrinsics | None = None,
                       raster: GeoRaster | None = None) -> np.ndarray:
        """(3, 3) frame pixels -> raster pixels of the flat ground seen from ``pose`` (normalised)."""
        return normalize_H(self.raster_H_enu(raster) @ self._enu_H_frame(pose, self._camera(camera)))

    def correct(self, raster_H_frame_chained: np.ndarray, pose: FramePose,
                camera: CameraIntrinsics | None = None, raster: GeoRaster | None = None, *,
                chain_sigma_px: float | None = None) -> np.ndarray:
        """Drift control: fuse a chained frame -> raster homography with the pose-predicted one.

        A Kalman filter over the chain's corner error, the canvas's similarity error and the pose
        error (drift.py has the model and its equations). The chain is precise from frame to
        frame; its error grows by ``chain_sigma_px`` per call (the registration's corner noise:
        pass it from the registration's covariance, see :meth:`corner_sigma_px`; default
        ``drift_chain_sigma_px``) and is carried along the chain. The pose-predicted corners carry
        the error of the fused pose and ground height (``pose.pose_ground_covariance``; the ground
        is taken as exact when ``pose.ground_covariance`` is not known), a Gauss-Markov process
        whose time constants come from the pose filter (``pose.info_rate``: how fast the fixes and
        attitudes renew it, and how fast the pose's own covariance shrinks) over the actual frame
        spacing (the stamps), or from ``drift_pose_time_constant_s`` when it is set; plus the
        flat-ground model error ``homography_min_sigma_px``. The frames are placed in the canvas
        frame: the raster as the first chain's anchor put it, which differs from the true one by a
        similarity (offset, rotation, scale; see :attr:`canvas_similarity`) that the offline
        re-anchoring takes out; drift control does not bend the mosaic to follow it, it corrects
        the chain's drift and the rest of the anchor error. Slow pose wander is not copied into
        the mosaic. The corrected homography maps the frame corners exactly onto the filtered
        corners. Feed the result back into the chain (``raster_H_next = corrected @ cur_H_next``).

        The first call after :meth:`reset_drift` anchors a new chain: the first chain of a canvas
        where it is (returned unchanged), a later one in the canvas frame (the estimated
        similarity applied). An invalid pose leaves the chain unchanged (its uncertainty grows).
        """
        chained = normalize_H(np.asarray(raster_H_frame_chained, dtype=np.float64))
        cam = self._camera(camera)
        corners = _frame_corners(cam)
        cfg = self.config
        measured = None
        if pose.valid and np.all(np.isfinite(pose.covariance)):
            z, J = self._corner_prediction(pose, cam, corners, raster)
            measured = (pose.stamp_ns, z.ravel(), J, pose.pose_ground_covariance)
        if self._drift is None:
            if measured is None:
                return chained
            self._drift, placed = drift_init(chained, pose.stamp_ns, measured[3], measured[2], corners, self._canvas)
            self._canvas = self._drift.canvas
            return placed
        step = cfg.drift_chain_sigma_px if chain_sigma_px is None else float(chain_sigma_px)
        info = pose.info_rate if pose.info_rate is not None else self._last_info_rate
        if info is not None:
            info = np.pad(np.asarray(info, dtype=np.float64), ((0, 1), (0, 1)))  # nothing measures the ground alone
        out = drift_step(self._drift, chained, corners, step, measured, model_sigma_px=cfg.homography_min_sigma_px,
                         info_rate=info, time_constant_s=cfg.drift_pose_time_constant_s)
        self._canvas = self._drift.canvas
        return out

    def corner_sigma_px(self, prev_H_cur: np.ndarray, covariance: np.ndarray | None,
                        camera: CameraIntrinsics | None = None) -> float:
        """RMS standard deviation (px) of the frame corners under a registration's (8, 8) covariance of
        h (:func:`corner_jacobian`), or ``drift_chain_sigma_px`` when there is none."""
        if covariance is None:
            return self.config.drift_chain_sigma_px
        H = np.asarray(prev_H_cur, dtype=np.float64)
        J = corner_jacobian(H / H[2, 2], _frame_corners(self._camera(camera)))
        return float(math.sqrt(max(np.trace(J @ np.asarray(covariance, dtype=np.float64) @ J.T) / 8.0, 0.0)))

    def reset_drift(self, *, new_canvas: bool = False) -> None:
        """Forget the drift controller's chain (a new mosaic segment starts). The next chain is placed
        in the same canvas frame (the similarity estimated so far applied to its first placement)
        unless ``new_canvas``: then it defines a canvas of its own, as the first chain did."""
        self._drift = None
        if new_canvas:
            self._canvas = None

    @property
    def drift_nis(self) -> float:
        """The normalised innovation squared of the last :meth:`correct` (pose-predicted corners
        against the chained ones, chi-square with 8 dof when they agree; see pose_check.py); NaN
        when that call fused no pose or anchored a chain."""
        return float('nan') if self._drift is None else self._drift.nis

    @property
    def canvas_similarity(self) -> np.ndarray | None:
        """(3, 3) the drift controller's estimate of the similarity between the true raster and the
        canvas frame (true raster pixel -> canvas pixel; see drift.py), or None before a chain."""
        return None if self._canvas is None else self._canvas.homography

    # -- internals -----------------------------------------------------------------------------
    def _check_raster_agl(self, pose: FramePose) -> None:
        """Warn once when the raster's ground sampling was chosen for a height above the ground that
        the filter, once the ground height is known to 10%, puts more than 20% away: at the first
        frame the ground is a guess (the first fix minus georef.nominal_agl_m) unless
        georef.ground_altitude_m is given, so a low flight gets a coarser mosaic than its frames."""
        agl0 = self.__dict__.get('_raster_agl_m')
        if agl0 is None or 'raster_gsd_agl' in self._warned or not pose.valid or pose.camera is None:
            return
        agl = float(pose.camera.center_enu_m[2]) - _ground(pose)
        ground_var = self.ukf.ground_z[1] if self.ukf.initialized else float('inf')
        if not (agl > 0 and math.sqrt(max(ground_var, 0.0)) < 0.1 * agl):
            return
        if abs(agl / agl0 - 1.0) > 0.2:
            self.skipped['raster_gsd_agl'] += 1
            self._warned.add('raster_gsd_agl')
            _LOG.warning(
                'the mosaic raster samples the ground at %.3g m/px, chosen for %.0f m above the ground at the first '
                'frame; the filter now puts the camera %.0f m above it, so the frames are painted at %.0f%% of their '
                'own resolution. Set georef.ground_altitude_m (the ground\'s ellipsoidal height), '
                'georef.nominal_agl_m or georef.gsd_m_per_px for this flight.',
                self.raster.gsd_m_per_px if self.raster is not None else float('nan'), agl0, agl, 100.0 * min(agl / agl0, 1.0))

    def _skip(self, kind: str, message: str) -> None:
        self.skipped[kind] += 1
        if kind not in self._warned:
            self._warned.add(kind)
            _LOG.warning('%s (further ones are counted in skipped[%r], not logged).', message, kind)

    def _in_order(self, sensor: str, stamp_ns: int) -> bool:
        last = self._last_stamp.get(sensor)
        if last is not None and int(stamp_ns) <= last:
            self._skip(f'{sensor}_out_of_order', f'{sensor} message at {stamp_ns} ns not after the previous one '
                       f'({last} ns) ignored')
            return False
        self._last_stamp[sensor] = int(stamp_ns)
        return True

    def _fix_covariance(self, fix: GeoFix) -> np.ndarray:
        cfg = self.config
        default = np.diag([cfg.gps_sigma_h_m**2, cfg.gps_sigma_h_m**2, cfg.gps_sigma_v_m**2])
        cov = np.asarray(fix.position_covariance_m2, dtype=np.float64)
        if fix.covariance_type <= 0 or cov.size != 9:
            return default
        cov = cov.reshape(3, 3)
        cov = 0.5 * (cov + cov.T)
        if not np.all(np.isfinite(cov)):
            self._skip('fix_covariance_nan', 'GNSS fix covariance with NaN fields: the default sigmas are used')
            return default
        if np.trace(cov) <= 0.0 or np.min(np.linalg.eigvalsh(cov)) < 0.0:
            return default
        return cov + 1e-4 * np.eye(3)

    def _set_origin(self, fix: GeoFix) -> None:
        ground = self.config.ground_altitude_m
        if not math.isfinite(ground):
            ground = fix.altitude_m - self.config.nominal_agl_m
        self.ground_altitude_m = float(ground)
        self.origin = LocalTangentPlane(fix.latitude_deg, fix.longitude_deg, self.ground_altitude_m)

    def _telemetry(self, kind: str, stamp_ns: int, z: np.ndarray, R: np.ndarray) -> None:
        ukf = self.ukf
        if ukf.initialized:
            assert ukf.t_prev_ns is not None and ukf.t_cur_ns is not None
            if stamp_ns < ukf.t_prev_ns:
                self._skip(f'{kind}_stale', f'{kind} message at {stamp_ns} ns is older than the filter window '
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
            self._skip(f'{kind}_gated', f'{kind} at {stamp_ns} ns disagrees with the fused state '
                       f'(squared Mahalanobis distance {res.mahalanobis2:.1f}) and was not fused')
        elif res.status == 'failed':
            self._skip(f'{kind}_failed', f'{kind} update at {stamp_ns} ns failed numerically and was skipped')
        if res.accepted:
            self._add_information(kind, stamp_ns, R)
        return res.accepted

    def _add_information(self, kind: str, stamp_ns: int, R: np.ndarray) -> None:
        """Count an absolute measurement fused (a fix: position block; an attitude: attitude block)."""
        try:
            info = np.linalg.inv(0.5 * (R + R.T))
        except np.linalg.LinAlgError:
            return
        self._info[kind].add(stamp_ns, info)

    def information_rate(self, stamp_ns: int) -> np.ndarray:
        """(6, 6) information per second of the absolute measurements fused before ``stamp_ns``: fixes
        in the position block, IMU attitudes in the attitude block, each averaged over the last
        ``INFO_RATE_WINDOW_S`` (see FramePose.info_rate and drift.InformationRate); call it with
        non-decreasing stamps."""
        out = np.zeros((6, 6))
        out[:3, :3] = self._info['fix'].rate(stamp_ns)
        out[3:, 3:] = self._info['imu'].rate(stamp_ns)
        return out

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
                self._skip(f'{kind}_stale', f'{kind} message at {stamp} ns is older than the filter window and was '
                           'ignored')
            elif self._apply(kind, stamp, z, R):
                n_fix += kind == 'fix'
                n_imu += kind == 'imu'
        self._pending = keep
        return n_fix, n_imu

    def _initialize(self, stamp_ns: int) -> bool:
        """Start the filter at the first frame that has a fix before it (or the nearest fix)."""
        fixes = [p for p in self._pending if p[2] == 'fix']
        if not fixes:
            return False
        cfg = self.config
        before = [p for p in fixes if p[0] <= stamp_ns]
        fix = before[-1] if before else min(fixes, key=lambda p: abs(p[0] - stamp_ns))
        gap_s = abs(fix[0] - stamp_ns) * 1e-9
        if gap_s > cfg.telemetry_buffer_s:  # a frame far from any fix (a still without its time): wait for a nearer one
            self._skip('no_fix_near_frame', f'no GNSS fix within telemetry_buffer_s ({cfg.telemetry_buffer_s:g} s) of '
                       f'the frame at {stamp_ns} ns: the filter starts at a later frame')
            return False
        cov = np.zeros((6, 6))
        pose = np.zeros(6)
        pose[:3] = fix[3]
        cov[:3, :3] = fix[4] + (cfg.initial_speed_sigma_m_s * gap_s) ** 2 * np.eye(3)
        imus = [p for p in self._pending if p[2] == 'imu']

        def course_yaw() -> tuple[float, float]:
            recent = [p for p in fixes if p[0] >= fix[0] - 5_000_000_000 and p[0] <= fix[0]]
            d = recent[-1][3][:2] - recent[0][3][:2]
            if np.hypot(*d) <= 3.0 * math.sqrt(fix[4][0, 0]):
                return 0.0, math.radians(90.0)
            t = np.array([(p[0] - fix[0]) * 1e-9 for p in recent])
            if len(recent) < 6 or np.ptp(t) < 2.0:
                return math.atan2(d[1], d[0]), math.radians(20.0)
            v = course_velocity(t, np.array([p[3][:2] for p in recent]))
            return math.atan2(v[1], v[0]), math.radians(20.0)

        if imus:
            imu = min(imus, key=lambda p: abs(p[0] - stamp_ns))
            gap_s = abs(imu[0] - stamp_ns) * 1e-9
            pose[3:] = imu[3]
            cov[3:, 3:] = imu[4] + (math.radians(cfg.initial_rate_sigma_deg_s) * gap_s) ** 2 * np.eye(3)
        else:
            yaw, yaw_sigma = course_yaw()
            self._skip('no_attitude', 'no Imu orientation before the first frame: level attitude and yaw from the '
                       'course over ground assumed; the first homographies may be gated')
            pose[3:] = (0.0, 0.0, yaw)
            cov[3:, 3:] = np.diag([math.radians(5.0) ** 2, math.radians(5.0) ** 2, yaw_sigma**2])
        if math.isfinite(cfg.ground_altitude_m):
            ground_var = cfg.ground_altitude_sigma_m**2
        else:
            ground_var = cfg.nominal_agl_sigma_m**2 + float(fix[4][2, 2])
        self.ukf.initialize(stamp_ns, pose, cov, 0.0, ground_var)
        self._add_information('fix', fix[0], fix[4])
        if imus:
            self._add_information('imu', imu[0], imu[4])
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
            self._skip('gyro_gap', f'Imu samples do not cover the frames at {a} and {b} ns without a gap over '
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
            self._skip('gyro_gated', f'the gyro rotation between the frames at {a} and {b} ns disagrees with the '
                       f'fused attitudes (squared Mahalanobis distance {res.mahalanobis2:.1f}) and was not fused')
        return res.accepted

    def _update_homography(self, prev_H_cur: np.ndarray, covariance: np.ndarray | None, rms_px: float,
                           inliers: int) -> bool:  # kept for a future rms/inlier model
        cfg = self.config
        H = np.asarray(prev_H_cur, dtype=np.float64)
        if H.shape != (3, 3) or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
            self._skip('homography_invalid', 'registration homography with NaN entries or h22 = 0 ignored')
            return False
        H = H / H[2, 2]
        agl = self.mount.camera_pose(self.ukf.x[SLOT_CUR]).center_enu_m[2] - self.ground_z_m
        if agl < cfg.min_agl_m:
            self._skip('homography_low', f'camera {agl:.1f} m above the ground plane (< min_agl_m '
                       f'{cfg.min_agl_m}): registrations are not fused')
            return False
        corners = _frame_corners(self.camera)
        R = None
        if covariance is not None:
            C = np.asarray(covariance, dtype=np.float64)
            if C.shape == (8, 8) and np.all(np.isfinite(C)):
                J = corner_jacobian(H, corners)
                R = J @ (0.5 * (C + C.T)) @ J.T
            else:
                self._skip('homography_covariance_invalid', 'registration covariance not an (8, 8) finite matrix: '
                           'the default from the inlier rms is used')
        if R is None:
            rms = rms_px if (rms_px is not None and math.isfinite(rms_px) and rms_px > 0) else 1.0
            R = (cfg.homography_sigma_gain * rms) ** 2 * np.eye(8)
        R = R + cfg.homography_min_sigma_px**2 * np.eye(8)
        prev_camera = getattr(self, '_prev_camera', None)  # the previous frame's intrinsics (a zoom changes them)
        K_prev = prev_camera.K if prev_camera is not None and prev_camera != self.camera else None
        res = self.ukf.update_homography(H, R, self.camera.K, self.mount, corners, K_prev)
        self.updates[f'homography_{res.status}'] += 1
        if res.status == 'gated':
            self._skip('homography_gated', f'a registration disagrees with the fused poses (squared Mahalanobis '
                       f'distance {res.mahalanobis2:.1f}) and was not fused')
        elif res.status == 'failed':
            self._skip('homography_failed', 'a homography update failed numerically and was skipped')
        return res.accepted

    def _pose(self, slot: slice, stamp_ns: int, used_h: bool, n_fix: int, n_imu: int) -> FramePose:
        x = self.ukf.x.copy()
        if slot == SLOT_PREV:
            x[SLOT_CUR] = x[SLOT_PREV]
            P = self.ukf.P.copy()
            P[SLOT_CUR, SLOT_CUR] = P[SLOT_PREV, SLOT_PREV]
            return self._pose_from(x, P, stamp_ns, used_h, n_fix, n_imu, self._last_info_rate)
        self._last_info_rate = self.information_rate(stamp_ns)
        return self._pose_from(x, self.ukf.P, stamp_ns, used_h, n_fix, n_imu, self._last_info_rate)

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

    def _raster(self, raster: GeoRaster | None) -> GeoRaster:
        raster = raster or self.raster
        if raster is None:
            msg = 'no raster yet: call make_raster(pose) first (or pass raster=).'
            raise ValueError(msg)
        return raster

    def _enu_H_frame(self, pose: FramePose, cam: CameraIntrinsics) -> np.ndarray:
        if not pose.valid or pose.camera is None:
            msg = f'the pose of frame {pose.stamp_ns} is not valid ({pose.reason}); it cannot place the frame.'
            raise ValueError(msg)
        return ground_H_image(cam.K, pose.camera.R_enu_from_cam, pose.camera.center_enu_m, ground_z_m=_ground(pose))

    def _utm_affine(self, epsg: int) -> np.ndarray:
        """(3, 3) affine ENU (east, north, 1) on the ground plane -> UTM (easting, northing, 1), fitted once."""
        if epsg in self._utm_affines:
            return self._utm_affines[epsg]
        if self.origin is None:
            msg = 'no origin yet: feed a GNSS fix first.'
            raise ValueError(msg)
        s = np.linspace(-_AFFINE_FIT_HALF_SPAN_M, _AFFINE_FIT_HALF_SPAN_M, 7)
        e, n = np.meshgrid(s, s)
        enu = np.stack([e.ravel(), n.ravel(), np.zeros(e.size)], axis=1)
        lat, lon, _ = self.origin.geodetic_from_enu(enu)
        east, north = _transformers(epsg)[0].transform(lon, lat)
        X = np.c_[enu[:, :2], np.ones(len(enu))]
        coef, *_ = np.linalg.lstsq(X, np.c_[east, north], rcond=None)
        A = np.eye(3)
        A[:2, :] = coef.T
        self._utm_affines[epsg] = A
        return A

    def _corner_prediction(self, pose: FramePose, cam: CameraIntrinsics, corners: np.ndarray,
                           raster: GeoRaster | None) -> tuple[np.ndarray, np.ndarray]:
        """Raster corners (4, 2) of the frame placed by ``pose`` and their Jacobian (8, 7) with respect
        to (east, north, up, roll, pitch, yaw, ground_z_m) (numerical), corners flattened x0, y0, x1, ..."""
        y0 = np.r_[pose.pose6, _ground(pose)]
        steps = np.array([0.1, 0.1, 0.1, 1e-4, 1e-4, 1e-4, 0.1])
        ys = np.concatenate([y0[None], y0 + np.diag(steps), y0 - np.diag(steps)])     # (15, 7)
        cp0 = self.mount.camera_pose(y0[:6])
        R = np.empty((len(ys), 3, 3))
        C = np.empty((len(ys), 3))
        for k, yg in enumerate(ys):
            if np.array_equal(yg[3:6], y0[3:6]):
                # the body's position and the ground height do not turn the camera: its centre
                # moves with the body (the lever arm turns with the attitude only)
                R[k], C[k] = cp0.R_enu_from_cam, cp0.center_enu_m + (yg[:3] - y0[:3])
            else:
                cp = self.mount.camera_pose(yg[:6])
                R[k], C[k] = cp.R_enu_from_cam, cp.center_enu_m
        # image_H_ground = K R^T M (ground_homography.py), for all 15 poses at once
        M = np.zeros((len(ys), 3, 3))
        M[:, 0, 0] = M[:, 1, 1] = 1.0
        M[:, 0, 2], M[:, 1, 2], M[:, 2, 2] = -C[:, 0], -C[:, 1], ys[:, 6] - C[:, 2]
        H = self.raster_H_enu(raster) @ np.linalg.inv(np.asarray(cam.K, dtype=np.float64) @ R.transpose(0, 2, 1) @ M)
        p = H @ np.c_[corners, np.ones(len(corners))].T                              # (15, 3, 4)
        c = (p[:, :2] / p[:, 2:3]).transpose(0, 2, 1).reshape(len(ys), -1)           # (15, 8)
        J = (c[1:8] - c[8:]).T / (2.0 * steps)
        return c[0].reshape(4, 2), J


def _ground(pose: FramePose) -> float:
    return pose.ground_z_m if math.isfinite(pose.ground_z_m) else 0.0


def _frame_corners(cam: CameraIntrinsics) -> np.ndarray:
    """(4, 2) corner pixel centres of a frame, clockwise from the top-left."""
    w, h = cam.width, cam.height
    return np.array([[0.0, 0.0], [w - 1.0, 0.0], [w - 1.0, h - 1.0], [0.0, h - 1.0]])
