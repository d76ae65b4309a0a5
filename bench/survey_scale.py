"""Surveys of full-size stills: throughput and peak memory of `srmosaic process FOLDER` against the
number of stills, at 12 megapixels.

The caliterra stills (../shared/data/real/surveys/caliterra, 2000x1500, halved from the camera's
4000x3000) are brought back to 4000x3000 (bicubic, EXIF kept: it describes the 4000 px original)
and processed as the first half and as the whole survey. Memory must not grow with the number of
stills (the canvas tiles, a bounded feature cache and one still in flight); the issue's goal is at
least 1 still/s and at most 3 GB.

With ``--baseline REV`` the same folders are processed by that revision too (a ``git worktree`` of
it under the output folder, run with this checkout's .venv through PYTHONPATH), the runs
interleaved (baseline, new, baseline, new... ``--repeat`` times each) so that both see the same
load on a shared machine; figures.json then holds every run, the medians, their spread (min..max)
and the ratios new / baseline, and whether the two mosaics have the same pixels.

With ``--sim`` the stills are a simulated lawnmower of 172 stills at that size (a DJI's EXIF/XMP)
instead: a survey of 150 to 200 stills, which the repository's real data does not hold.

    .venv/bin/python bench/survey_scale.py [--out bench/out/survey_scale] [--megapixels 12]
        [--baseline REV] [--new REV] [--repeat N] [--stills 37,75] [--sim]
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
SURVEY = ROOT.parent / 'shared' / 'data' / 'real' / 'surveys' / 'caliterra' / 'images'
PYTHON = ROOT / '.venv' / 'bin' / 'python'


def make_folder(dst: Path, files: list[Path], width: int) -> Path:
    (dst / 'images').mkdir(parents=True, exist_ok=True)
    for f in files:
        target = dst / 'images' / f.name
        if target.is_file():
            continue
        with Image.open(f) as im:
            exif = im.info.get('exif', b'')
            h = round(im.height * width / im.width)
            im.resize((width, h), Image.Resampling.BICUBIC).save(target, quality=92, exif=exif)
    return dst / 'images'


def sim_survey(dst: Path, width: int) -> list[Path]:
    """A simulated lawnmower of stills of width x 3/4 width (EXIF/XMP of a DJI: GPS, gimbal angles,
    focal length), 100 m up over the caliterra world (0.1 m): 10 legs of 220 m eastwards, 18 m apart,
    a still every 14.3 m (footprints 115 m along the legs, 87 m across: 79 % side, 88 % forward
    overlap), 172 stills; written once under ``dst``."""
    from srmosaic_ros.sim import SimConfig, save_truth, simulate
    from srmosaic_ros.sim.record import write_drone_stills

    folder = dst / 'survey'
    if not (dst / 'truth.json').is_file():
        flight = simulate(SimConfig(width=width, height=round(width * 3 / 4), trajectory='lawnmower', legs=10,
                                    leg_length_m=220.0, leg_spacing_m=18.0, speed_m_s=10.0, rate_hz=0.7,
                                    fix_rate_hz=0.7, gust_deg=1.0, max_supersample=1, seed=7))
        write_drone_stills(flight, folder)
        save_truth(flight.truth, dst / 'truth.json')
    return sorted((folder / 'images').iterdir())


def link_folder(dst: Path, files: list[Path]) -> Path:
    """A folder of links to ``files`` (the first n stills of a survey)."""
    (dst / 'images').mkdir(parents=True, exist_ok=True)
    for f in files:
        target = dst / 'images' / f.name
        if not target.exists():
            target.symlink_to(f.resolve())
    return dst / 'images'


def run(folder: Path, out: Path, source: Path = ROOT) -> dict:
    """`srmosaic process folder` in a subprocess (its own peak RSS) with the package of ``source``."""
    env = dict(os.environ, PYTHONPATH=str(source))
    subprocess.run([str(PYTHON), '-m', 'srmosaic_ros.cli', 'process', str(folder), '--out', str(out),
                    '--no-progress'], check=True, stdout=subprocess.DEVNULL, env=env, cwd=source)
    r = json.loads((out / 'report.json').read_text())
    return {'stills': r['frames_in'], 'placed': r['frames_registered'], 'wall_s': r['wall_s'],
            'frames_per_s': r['frames_per_s'], 'peak_rss_mb': r['peak_rss_mb'],
            'mosaic_px': r['segments'][0]['size_px'], 'mosaic_mp': round(np.prod(r['segments'][0]['size_px']) / 1e6, 1),
            'gsd_m': r['georeferenced']['gsd_m_per_px'], 'time_s': r['survey']['time_s'],
            'pairs_tried': r['survey']['pairs_tried'], 'canvas': r.get('canvas'),
            'bytes': {name: (out / name).stat().st_size for name in ('mosaic.png', 'mosaic.tif')}}


def same_pixels(a: Path, b: Path) -> dict:
    """Whether two runs' mosaic.png, mosaic.tif (bands, grid) and preview.png hold the same pixels."""
    import cv2
    import rasterio

    out = {}
    for name in ('mosaic.png', 'preview.png'):
        x, y = (cv2.imread(str(d / name), cv2.IMREAD_UNCHANGED) for d in (a, b))
        out[name] = bool(x.shape == y.shape and np.array_equal(x, y))
        if not out[name] and x.shape == y.shape:
            out[name + '_max_diff'] = int(np.abs(x.astype(int) - y.astype(int)).max())
    with rasterio.open(a / 'mosaic.tif') as s, rasterio.open(b / 'mosaic.tif') as t:
        same = (s.crs, s.transform, s.shape, s.count, s.overviews(1)) == (t.crs, t.transform, t.shape, t.count,
                                                                          t.overviews(1))
        for r in range(0, s.height, 1024) if same else ():
            w = rasterio.windows.Window(0, r, s.width, min(1024, s.height - r))
            if not np.array_equal(s.read(window=w), t.read(window=w)):
                same = False
                break
        out['mosaic.tif'] = same
    out['frames.csv'] = (a / 'frames.csv').read_bytes() == (b / 'frames.csv').read_bytes()
    return out


def _summary(rows: list[dict]) -> dict:
    def med(key: str) -> float:
        return statistics.median(r[key] for r in rows)

    stages = sorted({k for r in rows for k in r['time_s']})
    return {'runs': len(rows), 'stills': rows[0]['stills'], 'mosaic_mp': rows[0]['mosaic_mp'],
            'frames_per_s': med('frames_per_s'), 'frames_per_s_range': [min(r['frames_per_s'] for r in rows),
                                                                        max(r['frames_per_s'] for r in rows)],
            'wall_s': med('wall_s'), 'peak_rss_mb': med('peak_rss_mb'),
            'peak_rss_mb_range': [min(r['peak_rss_mb'] for r in rows), max(r['peak_rss_mb'] for r in rows)],
            'time_s': {k: statistics.median(r['time_s'].get(k, float('nan')) for r in rows) for k in stages}}


def _print(label: str, r: dict, width: int) -> None:
    print(f"{label}: {r['stills']} stills of {width}x{round(width * 3 / 4)}: {r['placed']} placed, {r['wall_s']} s, "
          f"{r['frames_per_s']} stills/s, peak {r['peak_rss_mb']} MB, mosaic {r['mosaic_px']} px at "
          f"{r['gsd_m']:.4f} m, {r['pairs_tried']} pairs, times {r['time_s']}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, default=ROOT / 'bench' / 'out' / 'survey_scale')
    ap.add_argument('--megapixels', type=float, default=12.0)
    ap.add_argument('--baseline', metavar='REV', help='also measure this revision, interleaved with this checkout')
    ap.add_argument('--new', metavar='REV', help='measure this revision as the new one (default: this working tree)')
    ap.add_argument('--repeat', type=int, default=1, help='runs of each (default 1)')
    ap.add_argument('--stills', default='', help='comma-separated numbers of stills (default: half and all)')
    ap.add_argument('--sim', action='store_true',
                    help='a simulated lawnmower of 172 stills (with truth) instead of the caliterra stills')
    ap.add_argument('--generate', action='store_true', help=argparse.SUPPRESS)  # the child that writes --sim
    args = ap.parse_args()
    args.out = args.out.resolve()  # the runs of --baseline work in their own checkout
    width = round((args.megapixels * 1e6 * 4 / 3) ** 0.5)
    if args.sim and not args.generate and not (args.out / f'sim_{width}' / 'truth.json').is_file():
        # in a child: this process forks the runs, and a child's peak RSS starts at its parent's
        subprocess.run([sys.executable, __file__, '--sim', '--generate', '--out', str(args.out),
                        '--megapixels', str(args.megapixels)], check=True)
    files = sim_survey(args.out / f'sim_{width}', width) if args.sim else sorted(SURVEY.iterdir())
    if args.generate:
        return 0
    counts = [int(n) for n in args.stills.split(',')] if args.stills else [len(files) // 2, len(files)]
    sources: dict[str, Path] = {}
    for label, rev in (('baseline', args.baseline), ('new', args.new)):
        if rev:
            sources[label] = _worktree(args.out / f'{label}_src', rev)
    sources.setdefault('new', ROOT)
    figures: dict = {'baseline': args.baseline, 'new': args.new or 'working tree', 'runs': []}
    try:
        for n in counts:
            folder = (link_folder(args.out / f'sim_{width}' / f'stills_{n}', files[:n]) if args.sim
                      else make_folder(args.out / f'stills_{n}', files[:n], width))
            for rep in range(args.repeat):
                for label, source in sources.items():  # interleaved: the same load for both
                    r = run(folder, args.out / f'out_{n}_{label}', source)
                    r.update(label=label, repeat=rep)
                    figures['runs'].append(r)
                    _print(label, r, width)
            if args.baseline:
                figures.setdefault('same_pixels', {})[n] = same_pixels(args.out / f'out_{n}_baseline',
                                                                       args.out / f'out_{n}_new')
                print(f'{n} stills, same pixels: {figures["same_pixels"][n]}', flush=True)
        figures['summary'] = {}
        for n in counts:
            s = {label: _summary([r for r in figures['runs'] if r['label'] == label and r['stills'] == n])
                 for label in sources}
            if args.baseline:
                s['ratio_new_over_baseline'] = {
                    'frames_per_s': round(s['new']['frames_per_s'] / s['baseline']['frames_per_s'], 3),
                    'peak_rss_mb': round(s['new']['peak_rss_mb'] / s['baseline']['peak_rss_mb'], 3),
                    'paint_and_write_s': round(s['new']['time_s']['paint_and_write']
                                               / s['baseline']['time_s']['paint_and_write'], 3)}
            figures['summary'][n] = s
            print(json.dumps({n: s}), flush=True)
    finally:
        (args.out / 'figures.json').write_text(json.dumps(figures, indent=2))
        for source in sources.values():
            if source != ROOT:
                subprocess.run(['git', 'worktree', 'remove', '--force', str(source)], cwd=ROOT, check=False)
    return 0


def _worktree(path: Path, rev: str) -> Path:
    """A detached git worktree of ``rev`` at ``path`` (replacing one left there)."""
    if path.exists():
        subprocess.run(['git', 'worktree', 'remove', '--force', str(path)], cwd=ROOT, check=False)
        shutil.rmtree(path, ignore_errors=True)
    subprocess.run(['git', 'worktree', 'add', '--detach', str(path), rev], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL)
    return path


if __name__ == '__main__':
    sys.exit(main())
