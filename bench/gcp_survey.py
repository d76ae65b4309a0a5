"""Benchmark: ground control points on a real survey without GPS (../shared/data/real/surveys/copr:
41 stills, gcp_list.txt with 10 targets in 27 picks).

The stills are registered once (as `process` does); the global solve is then repeated with
different targets held out as check points, and each check point's residual (the mean over its
picks of where the solved stills put it, minus its surveyed position) is printed in metres and in
GSD (the stills' median ground sampling, which is the mosaic's):

- the survey without control, taken to the ground by the best similarity to every target: what
  the drift leaves (what `process` gave before ground control);
- every target as control (the control's own residuals);
- ``--check-points N`` (3: 7 of 10 as control), as `process --check-points 3` chooses them;
- leave one target out, once per target.

    python bench/gcp_survey.py [--survey DIR] [--gcp FILE] [--check-points N] [--json OUT] [--cache FILE]
"""
from __future__ import annotations

import argparse
import json
import math
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SURVEY = ROOT.parent / 'shared' / 'data' / 'real' / 'surveys' / 'copr'


def _gsd(sol, stills) -> float:
    """Median ground sampling (m/px) of the placed stills, as the mosaic takes it."""
    g = [math.sqrt(abs(np.linalg.det(G[:2, :2] / G[2, 2]))) / float(s.K[0, 0])
         for G, s, by in zip(sol.ground_H_frame, stills, sol.placed_by) if by]
    return float(np.median(g))


def _similarity_rms(sol, control) -> float:
    """RMS over targets of the residual left by the best similarity from the solved plane to the control."""
    from srmosaic_ros.core.survey.global_align import control_residuals

    p = control_residuals(sol.ground_H_frame, control) + control.ground_m
    ok = np.isfinite(p).all(axis=1) & control.use
    pc, X = p[ok, 0] + 1j * p[ok, 1], control.ground_m[ok, 0] + 1j * control.ground_m[ok, 1]
    (s, t), *_ = np.linalg.lstsq(np.stack([pc, np.ones(len(pc))], axis=1), X, rcond=None)
    r = s * pc + t - X
    names = np.array(control.target)[ok]
    per = [abs(r[names == n].mean()) for n in dict.fromkeys(names)]
    return float(np.sqrt(np.mean(np.square(per))))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--survey', type=Path, default=DEFAULT_SURVEY)
    ap.add_argument('--gcp', type=Path, default=None, help='default: the survey\'s gcp_list.txt')
    ap.add_argument('--check-points', default='3')
    ap.add_argument('--json', type=Path, default=None, help='also write the figures here')
    ap.add_argument('--working-megapixels', type=float, default=None,
                    help='survey.working_megapixels for the registrations (default: the parameter file\'s)')
    ap.add_argument('--cache', type=Path, default=None,
                    help='keep the registrations in this file and use them when it exists (the solve only)')
    args = ap.parse_args()
    if not args.survey.is_dir():
        print(f'{args.survey}: not found; give --survey DIR (a folder of stills with its gcp_list.txt)')
        return 2
    from srmosaic_ros.app.ground_control import SurveyControl, check_point_names
    from srmosaic_ros.app.survey import register_survey, survey_stills
    from srmosaic_ros.config import pipeline_config
    from srmosaic_ros.core.survey.global_align import solve_survey
    from srmosaic_ros.io.gcp import find_gcp_file
    from srmosaic_ros.io.image_folder import ImageFolderReader

    gcp_file = args.gcp or find_gcp_file(args.survey)
    config = pipeline_config({} if args.working_megapixels is None else
                             {'survey.working_megapixels': args.working_megapixels})
    reader = ImageFolderReader(args.survey)
    stills, epsg, origin = survey_stills(reader)
    full = SurveyControl.load(gcp_file, stills, epsg, origin, None)
    t0 = time.perf_counter()
    if args.cache is not None and args.cache.is_file():
        with args.cache.open('rb') as handle:
            reg = pickle.load(handle)
    else:
        reg = register_survey(stills, config, progress=True, control=full.control)
        reg.registrations = {}  # the Registration objects: not needed here, and not all picklable
        if args.cache is not None:
            args.cache.parent.mkdir(parents=True, exist_ok=True)
            with args.cache.open('wb') as handle:
                pickle.dump(reg, handle)
    print(f'{len(stills)} stills, {len(reg.pairs)} pairs registered in {time.perf_counter() - t0:.1f} s; '
          f'{full.control.use.sum()} of {len(full.control.frame)} picks usable as control')
    n = len(stills)
    names = full.gcp.targets()
    rows = []

    def run(label: str, check: list[str]) -> dict:
        ctl = full.holding_out(check)
        t = time.perf_counter()
        sol = solve_survey(n, reg.pairs, reg.priors, control=ctl.control)
        solve_s = time.perf_counter() - t
        gsd = _gsd(sol, stills)
        rep = ctl.report(sol, gsd)
        row = {'label': label, 'check': check, 'gsd_m': gsd, 'solve_s': round(solve_s, 2),
               'control_rms_m': rep['control_rms_m'], 'control_rms_gsd': rep['control_rms_gsd'],
               'check_rms_m': rep['check_rms_m'], 'check_rms_gsd': rep['check_rms_gsd'],
               'check_errors_m': {p['name']: p['error_m'] for p in rep['points'] if p['role'] == 'check'},
               'rejected': [f"{r['name']}@{r['image']}" for r in rep['rejected']],
               'contradicting': [c.get('agrees_with') for c in rep['contradicting_picks']],
               'placed': n - sol.placed_by.count('')}
        rows.append(row)
        return row

    plain = solve_survey(n, reg.pairs, reg.priors)
    drift = _similarity_rms(plain, full.control)
    gsd0 = run('all targets control', [])['gsd_m']
    first = [next(m for m, o in enumerate(full.gcp.observations) if o.name == t) for t in names]
    xy = full.control.ground_m[first]
    usable = [any(o.name == t and not o.excluded for o in full.gcp.observations) for t in names]
    split = check_point_names(args.check_points, names, xy, usable)
    run(f'--check-points {args.check_points}', split)
    for t in names:
        run(f'leave out {t}', [t])

    print(f'\nno control, best similarity to all targets: {drift:.3f} m RMS ({drift / gsd0:.1f} GSD; GSD {gsd0 * 100:.2f} cm)')
    print(f"\n{'run':<28} {'check':<22} {'control RMS':>16} {'check RMS':>18}  rejected / contradicting pick")
    for r in rows:
        ctl = f"{r['control_rms_m']:.3f} m {r['control_rms_gsd']:>5} px" if r['control_rms_m'] is not None else '-'
        chk = f"{r['check_rms_m']:.3f} m {r['check_rms_gsd']:>5} px" if r['check_rms_m'] is not None else '-'
        print(f"{r['label']:<28} {','.join(r['check']) or '-':<22} {ctl:>16} {chk:>18}  "
              f"{','.join(r['rejected']) or '-'} / {','.join(str(c) for c in r['contradicting']) or '-'}")
    loo = [r['check_errors_m'][r['check'][0]] for r in rows if r['label'].startswith('leave out')
           and r['check_errors_m'].get(r['check'][0]) is not None]
    loo_ok = [r['check_errors_m'][r['check'][0]] for r in rows if r['label'].startswith('leave out')
              and r['check_errors_m'].get(r['check'][0]) is not None and usable[names.index(r['check'][0])]]
    if loo:
        rms = float(np.sqrt(np.mean(np.square(loo))))
        rms_ok = float(np.sqrt(np.mean(np.square(loo_ok)))) if loo_ok else math.nan
        print(f'\nleave-one-target-out: {len(loo)} targets {rms:.3f} m RMS ({rms / gsd0:.2f} GSD); the {len(loo_ok)} '
              f'with a pick that contradicts no other: {rms_ok:.3f} m RMS ({rms_ok / gsd0:.2f} GSD)')
    if args.json:
        args.json.write_text(json.dumps({'drift_similarity_rms_m': drift, 'gsd_m': gsd0, 'rows': rows}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
