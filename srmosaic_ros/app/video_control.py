"""Ground control points for the mosaic of a video or a bag: the offline re-anchoring of its raster on
surveyed targets, and check points that measure where it lies.

The file is OpenDroneMap's gcp_list.txt (io/gcp.py), given with ``process --gcp``. Each pick names
the frame it was made in by its stamp (app/frame_names.py: the names `srmosaic frames` writes, or
the stamp_ns of frames.csv), at pixels of that frame as decoded (before any undistortion). A pick
goes through its frame's chained homography onto mosaic.png's pixel grid; the targets held as
control then fix where that grid lies on the ground:

- two or more control targets: the least-squares similarity (Umeyama) from their mosaic pixels to
  their surveyed east, north replaces the raster's scale, rotation and offset (the GNSS-anchored
  raster, or none, before: a flight without GNSS is placed by its control alone);
- one: the raster the run had is shifted onto it (its scale and rotation stay the filter's);
- none: the raster stays; the check points still measure it.

A control target whose leave-one-out miss is both beyond GCP_REJECT_SIGMA of the picks' own noise and
several times the others' miss of that fit is left out as a wrong point, and said so. The mosaic's pixels
never move: this places the grid, it does not warp the mosaic, so a drift along the chain stays
in the check points' residuals. report.json ``gcp`` has the same form as a survey's.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.georef.anchoring import fit_similarity
from ..core.georef.raster import GeoRaster
from ..errors import InputError
from ..io.gcp import GcpList, read_gcp_list
from .frame_names import stamp_of_name
from .ground_control import GCP_PICK_SIGMA_PX, GCP_REJECT_SIGMA, GCP_SURVEY_SIGMA_M, check_point_names

if TYPE_CHECKING:
    from ..core.types import CameraIntrinsics
    from ..pipeline import PipelineResult
    from .georeference import MainPlacement

__all__ = ['VideoControl', 'WRONG_POINT_MEDIAN_FACTOR', 'control_main']

_LOG = logging.getLogger(__name__)
#: A control target is a wrong point when its leave-one-out miss is also this many times the RMS
#: miss of the others in that fit (the chain's own drift makes every miss larger than the picks' noise).
WRONG_POINT_MEDIAN_FACTOR = 4.0


@dataclass
class VideoControl:
    """A run's ground control: the file, the picks placed on mosaic.png's grid (``mosaic_px`` (M, 2),
    NaN where the pick's frame is not in the main mosaic, with ``why`` per pick) and the targets held
    out as check points."""

    gcp: GcpList
    mosaic_px: np.ndarray
    why: list[str]
    check: list[str]

    @classmethod
    def load(cls, path: Path, result: PipelineResult, origin: tuple[int, int], check_points: str | None,
             source_camera: CameraIntrinsics | None = None) -> VideoControl:
        """Read ``path`` and place its picks through the frames of the main mosaic (pixel (0, 0) of
        mosaic.png = canvas pixel ``origin``). source_camera: the camera the frames were decoded with,
        when its lens distortion was removed before registration (the picks are then undistorted too).

        Raises:
            InputError: a pick whose image name gives no stamp, or a file io/gcp.py refuses.
        """
        gcp = read_gcp_list(path)
        for warning in gcp.warnings:
            _LOG.warning('%s: %s', path.name, warning)
        main = result.main_segment
        on_main = {seg.index for seg in result.segments if main is not None and seg.canvas is main.canvas}
        by_stamp = {rec.stamp_ns: rec for rec in result.records}
        px = np.full((len(gcp.observations), 2), np.nan)
        why = [''] * len(gcp.observations)
        for m, o in enumerate(gcp.observations):
            stamp = stamp_of_name(o.image)
            if stamp is None:
                msg = (f'{path}:{o.line}: image "{o.image}" names no frame; name each pick\'s frame by its stamp, as '
                       '`srmosaic frames INPUT DIR` names the files it writes (frame_000123_33333333ns.png) or as '
                       'frames.csv\'s stamp_ns column gives it.')
                raise InputError(msg)
            rec = by_stamp.get(stamp)
            if rec is None:
                why[m] = 'no frame of the run has this stamp (another --select, or another input?)'
            elif not (-0.5 <= o.pixel_xy[0] <= rec.size[0] - 0.5 and -0.5 <= o.pixel_xy[1] <= rec.size[1] - 0.5):
                msg = (f'{path}:{o.line}: pixel ({o.pixel_xy[0]:g}, {o.pixel_xy[1]:g}) is outside frame {o.image} '
                       f'({rec.size[0]}x{rec.size[1]}); picks made on other-sized copies of the frames must be scaled.')
                raise InputError(msg)
            elif rec.segment not in on_main or rec.seg_H_frame is None:
                why[m] = 'its frame is not in the main mosaic'
            elif o.excluded:
                why[m] = o.excluded
            else:
                xy = _undistorted(np.array(o.pixel_xy, dtype=np.float64), source_camera)
                q = rec.seg_H_frame @ np.array([xy[0], xy[1], 1.0])
                px[m] = q[:2] / q[2] - np.asarray(origin, dtype=np.float64)
        names = gcp.targets()
        placed = [any(o.name == t and np.isfinite(px[m]).all() for m, o in enumerate(gcp.observations)) for t in names]
        first = {t: next(m for m, o in enumerate(gcp.observations) if o.name == t) for t in names}
        ground = gcp.ground_in(gcp.projected_epsg())
        check = check_point_names(check_points, names, np.array([ground[first[t]] for t in names]), placed)
        _LOG.info('%s: %d picks of %d targets, %d on the main mosaic; control: %s; check: %s', path, len(px), len(names),
                  int(np.isfinite(px).all(axis=1).sum()), ', '.join(t for t in names if t not in check) or 'none',
                  ', '.join(check) or 'none')
        return cls(gcp, px, why, check)

    def place(self, placement: MainPlacement) -> tuple[MainPlacement, dict[str, Any]]:
        """(the main mosaic's placement on the control, report.json's ``gcp``)."""
        from .georeference import MainPlacement

        prior = placement.raster
        epsg = prior.epsg if prior is not None else self.gcp.projected_epsg()
        ground = self.gcp.ground_in(epsg)
        names = self.gcp.targets()
        target_px, target_en = self._targets(ground)
        control = [t for t in names if t not in self.check and t in target_px]
        gsd = prior.gsd_m_per_px if prior is not None else math.nan
        rejected: dict[str, float] = {}
        if len(control) >= 2:
            gsd = _similarity_raster(epsg, [target_px[t] for t in control], [target_en[t] for t in control]).gsd_m_per_px
            rejected = self._wrong_points(epsg, control, target_px, target_en, gsd)
        kept = [t for t in control if t not in rejected]
        raster, method = prior, 'none'
        if len(kept) >= 2:
            raster, method = _similarity_raster(epsg, [target_px[t] for t in kept], [target_en[t] for t in kept]), 'similarity'
        elif len(kept) == 1 and prior is not None:
            t = kept[0]
            shift = target_en[t] - prior.utm_from_pixels(target_px[t][None, :])[0]
            raster = GeoRaster(prior.epsg, prior.gsd_m_per_px, prior.origin_easting_m + float(shift[0]),
                               prior.origin_northing_m + float(shift[1]), prior.rotation_rad)
            method = 'offset'
        elif control:
            _LOG.warning('gcp: %s control target(s) usable: the mosaic stays where %s', len(kept),
                         'its poses put it' if prior is not None else 'nothing puts it (not georeferenced)')
        if raster is not None and math.isfinite(raster.gsd_m_per_px):
            gsd = raster.gsd_m_per_px
        report = self._report(raster, epsg, ground, kept, rejected, method, gsd)
        if raster is None:
            return placement, report
        entry = {**placement.report, 'epsg': raster.epsg, 'gsd_m_per_px': raster.gsd_m_per_px,
                 'geotransform': list(raster.geotransform)}
        if method != 'none':
            entry.update(method=f'ground control ({method})', placed_before_control=placement.report.get('method', 'none'))
        return MainPlacement(raster, entry, placement.poses), report

    def _targets(self, ground: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Each target's mean mosaic pixel over its placed picks, and its surveyed east, north."""
        px, en = {}, {}
        for t in self.gcp.targets():
            rows = [m for m, o in enumerate(self.gcp.observations) if o.name == t and np.isfinite(self.mosaic_px[m]).all()]
            if rows:
                px[t] = self.mosaic_px[rows].mean(axis=0)
                en[t] = ground[rows[0]]
        return px, en

    def _wrong_points(self, epsg: int, control: list[str], px: dict[str, np.ndarray], en: dict[str, np.ndarray],
                      gsd: float) -> dict[str, float]:
        """Control targets far from where the others put them: {name: leave-one-out miss (m)}.

        Each target is left out in turn and the others fitted; the target is wrong when it misses that
        fit by more than GCP_REJECT_SIGMA of the picks' own noise and by more than
        WRONG_POINT_MEDIAN_FACTOR times the RMS by which the others miss it (the chain's drift between
        them). The worst is left out, then the rest tried again, keeping at least three; needs four
        targets (with three, a wrong one cannot be told from the two it disagrees with)."""
        sd = math.hypot(GCP_PICK_SIGMA_PX * gsd, GCP_SURVEY_SIGMA_M)
        out: dict[str, float] = {}
        while len(control) - len(out) >= 4:
            kept = [t for t in control if t not in out]
            worst, worst_ratio, worst_miss = None, 1.0, 0.0
            for t in kept:
                others = [u for u in kept if u != t]
                fit = _similarity_raster(epsg, [px[u] for u in others], [en[u] for u in others])
                miss = float(np.hypot(*(fit.utm_from_pixels(px[t][None, :])[0] - en[t])))
                spread = float(np.sqrt(np.mean([np.sum((fit.utm_from_pixels(px[u][None, :])[0] - en[u]) ** 2) for u in others])))
                ratio = miss / max(WRONG_POINT_MEDIAN_FACTOR * spread, GCP_REJECT_SIGMA * sd, 1e-9)
                if ratio > worst_ratio:
                    worst, worst_ratio, worst_miss = t, ratio, miss
            if worst is None:
                break
            out[worst] = worst_miss
            _LOG.warning('gcp: %s is %.2f m from where the other control targets put it: left out as a wrong point; '
                         'check its pick and its surveyed position.', worst, worst_miss)
        return out

    def _report(self, raster: GeoRaster | None, epsg: int, ground: np.ndarray, kept: list[str],
                rejected: dict[str, float], method: str, gsd: float) -> dict[str, Any]:
        obs = self.gcp.observations

        def in_gsd(v: float | None) -> float | None:
            return round(v / gsd, 2) if v is not None and math.isfinite(gsd) and gsd > 0 else None

        res = np.full((len(obs), 2), np.nan)
        if raster is not None:
            ok = np.isfinite(self.mosaic_px).all(axis=1)
            res[ok] = raster.utm_from_pixels(self.mosaic_px[ok]) - ground[ok]
        points, errors = [], {'control': [], 'check': []}
        for t in self.gcp.targets():
            rows = [m for m, o in enumerate(obs) if o.name == t]
            role = 'check' if t in self.check else 'control'
            counted = [m for m in rows if np.isfinite(res[m]).all()]
            entry: dict[str, Any] = {'name': t, 'role': role, 'surveyed': [round(float(v), 4) for v in obs[rows[0]].geo_xyz],
                                     'surveyed_utm': [round(float(v), 3) for v in ground[rows[0]]]}
            if counted:
                r = res[counted].mean(axis=0)
                err = float(np.hypot(*r))
                entry.update(residual_m=[round(float(r[0]), 4), round(float(r[1]), 4)], error_m=round(err, 4),
                             error_gsd=in_gsd(err))
                if role == 'check' or t in kept:
                    errors[role].append(err)
            else:
                reasons = sorted({self.why[m] for m in rows if self.why[m]}) or ['the mosaic is not georeferenced']
                entry.update(residual_m=None, error_m=None, error_gsd=None, note='; '.join(reasons))
            if t in rejected:
                entry['note'] = f'left out as a wrong point: {rejected[t]:.2f} m from where the others put it'
            entry['observations'] = [
                {'image': obs[m].image, 'line': obs[m].line, 'pixel': list(obs[m].pixel_xy),
                 'residual_m': [round(float(v), 4) for v in res[m]] if np.isfinite(res[m]).all() else None,
                 'error_m': round(float(np.hypot(*res[m])), 4) if np.isfinite(res[m]).all() else None,
                 'error_gsd': in_gsd(float(np.hypot(*res[m]))) if np.isfinite(res[m]).all() else None,
                 'control': role == 'control' and t in kept and np.isfinite(res[m]).all(), 'note': self.why[m]}
                for m in rows]
            points.append(entry)
        out: dict[str, Any] = {
            'file': str(self.gcp.path), 'crs': self.gcp.crs.name, 'epsg': epsg, 'targets': len(points),
            'observations': len(obs), 'control': [p['name'] for p in points if p['role'] == 'control'],
            'check': [p['name'] for p in points if p['role'] == 'check'], 'pick_sigma_px': GCP_PICK_SIGMA_PX,
            'survey_sigma_m': GCP_SURVEY_SIGMA_M, 'gsd_m_per_px': gsd if math.isfinite(gsd) else None,
            'placed_mosaic': method, 'placed_survey': method == 'similarity',
        }
        for role in ('control', 'check'):
            e = errors[role]
            rms = float(np.sqrt(np.mean(np.square(e)))) if e else None
            out[f'{role}_rms_m'] = None if rms is None else round(rms, 4)
            out[f'{role}_rms_gsd'] = in_gsd(rms)
            out[f'{role}_targets_measured'] = len(e)
        out['rejected'] = [{'name': t, 'error_m': round(d, 3)} for t, d in rejected.items()]
        out['wrong_point_test'] = 'run' if len(kept) + len(rejected) >= 4 else 'not run (fewer than four control targets)'
        out['contradicting_picks'] = [{'image': o.image, 'line': o.line, 'pixel': list(o.pixel_xy), 'name': o.name,
                                       'note': o.excluded} for o in obs if o.excluded]
        out['warnings'] = list(self.gcp.warnings) + [
            f'{t} left out as a wrong point: {d:.2f} m from where the other control targets put it; check its pick and '
            'its surveyed position' for t, d in rejected.items()]
        unplaced = sorted({o.image for m, o in enumerate(obs) if self.why[m].startswith('no frame')})
        if unplaced:
            out['warnings'].append(f'{len(unplaced)} pick frame(s) not in the run: {", ".join(unplaced[:5])}'
                                   f'{" ..." if len(unplaced) > 5 else ""}; pick in frames the run used (frames.csv).')
            _LOG.warning('gcp: %s', out['warnings'][-1])
        out['points'] = points
        return out


def _similarity_raster(epsg: int, px: list[np.ndarray], en: list[np.ndarray]) -> GeoRaster:
    """The GeoRaster whose pixel grid puts mosaic pixels ``px`` nearest ``en`` (least squares).

    utm = g [[c, s], [s, -c]] (x, y) + (e0, n0) is a similarity of (x, -y): fit that (raster.py)."""
    src = np.array(px, dtype=np.float64).reshape(-1, 2) * np.array([1.0, -1.0])
    S = fit_similarity(src, np.array(en, dtype=np.float64).reshape(-1, 2), from_a_line=True)
    g = float(math.hypot(S[0, 0], S[1, 0]))
    if not g > 0:
        msg = 'the control targets coincide on the mosaic: they cannot give its scale; pick targets apart.'
        raise InputError(msg)
    return GeoRaster(epsg, g, float(S[0, 2]), float(S[1, 2]), float(math.atan2(S[1, 0], S[0, 0])))


def _undistorted(xy: np.ndarray, camera: CameraIntrinsics | None) -> np.ndarray:
    """A pick (x, y) of a decoded frame in the pixels of the frame registration saw (core/undistort.py)."""
    if camera is None or not camera.has_distortion:
        return xy
    import cv2

    from ..core.undistort import pinhole_of

    pinhole = pinhole_of(camera)[0]
    K_new = np.array([[pinhole.fx, 0.0, pinhole.cx], [0.0, pinhole.fy, pinhole.cy], [0.0, 0.0, 1.0]])
    D = np.asarray(camera.distortion, dtype=np.float64)
    pts = xy.reshape(1, 1, 2)
    if camera.distortion_model == 'equidistant':
        out = cv2.fisheye.undistortPoints(pts, camera.K, D, P=K_new)
    else:
        out = cv2.undistortPoints(pts, camera.K, D, P=K_new)
    return out.reshape(2)


def control_main(path: Path, result: PipelineResult, placement: MainPlacement, check_points: str | None,
                 source_camera: CameraIntrinsics | None = None) -> tuple[MainPlacement, dict[str, Any] | None]:
    """(the main mosaic's placement with the ground control of ``path``, report.json's ``gcp``); the
    placement unchanged and None when the run has no main mosaic."""
    main = result.main_segment
    if main is None:
        _LOG.warning('%s: no mosaic to place on the ground control', path)
        return placement, None
    x0, y0, _, _ = main.canvas.bounds()
    control = VideoControl.load(path, result, (x0, y0), check_points, source_camera)
    placed, report = control.place(placement)
    for p in report['points']:
        if p['error_m'] is not None:
            _LOG.info('gcp %s (%s): %.3f m (%s GSD)', p['name'], p['role'], p['error_m'], p['error_gsd'])
    return placed, report
