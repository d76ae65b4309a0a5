"""Benchmark: drift on an image flight that comes back over its own ground (lawnmower), with and
without keyframe-to-mosaic registration, with and without georeferencing.

Simulates (once, cached under bench/out/drift/) a 3-leg lawnmower flight with raw images
(`srmosaic simulate --trajectory lawnmower --legs 3 --leg-length 150 --leg-spacing 40`, 231
frames at 640x480, GPS 2.5 m, IMU 0.5 deg), runs `process` on it per configuration and prints
what `srmosaic evaluate` measures: corner error of the mosaic placements after the best-fitting
plane homography (mean, max, last frame; px), consecutive-frame error (px), georeferencing error
of mosaic points (m RMS, max) and the wall time.

    python bench/drift.py [--frames N]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / 'bench' / 'out' / 'drift'
SRMOSAIC = [sys.executable, '-m', 'srmosaic_ros.cli']

CONFIGS = {
    'georef, no keyframes': {'georef': {'enabled': True}, 'mosaic': {'keyframe_interval': 0}},
    'georef, keyframes on revisits (default)': {'georef': {'enabled': True}, 'mosaic': {}},
    'georef, keyframes, no settling': {'georef': {'enabled': True}, 'mosaic': {'settle_s': 0.0}},
    'georef, keyframe every 10 frames': {'georef': {'enabled': True}, 'mosaic': {'keyframe_revisit_frames': 0}},
    'first-frame plane, no keyframes': {'georef': {'enabled': False}, 'mosaic': {'keyframe_interval': 0}},
    'first-frame plane, keyframes on revisits': {'georef': {'enabled': False}, 'mosaic': {}},
}


def _params(path: Path, sections: dict) -> Path:
    lines = ['/**:', '  ros__parameters:']
    for section, values in sections.items():
        if not values:
            continue
        lines.append(f'    {section}:')
        lines += [f'      {k}: {str(v).lower() if isinstance(v, bool) else v}' for k, v in values.items()]
    path.write_text('\n'.join(lines) + '\n')
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--frames', type=int, default=0, help='frames to simulate (default: the whole pattern, 231)')
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    flight = OUT / f'lawnmower_{args.frames or "all"}'
    if not (flight / 'ground_truth.json').is_file():
        print(f'simulating {flight} ...', flush=True)
        cmd = [*SRMOSAIC, 'simulate', '--trajectory', 'lawnmower', '--legs', '3', '--leg-length', '150',
               '--leg-spacing', '40', '--transport', 'raw', '--seed', '3', '--out', str(flight), '--overwrite',
               '--no-progress']
        if args.frames:
            cmd += ['--frames', str(args.frames)]
        subprocess.run(cmd, check=True, cwd=ROOT)
    rows = []
    for name, sections in CONFIGS.items():
        out = OUT / ('run_' + ''.join(c if c.isalnum() else '_' for c in name))
        params = _params(OUT / (out.name + '.yaml'), sections)
        t0 = time.perf_counter()
        subprocess.run([*SRMOSAIC, 'process', str(flight), '--out', str(out), '--params', str(params), '--no-progress'],
                       check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        ev = json.loads(subprocess.run([*SRMOSAIC, 'evaluate', str(out), '--truth', str(flight / 'ground_truth.json'),
                                        '--json'], check=True, cwd=ROOT, capture_output=True, text=True).stdout)
        ev['config'], ev['wall_s'] = name, wall
        rows.append(ev)
        print(f'{name:<42} corner mean {ev["corner_error_mean_px"]:6.2f} max {ev["corner_error_max_px"]:6.2f} '
              f'last {ev["corner_error_last_px"]:6.2f} px | pair {ev["pair_corner_error_mean_px"]:.3f} px | '
              f'georef RMS {ev.get("georef_error_rms_m", float("nan")):.2f} m max {ev.get("georef_error_max_m", float("nan")):.2f} m'
              f' | {wall:.0f} s', flush=True)
    (OUT / 'drift.json').write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
