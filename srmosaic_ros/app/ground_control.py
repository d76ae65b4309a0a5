"""Ground control points of a survey of stills: read, split into control and check points, given to
the solve, and reported.

The file is OpenDroneMap's gcp_list.txt (io/gcp.py), found inside or beside the stills' folder or
given with ``process --gcp``. Its targets are control (constraints of the global solve, see
core/survey/global_align.py) unless held out as check points (``--check-points N`` or a list of
names), which the solve never sees: their residuals measure the mosaic's absolute accuracy.

A target's residual is the mean, over the stills it is picked in, of (where the solved still puts
the pick on the ground) - (its surveyed position), east and north in metres (its height is not
used: the survey's ground is a plane); the report gives it in metres and in mosaic pixels (GSD).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.survey.global_align import GroundControl, SurveySolution, control_residuals
from ..errors import InputError
from ..io.gcp import GcpList, read_gcp_list

if TYPE_CHECKING:
    from .survey_still import SurveyStill

__all__ = ['GCP_PICK_SIGMA_PX', 'GCP_REJECT_SIGMA', 'GCP_SURVEY_SIGMA_M', 'SurveyControl', 'check_point_names']

_LOG = logging.getLogger(__name__)
#: sd of a target's pick in a still (pixels of the still as stored).
GCP_PICK_SIGMA_PX = 2.0
#: sd of a target's surveyed position (metres, horizontal).
GCP_SURVEY_SIGMA_M = 0.02
#: A control pick or target this many sd from where the others put it is dropped (solve_survey's
#: control_reject_sigma).
GCP_REJECT_SIGMA = 5.0


def check_point_names(spec: str | None, names: list[str], ground_m: np.ndarray, usable: list[bool]) -> list[str]:
    """The targets held out as check points.

    Args:
        spec: None or '' (none), a count N, or names separated by commas.
        names: (T,) the targets; ground_m: (T, 2) their positions, metres; usable: (T,) whether a
            target has a pick that contradicts no other (only those are chosen by count).

    A count picks targets spread over the survey and inside it where it can: the usable targets off
    the convex hull of all targets first (a check point outside the control is extrapolated),
    starting from the one nearest the centre, then each the farthest from those already chosen
    (ties: file order). At least two targets stay control.
    """
    if spec is None or not str(spec).strip():
        return []
    spec = str(spec).strip()
    if spec.isdigit():
        count = int(spec)
        if count == 0:
            return []
        if count > len(names) - 2:
            msg = (f'--check-points {count}: the file has {len(names)} targets and at least two must stay control; '
                   f'hold out at most {max(len(names) - 2, 0)}.')
            raise InputError(msg)
        return _spread_inside(names, np.asarray(ground_m, dtype=np.float64), usable, count)
    chosen = [s.strip() for s in spec.split(',') if s.strip()]
    unknown = [s for s in chosen if s not in names]
    if unknown:
        msg = f'--check-points: {", ".join(unknown)} not in the GCP file; its targets are {", ".join(names)}.'
        raise InputError(msg)
    if len(set(chosen)) > len(names) - 2:
        msg = f'--check-points: {len(set(chosen))} of {len(names)} targets held out; at least two must stay control.'
        raise InputError(msg)
    return list(dict.fromkeys(chosen))


def _spread_inside(names: list[str], xy: np.ndarray, usable: list[bool], count: int) -> list[str]:
    hull: set[int] = set()
    try:
        from scipy.spatial import ConvexHull, QhullError

        try:
            hull = set(int(v) for v in ConvexHull(xy).vertices)
        except (QhullError, ValueError):  # collinear or too few: no inside
            hull = set()
    except ImportError:  # pragma: no cover - scipy is a dependency
        hull = set()
    tiers = ([t for t in range(len(names)) if usable[t] and t not in hull],
             [t for t in range(len(names)) if usable[t] and t in hull],
             [t for t in range(len(names)) if not usable[t]])
    centre = xy.mean(axis=0)
    chosen: list[int] = []
    for tier in tiers:
        pool = list(tier)
        while pool and len(chosen) < count:
            if not chosen:
                pick = min(pool, key=lambda t: (float(np.hypot(*(xy[t] - centre))), t))
            else:
                pick = max(pool, key=lambda t: (min(float(np.hypot(*(xy[t] - xy[c]))) for c in chosen), -t))
            chosen.append(pick)
            pool.remove(pick)
    return [names[t] for t in chosen]


@dataclass
class SurveyControl:
    """A survey's ground control: the file, the projected CRS and plane origin the survey is solved
    in (epsg, origin (e0, n0) metres), the observations of stills in the folder as the solve's
    GroundControl (control: rows in file order), and the targets held out (check)."""

    gcp: GcpList
    epsg: int
    origin: tuple[float, float]
    control: GroundControl
    check: list[str]

    @classmethod
    def load(cls, path: Path, stills: list[SurveyStill], epsg: int, origin: tuple[float, float],
             check_points: str | None) -> SurveyControl:
        """Read ``path`` for these stills. epsg, origin: the survey's CRS and plane origin from its
        GPS (epsg 0: none; then the GCPs' own projected CRS and the targets' centre)."""
        sizes = {s.file.name: (int(s.size[0]), int(s.size[1])) for s in stills}
        gcp = read_gcp_list(path, image_sizes=sizes)
        for warning in gcp.warnings:
            _LOG.warning('%s: %s', path.name, warning)
        if not epsg:
            epsg = gcp.projected_epsg()
            xy = gcp.ground_in(epsg)
            origin = (float(np.round(xy[:, 0].mean())), float(np.round(xy[:, 1].mean())))
        ground = gcp.ground_in(epsg) - np.array(origin)
        names = gcp.targets()
        first = {name: next(k for k, o in enumerate(gcp.observations) if o.name == name) for name in names}
        usable = [any(o.name == name and not o.excluded for o in gcp.observations) for name in names]
        check = check_point_names(check_points, names, np.array([ground[first[t]] for t in names]), usable)
        index = {s.file.name: k for k, s in enumerate(stills)}
        frame = np.array([index[o.image] for o in gcp.observations], dtype=int)
        point_n = np.array([(np.linalg.inv(stills[k].K) @ np.array([o.pixel_xy[0], o.pixel_xy[1], 1.0]))[:2]
                            for k, o in zip(frame, gcp.observations)])
        sigma_n = np.array([GCP_PICK_SIGMA_PX / float(stills[k].K[0, 0]) for k in frame])
        use = np.array([not o.excluded and o.name not in check for o in gcp.observations])
        control = GroundControl(frame, point_n, ground, sigma_n, tuple(o.name for o in gcp.observations), use,
                                GCP_SURVEY_SIGMA_M)
        _LOG.info('%s: %d observations of %d targets in %d stills (%s); control: %s; check: %s', path,
                  len(frame), len(names), len(set(frame.tolist())), gcp.crs.name,
                  ', '.join(t for t in names if t not in check) or 'none', ', '.join(check) or 'none')
        if len({o.name for o, u in zip(gcp.observations, use) if u}) < 2:
            _LOG.warning('%s: fewer than two targets are control: they cannot place the survey on the ground '
                         '(hold out fewer check points, or fix the contradicting picks).', path)
        return cls(gcp, int(epsg), (float(origin[0]), float(origin[1])), control, check)

    def holding_out(self, check: list[str]) -> SurveyControl:
        """The same control with ``check`` held out instead (bench/gcp_survey.py's leave-one-out)."""
        use = np.array([not o.excluded and o.name not in check for o in self.gcp.observations])
        return dataclasses.replace(self, control=dataclasses.replace(self.control, use=use), check=list(check))

    def report(self, sol: SurveySolution, gsd_m: float) -> dict[str, Any]:
        """report.json's ``gcp``: every target's role and residual (metres, GSD) with each of its
        observations, the control and check RMS, the observations the solve rejected and which name
        a contradicting pick agrees with; logs the same."""
        ctl = self.control
        res = control_residuals(sol.ground_H_frame, ctl)
        used = sol.control_used if sol.control_used is not None else ctl.use
        rejected = set(sol.figures.get('control_rejected', []))
        obs = self.gcp.observations

        def in_gsd(v: float) -> float | None:
            return round(v / gsd_m, 2) if math.isfinite(gsd_m) and gsd_m > 0 and math.isfinite(v) else None

        points = []
        errors: dict[str, list[float]] = {'control': [], 'check': []}
        for name in self.gcp.targets():
            rows = [m for m, o in enumerate(obs) if o.name == name]
            role = 'check' if name in self.check else 'control'
            counted = [m for m in rows if not obs[m].excluded and m not in rejected and np.isfinite(res[m]).all()]
            entry: dict[str, Any] = {'name': name, 'role': role,
                                     'surveyed': [round(float(v), 4) for v in obs[rows[0]].geo_xyz],
                                     # east, north in the survey's projected CRS (``epsg``): report.html's map
                                     'surveyed_utm': [round(float(ctl.ground_m[rows[0]][i] + self.origin[i]), 3)
                                                      for i in (0, 1)]}
            if counted:
                r = res[counted].mean(axis=0)
                err = float(np.hypot(*r))
                entry.update(residual_m=[round(float(r[0]), 4), round(float(r[1]), 4)], error_m=round(err, 4),
                             error_gsd=in_gsd(err))
                if role == 'check' or any(used[m] for m in counted):
                    errors[role].append(err)
            else:
                why = ('all rejected' if all(m in rejected for m in rows)
                       else 'contradicting picks only' if all(obs[m].excluded for m in rows)
                       else 'the stills that see it are not placed')
                entry.update(residual_m=None, error_m=None, error_gsd=None, note=f'no pick that the solve kept: {why}')
            entry['observations'] = [self._observation(m, res, used, rejected, in_gsd) for m in rows]
            points.append(entry)
        out: dict[str, Any] = {
            'file': str(self.gcp.path), 'crs': self.gcp.crs.name, 'epsg': self.epsg,
            'targets': len(points), 'observations': len(obs),
            'control': [p['name'] for p in points if p['role'] == 'control'],
            'check': [p['name'] for p in points if p['role'] == 'check'],
            'pick_sigma_px': GCP_PICK_SIGMA_PX, 'survey_sigma_m': GCP_SURVEY_SIGMA_M,
            'gsd_m_per_px': gsd_m if math.isfinite(gsd_m) else None,
            'placed_survey': bool(sol.figures.get('control_placed_survey')),
        }
        for role in ('control', 'check'):
            e = errors[role]
            rms = float(np.sqrt(np.mean(np.square(e)))) if e else None
            out[f'{role}_rms_m'] = None if rms is None else round(rms, 4)
            out[f'{role}_rms_gsd'] = None if rms is None else in_gsd(rms)
            out[f'{role}_targets_measured'] = len(e)
        left_out = sol.figures.get('control_left_out_m') or {}
        median_left_out = float(np.median([np.hypot(*v) for v in left_out.values()])) if left_out else None
        out['left_out_median_m'] = None if median_left_out is None else round(median_left_out, 4)
        sd_m = math.hypot(GCP_PICK_SIGMA_PX * gsd_m, GCP_SURVEY_SIGMA_M) if math.isfinite(gsd_m) else math.nan
        out['wrong_point_test'] = (
            'not run (fewer than four control targets)' if median_left_out is None
            else f'no power: each target left out, the survey misses it by {median_left_out:.2f} m (median), more '
                 f'than {GCP_REJECT_SIGMA:g} sd ({GCP_REJECT_SIGMA * sd_m:.2f} m): a wrong point cannot be told from '
                 'the survey\'s own error; check the picks by eye'
            if median_left_out > GCP_REJECT_SIGMA * sd_m else 'run')
        out['rejected'] = [{'name': obs[m].name, 'image': obs[m].image, 'line': obs[m].line,
                            'error_m': round(float(np.hypot(*res[m])), 3)} for m in sorted(rejected)]
        out['contradicting_picks'] = self._contradictions(res)
        out['warnings'] = list(self.gcp.warnings)
        unplaced = [k for k, by in enumerate(sol.placed_by) if not by]
        if out['placed_survey'] and unplaced:
            seen = sorted({self.gcp.observations[m].image for m in range(len(obs)) if int(ctl.frame[m]) in unplaced})
            out['warnings'].append(
                f'{len(unplaced)} stills not placed: no registration joins them to the stills the control places, and '
                'their part of the survey sees fewer than two control targets' +
                (f' ({", ".join(seen)} see targets held out or contradicting)' if seen else '') +
                '; hold out other targets as check points, or add targets there.')
            _LOG.warning('gcp: %s', out['warnings'][-1])
        out['points'] = points
        self._log(out)
        return out

    def _observation(self, m: int, res: np.ndarray, used: np.ndarray, rejected: set[int], in_gsd: Any) -> dict[str, Any]:
        o = self.gcp.observations[m]
        finite = bool(np.isfinite(res[m]).all())
        err = float(np.hypot(*res[m])) if finite else math.nan
        note = o.excluded or ('rejected by the solve' if m in rejected else '')
        return {'image': o.image, 'line': o.line, 'pixel': [o.pixel_xy[0], o.pixel_xy[1]],
                'residual_m': [round(float(res[m][0]), 4), round(float(res[m][1]), 4)] if finite else None,
                'error_m': round(err, 4) if finite else None, 'error_gsd': in_gsd(err),
                'control': bool(used[m]), 'note': note}

    def _contradictions(self, res: np.ndarray) -> list[dict[str, Any]]:
        """Picks named as two targets in one still: how far the solve puts the pick from each."""
        obs = self.gcp.observations
        out = []
        seen = set()
        for m, o in enumerate(obs):
            if not o.excluded.startswith('same pixel as ') or m in seen:
                continue
            group = [k for k, q in enumerate(obs) if q.image == o.image and q.excluded.startswith('same pixel as ')
                     and math.hypot(q.pixel_xy[0] - o.pixel_xy[0], q.pixel_xy[1] - o.pixel_xy[1]) <= 5.0]
            seen.update(group)
            far = {obs[k].name: round(float(np.hypot(*res[k])), 3) for k in group if np.isfinite(res[k]).all()}
            entry: dict[str, Any] = {'image': o.image, 'pixel': [o.pixel_xy[0], o.pixel_xy[1]],
                                     'lines': [obs[k].line for k in group], 'distance_m': far}
            if len(far) >= 2:
                ranked = sorted(far.items(), key=lambda kv: kv[1])
                entry['agrees_with'] = ranked[0][0] if ranked[1][1] > 3.0 * max(ranked[0][1], 0.05) else None
            out.append(entry)
        return out

    def _log(self, out: dict[str, Any]) -> None:
        for p in out['points']:
            if p['error_m'] is None:
                _LOG.warning('gcp %s (%s): %s', p['name'], p['role'], p.get('note', 'not measured'))
                continue
            _LOG.info('gcp %s (%s): %.3f m (%s GSD) east %+.3f north %+.3f over %d pick(s)', p['name'], p['role'],
                      p['error_m'], p['error_gsd'], p['residual_m'][0], p['residual_m'][1],
                      sum(1 for o in p['observations'] if not o['note']))
        for r in out['rejected']:
            _LOG.warning('gcp %s in %s (line %d) rejected by the solve: %.2f m from where the other control and '
                         'the registrations put it; check its pick and coordinates.', r['name'], r['image'], r['line'],
                         r['error_m'])
        for c in out['contradicting_picks']:
            agree = c.get('agrees_with')
            dist = ', '.join(f'{k} {v:.2f} m' for k, v in c['distance_m'].items())
            _LOG.warning('gcp: the pick at %s (%.0f, %.0f) is %s from the solve%s', c['image'], c['pixel'][0],
                         c['pixel'][1], dist, f': it is {agree}; remove the other line' if agree else '')
        if out['wrong_point_test'].startswith('no power'):
            _LOG.warning('gcp: %s.', out['wrong_point_test'])
        for role in ('control', 'check'):
            if out[f'{role}_rms_m'] is not None:
                _LOG.info('gcp: %d %s target(s) %.3f m RMS (%s GSD)', out[f'{role}_targets_measured'], role,
                          out[f'{role}_rms_m'], out[f'{role}_rms_gsd'])
