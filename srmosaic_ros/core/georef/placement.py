"""The flight's north-up UTM raster and drift control: where frames go on the map (the placing half of
the Georeferencer, which owns one and gives it the local tangent plane's origin).

    placement.make_raster(pose, camera)                 # once: gsd from the frame's ground sampling
    raster_H_frame = placement.raster_H_frame(pose, camera)
    raster_H_frame = placement.correct(chained_H, pose, camera)   # drift control (drift.py)

Raster pixel (x, y) (x right, y down, pixel centres at integers) is at easting ``e0 + gsd x``,
northing ``n0 - gsd y`` of the flight's UTM zone; ENU and UTM differ by the grid convergence and the
UTM scale factor, an affine map over a UAS flight (fitted once over +-3 km).
"""
from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING

import numpy as np

from .drift import CanvasSimilarity, DriftState, drift_init, drift_step, scaled_drift, scaled_similarity
from .ground_homography import apply_H, ground_H_image, normalize_H
from .raster import GeoRaster, _transformers, utm_epsg
from .ukf import corner_jacobian

if TYPE_CHECKING:
    from ..types import CameraIntrinsics
    from .frame_pose import FramePose
    from .geodetic import LocalTangentPlane
    from .georef_config import GeorefConfig
    from .ukf import CameraMount
    from .skip_log import SkipLog

__all__ = ['RasterPlacement', 'frame_corners', 'ground_of']

_LOG = logging.getLogger('srmosaic_ros.core.georef.georeferencer')  # the Georeferencer's log, as before the split
_AFFINE_FIT_HALF_SPAN_M = 3000.0


class RasterPlacement:
    """The raster (None until :meth:`make_raster`) and the drift controller of the current chain.

    Args:
        config: the ``georef.`` parameters.
        mount: how the camera sits on the body (turns a body pose into the camera's).
    """

    def __init__(self, config: GeorefConfig, mount: CameraMount) -> None:
        self.config = config
        self.mount = mount
        self.origin: LocalTangentPlane | None = None  # the Georeferencer's, from its first fix
        self.raster: GeoRaster | None = None
        self._raster_agl_m: float | None = None  # the height the raster's gsd was chosen for
        self._utm_affines: dict[int, np.ndarray] = {}
        self._drift: DriftState | None = None
        self._canvas: CanvasSimilarity | None = None

    def make_raster(self, pose: FramePose, camera: CameraIntrinsics | None, *,
                    gsd_m_per_px: float | None = None, coarsen: float = 1.0) -> GeoRaster:
        """The north-up UTM raster of this flight (created once, then returned as is).

        gsd: ``gsd_m_per_px``, else the config's, else the ground sampling of ``pose``'s frame at its
        centre (height above ground / fx) times ``coarsen`` (>= 1: a mosaic coarser than large
        frames), rounded to two significant digits. Pixel (0, 0) is the ground point under the frame
        centre, snapped to the gsd grid.
        """
        if self.raster is not None:
            return self.raster
        cam = _need_camera(camera)
        if not pose.valid or self.origin is None:
            msg = 'make_raster needs a valid pose (a GNSS fix must have been fed before the frame).'
            raise ValueError(msg)
        gsd = gsd_m_per_px if gsd_m_per_px is not None else self.config.gsd_m_per_px
        if not (gsd and math.isfinite(gsd) and gsd > 0):
            agl = max(float(pose.camera.center_enu_m[2]) - ground_of(pose), self.config.min_agl_m, 1.0) \
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

    def refine_raster(self, zoom: float) -> float:
        """Sample the raster ``zoom`` (>= 1) times finer about pixel (0, 0), which stays on the same ground
        point: the gsd becomes gsd / zoom rounded to two significant digits, as :meth:`make_raster`'s; old
        raster pixel (x, y) is new pixel (z x, z y) with z = old gsd / new gsd, the zoom returned (1 where
        the rounding leaves the gsd as it was, nothing changed). The drift controller's state follows:
        its pixel-valued parts (placement, the chain's corner errors, the similarity's offset and origin)
        scale by z, their covariances by z squared; angles, scale and pose errors are unchanged.
        Only before anything is painted on the raster (pipeline: a segment's first frames, held)."""
        raster = self._raster(None)
        if not (math.isfinite(zoom) and zoom >= 1.0):
            msg = f'refine_raster needs a zoom >= 1, got {zoom!r}.'
            raise ValueError(msg)
        gsd = float(f'{raster.gsd_m_per_px / zoom:.2g}')
        if not gsd < raster.gsd_m_per_px:
            return 1.0
        z = raster.gsd_m_per_px / gsd
        self.raster = GeoRaster(raster.epsg, gsd, raster.origin_easting_m, raster.origin_northing_m, raster.rotation_rad)
        if self._drift is not None:
            self._drift = scaled_drift(self._drift, z)
        if self._canvas is not None:
            self._canvas = scaled_similarity(self._canvas, z)
        return z

    def drop_raster(self) -> None:
        """Forget the raster and the drift controller: the mosaic is not placed by the poses after
        all (pipeline: pose_check.py); the filter goes on giving poses."""
        self.raster = None
        self._raster_agl_m = None  # nothing painted at its sampling: no warning about it
        self.reset_drift(new_canvas=True)

    def raster_H_enu(self, raster: GeoRaster | None = None) -> np.ndarray:
        """(3, 3) ENU ground (east, north, 1) -> raster pixel (x, y, 1) (affine)."""
        raster = self._raster(raster)
        return raster.raster_H_utm @ self._utm_affine(raster.epsg)

    def raster_H_frame(self, pose: FramePose, camera: CameraIntrinsics | None,
                       raster: GeoRaster | None = None) -> np.ndarray:
        """(3, 3) frame pixels -> raster pixels of the flat ground seen from ``pose`` (normalised)."""
        return normalize_H(self.raster_H_enu(raster) @ self._enu_H_frame(pose, _need_camera(camera)))

    def correct(self, raster_H_frame_chained: np.ndarray, pose: FramePose,
                camera: CameraIntrinsics | None, raster: GeoRaster | None = None, *,
                chain_sigma_px: float | None = None, fallback_info_rate: np.ndarray | None = None) -> np.ndarray:
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
        cam = _need_camera(camera)
        corners = frame_corners(cam)
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
        info = pose.info_rate if pose.info_rate is not None else fallback_info_rate
        if info is not None:
            info = np.pad(np.asarray(info, dtype=np.float64), ((0, 1), (0, 1)))  # nothing measures the ground alone
        out = drift_step(self._drift, chained, corners, step, measured, model_sigma_px=cfg.homography_min_sigma_px,
                         info_rate=info, time_constant_s=cfg.drift_pose_time_constant_s)
        self._canvas = self._drift.canvas
        return out

    def corner_sigma_px(self, prev_H_cur: np.ndarray, covariance: np.ndarray | None,
                        camera: CameraIntrinsics | None) -> float:
        """RMS standard deviation (px) of the frame corners under a registration's (8, 8) covariance of
        h (:func:`corner_jacobian`), or ``drift_chain_sigma_px`` when there is none."""
        if covariance is None:
            return self.config.drift_chain_sigma_px
        H = np.asarray(prev_H_cur, dtype=np.float64)
        J = corner_jacobian(H / H[2, 2], frame_corners(_need_camera(camera)))
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

    def check_raster_agl(self, pose: FramePose, ground_var_m2: float, log: SkipLog) -> None:
        """Warn once when the raster's ground sampling was chosen for a height above the ground that
        the filter, once the ground height is known to 10%, puts more than 20% away: at the first
        frame the ground is a guess (the first fix minus georef.nominal_agl_m) unless
        georef.ground_altitude_m is given, so a low flight gets a coarser mosaic than its frames."""
        agl0 = self._raster_agl_m
        if agl0 is None or log.warned('raster_gsd_agl') or not pose.valid or pose.camera is None:
            return
        agl = float(pose.camera.center_enu_m[2]) - ground_of(pose)
        if not (agl > 0 and math.sqrt(max(ground_var_m2, 0.0)) < 0.1 * agl):
            return
        if abs(agl / agl0 - 1.0) > 0.2:
            log.count_once('raster_gsd_agl')
            _LOG.warning(
                'the mosaic raster samples the ground at %.3g m/px, chosen for %.0f m above the ground at the first '
                'frame; the filter now puts the camera %.0f m above it, so the frames are painted at %.0f%% of their '
                'own resolution. Set georef.ground_altitude_m (the ground\'s ellipsoidal height), '
                'georef.nominal_agl_m or georef.gsd_m_per_px for this flight.',
                self.raster.gsd_m_per_px if self.raster is not None else float('nan'), agl0, agl, 100.0 * min(agl / agl0, 1.0))

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
        return ground_H_image(cam.K, pose.camera.R_enu_from_cam, pose.camera.center_enu_m, ground_z_m=ground_of(pose))

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
        y0 = np.r_[pose.pose6, ground_of(pose)]
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


def _need_camera(camera: CameraIntrinsics | None) -> CameraIntrinsics:
    if camera is None:
        msg = 'no camera intrinsics: pass camera= or construct the Georeferencer with them.'
        raise ValueError(msg)
    return camera


def ground_of(pose: FramePose) -> float:
    """The ground plane's height (ENU z, m) under ``pose``; 0 where the filter has none."""
    return pose.ground_z_m if math.isfinite(pose.ground_z_m) else 0.0


def frame_corners(cam: CameraIntrinsics) -> np.ndarray:
    """(4, 2) corner pixel centres of a frame, clockwise from the top-left."""
    w, h = cam.width, cam.height
    return np.array([[0.0, 0.0], [w - 1.0, 0.0], [w - 1.0, h - 1.0], [0.0, h - 1.0]])
