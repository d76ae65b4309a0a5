"""Where the mosaic of a run lies on the map: the raster of mosaic.png re-anchored on the smoothed
poses of all its frames (core/georef/anchoring.py), or, where the filter did not place it, fitted
to the frames' geotags (core/georef/geotag_fit.py)."""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..config import PipelineConfig
from ..core.georef.geotag_fit import GEOTAG_MIN_EXTENT_M
from ..pipeline import PipelineResult

if TYPE_CHECKING:
    from ..core.georef import GeoRaster

_LOG = logging.getLogger(__name__)

__all__ = ['MainPlacement', 'anchored_raster', 'georeference_main', 'geotag_fit_of_main', 'ground_offsets']

#: Offline re-anchoring fits frame corners unless the height above ground is known worse than this
#: (relative standard deviation, median over the frames): then the frame centres only.
ANCHOR_CORNERS_MAX_REL_AGL_SD = 0.02
#: The fit of a mosaic to its geotags needs them to span GEOTAG_MIN_EXTENT_M (geotag_fit.py) ...
#: ... and fits only the offset when the similarity's rotation is known worse than the poses' heading,
#: and than this (deg).
ANCHOR_MIN_ROTATION_SD_DEG = 0.5


@dataclass(frozen=True)
class MainPlacement:
    """Where the main mosaic lies on the ground, decided before anything is written.

    raster: the GeoRaster of mosaic.png's pixel grid (None: not georeferenced); report: report.json's
    'georeferenced' entry ({} when not); poses: the smoothed poses for poses.csv where the filter
    placed the mosaic (None where its geotags did, or nothing)."""

    raster: GeoRaster | None
    report: dict[str, Any]
    poses: list[Any] | None = None


def georeference_main(result: PipelineResult, config: PipelineConfig) -> MainPlacement:
    """The main mosaic's placement: re-anchored on the filter's smoothed poses where the filter placed
    it (anchored_raster), else fitted to its frames' geotags (geotag_fit_of_main), else none."""
    main = result.main_segment
    if main is None:
        return MainPlacement(None, {})
    x0, y0, _, _ = main.canvas.bounds()
    georef = result.georef
    if not (main.georeferenced and georef is not None and georef.raster is not None):
        fit = geotag_fit_of_main(result, (x0, y0), config) if config.georef_enabled else None
        if fit is None:
            return MainPlacement(None, {})
        return MainPlacement(fit.raster, {'epsg': fit.raster.epsg, 'gsd_m_per_px': fit.raster.gsd_m_per_px,
                                          'geotransform': list(fit.raster.geotransform), **fit.figures()})
    poses = georef.smoothed_poses()
    raster, anchoring = anchored_raster(result, poses, (x0, y0))
    return MainPlacement(raster, {'method': 'filter', 'epsg': raster.epsg, 'gsd_m_per_px': raster.gsd_m_per_px,
                                  'geotransform': list(raster.geotransform), **anchoring, 'poses': len(poses),
                                  'skipped_telemetry': dict(georef.skipped)}, poses)


def anchored_raster(result: PipelineResult, poses: list[Any], origin: tuple[int, int]) -> tuple[GeoRaster, dict[str, Any]]:
    """(GeoRaster of mosaic.png's pixel (0, 0), the anchoring figures) from the smoothed poses.

    The mosaic plane was anchored by the first frame's (early, filtered) pose. With the smoothed
    poses of every frame, re-anchor it (core/georef/anchoring.py): the least-squares similarity
    between each frame's chained corners and its pose-predicted corners (offset, rotation and
    scale, estimated from the whole flight) goes into the geotransform. The mosaic's pixels do
    not move: mosaic.png and mosaic.tif stay one grid.
    """
    from ..core.georef.anchoring import fit_similarity
    from ..core.metrics import apply_homography

    georef = result.georef
    chained, by_poses = [], []
    main_canvas = result.main_segment.canvas
    seg_of = {seg.index: seg for seg in result.segments}
    # A pose-predicted footprint is as large as its height above the ground says. Where the filter
    # never learnt the ground (registrations not fused: stills further apart than georef.max_step_s,
    # the nominal AGL prior left at +-30 m), the corners would carry that error into the scale;
    # the frame centres do not depend on it.
    rel_sd = [math.sqrt(max(float(p.ground_covariance[-1]), 0.0)) / max(p.camera.center_enu_m[2] - p.ground_z_m, 1.0)
              for p in poses if p.valid and p.ground_covariance is not None and p.camera is not None]
    centres_only = bool(rel_sd) and float(np.median(rel_sd)) > ANCHOR_CORNERS_MAX_REL_AGL_SD
    by_stamp = {p.stamp_ns: p for p in poses}  # records and poses need not align one to one
    for rec in result.records:
        seg, pose = seg_of.get(rec.segment), by_stamp.get(rec.stamp_ns)
        if seg is None or seg.canvas is not main_canvas or pose is None or not pose.valid or rec.seg_H_frame is None:
            continue
        w_f, h_f = rec.size
        corners = np.array([[0, 0], [w_f - 1, 0], [w_f - 1, h_f - 1], [0, h_f - 1]], dtype=float)
        if centres_only:
            corners = np.array([[(w_f - 1) / 2.0, (h_f - 1) / 2.0]])
        by_poses.append(apply_homography(georef.raster_H_frame(pose, rec.camera), corners))  # its own K: a zoom
        chained.append(apply_homography(rec.seg_H_frame, corners))
    translation_only = False
    if chained:
        src, dst = np.concatenate(chained), np.concatenate(by_poses)
        # raster pixel by the poses ~ fix @ chained raster pixel
        fix = fit_similarity(src, dst)
        # Points that stay within their own noise of each other (a stare at a site from kilometres)
        # cannot tell a rotation or a scale: the fit's angle is uncertain by about residual /
        # (spread sqrt(n)) rad; when that is worse than the poses' own heading (their yaw std, median),
        # the fit would add error, and only the offset is re-anchored.
        residual = float(np.sqrt(np.mean(np.sum((apply_homography(fix, src) - dst) ** 2, axis=1))))
        spread = float(np.sqrt(np.mean(np.sum((src - src.mean(axis=0)) ** 2, axis=1))))
        rotation_sd = residual / max(spread * math.sqrt(len(src)), 1e-9)
        yaw_sd = [float(p.std_rpy_rad[2]) for p in poses if p.valid]
        translation_only = bool(yaw_sd) and rotation_sd > max(float(np.median(yaw_sd)),
                                                              math.radians(ANCHOR_MIN_ROTATION_SD_DEG))
        if translation_only:
            fix = np.eye(3)
            fix[:2, 2] = (dst - src).mean(axis=0)
    else:
        fix = np.eye(3)
    # mosaic pixel m is chained raster pixel m + origin, truly at raster pixel fix @ (m + origin).
    raster = georef.raster.transformed(fix).shifted(origin[0], origin[1])
    figures = {'anchor_shift_px': [float(fix[0, 2]), float(fix[1, 2])],
               'anchor_scale': float(np.hypot(fix[0, 0], fix[1, 0])),
               'anchor_rotation_deg': float(np.degrees(np.arctan2(fix[1, 0], fix[0, 0]))),
               'anchor_frames': len(chained), 'anchor_points': 'centres' if centres_only else 'corners',
               'anchor_model': 'translation' if translation_only else 'similarity'}
    return raster, figures


def ground_offsets(result: PipelineResult, stamps_ns: np.ndarray, config: PipelineConfig,
                    max_gap_s: float = 0.5) -> np.ndarray:
    """(M, 2) east, north offset per metre of height of where each frame's optical axis meets the
    ground (-r_xy / r_z), from the Imu orientation nearest its stamp (within max_gap_s) and the
    camera mount (georef.gimbal_*); NaN without an orientation or for an axis near the horizon."""
    from ..core.georef.frames import R_body_from_cam, matrix_from_quat_xyzw

    imus = [i for i in result.imus if i.orientation_xyzw is not None]
    out = np.full((len(stamps_ns), 2), np.nan)
    if not imus:
        return out
    t = np.array([i.stamp_ns for i in imus], dtype=np.int64)
    order = np.argsort(t)
    t = t[order]
    mount = config.georef.mount
    R_bc = R_body_from_cam(mount.gimbal_azimuth_rad, mount.gimbal_elevation_rad)
    for k, stamp in enumerate(stamps_ns):
        j = int(np.clip(np.searchsorted(t, stamp), 1, len(t) - 1)) if len(t) > 1 else 0
        j = j - 1 if len(t) > 1 and abs(t[j - 1] - stamp) < abs(t[j] - stamp) else j
        if abs(int(t[j]) - int(stamp)) > max_gap_s * 1e9:
            continue
        axis = matrix_from_quat_xyzw(np.asarray(imus[order[j]].orientation_xyzw)) @ R_bc @ np.array([0.0, 0.0, 1.0])
        if axis[2] < -0.2:  # looking down, not near the horizon
            out[k] = -axis[:2] / axis[2]
    return out


def geotag_fit_of_main(result: PipelineResult, origin: tuple[int, int], config: PipelineConfig) -> Any:
    """GeotagFit of mosaic.png's grid (pixel (0, 0) = canvas pixel ``origin``) from the frames of the
    main canvas and the fixes at their stamps (core/georef/geotag_fit.py), or None (with the reason
    logged) when there are no fixes or they cannot place the mosaic."""
    from ..core.georef.geotag_fit import check_mount_nadir, check_views_nadir, fit_mosaic_to_geotags, geotags_at
    from ..core.metrics import apply_homography

    fixes = [f for f in result.fixes if f.status >= 0]
    if not fixes:
        return None
    main_canvas = result.main_segment.canvas
    on_main = {seg.index for seg in result.segments if seg.canvas is main_canvas}
    recs = [r for r in result.records if r.segment in on_main and r.painted and r.seg_H_frame is not None]
    centres = np.array([apply_homography(r.seg_H_frame, np.array([[(r.size[0] - 1) / 2.0, (r.size[1] - 1) / 2.0]]))[0]
                        for r in recs]).reshape(-1, 2) - np.asarray(origin, dtype=np.float64)
    fixes.sort(key=lambda f: f.stamp_ns)
    tags = geotags_at(np.array([f.stamp_ns for f in fixes]), np.array([[f.longitude_deg, f.latitude_deg] for f in fixes]),
                      np.array([r.stamp_ns for r in recs], dtype=np.int64))
    offsets = ground_offsets(result, np.array([r.stamp_ns for r in recs], dtype=np.int64), config) \
        if result.imus else None
    try:
        if offsets is None:  # without attitudes the fit takes the camera as nadir: the chain must agree
            check_views_nadir([r.seg_H_frame for r in recs], [r.size for r in recs])
            check_mount_nadir(result.pose_check.frames_mount if result.pose_check is not None else None)
        fit = fit_mosaic_to_geotags(centres, tags, offsets)
        if fit.extent_m < GEOTAG_MIN_EXTENT_M:
            msg = (f'the geotags of the main mosaic span {fit.extent_m:.1f} m RMS, less than {GEOTAG_MIN_EXTENT_M:g} m: '
                   'their GNSS noise, not the flight, would set its scale and rotation (a hover, a pan)')
            raise ValueError(msg)
    except ValueError as exc:
        _LOG.info('the mosaic is not georeferenced: the filter did not place it (no camera intrinsics, no fix '
                     'before its first frame, or poses refused: see pose_placement) and its geotags cannot: %s', exc)
        result.georef_note = f'its geotags cannot place it: {exc}'
        return None
    _LOG.info('mosaic not placed by the filter: georeferenced by its %d geotagged frames (residual RMS %.2f m, '
              '%d left out, tilt %s)', int(fit.used.sum()), fit.rms_m, int((~fit.used).sum()),
              'corrected' if fit.height_m is not None else 'not corrected')
    return fit
