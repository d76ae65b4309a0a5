"""Benchmark: peak memory and throughput of `srmosaic process` on a long flight, with and without the tile bound.

The flight (srmosaic_ros.sim, written by `srmosaic simulate` as a user would): 640 x 480 RGB frames
at 4 frames/s over the caliterra orthophoto (400 m x 300 m at 0.1 m per world pixel), 70 m above
the ground (0.126 m per frame pixel, an 81 m x 61 m footprint), a lawnmower survey of 7 legs of
250 m, 33 m apart (59 % side overlap), at 4.1 m/s (8 px of motion between frames, 3.6 deg/frame in
the turns), 2 deg RMS gusts; 2,000 frames by default (the pattern lasts 2,011). Lower altitudes
give a larger mosaic but frames of this world then see too little texture to register reliably.
The bag is raw sqlite3 (1.8 GB for 2,000 frames) under --work and reused by later runs with the
same settings (--fresh to redo it).

`srmosaic process BAG --out DIR` then runs in a child process twice, with the default parameters
except mosaic.max_tiles_in_memory: 0 (no bound) and --max-tiles (default 32). The child is
`srmosaic process` itself, wrapped only to record, when the pipeline finishes (before the outputs
are written), the tiles in memory and on disk and the peak RSS so far. Figures per run: peak RSS
(MB: the whole run from report.json, and before writing the outputs), frames per second (report.json:
processing and writing, interpreter start excluded), tiles in memory / only on disk at the end,
spill writes / loads, spill files (MB), and whether mosaic.png is byte-identical between the runs.

The simulator renders every frame into memory before writing the bag (sim.simulate returns the
whole flight: ~0.9 MB per frame), so its own peak RSS is printed apart; it is not part of
`srmosaic process`, which reads the bag lazily.

    python bench/memory.py [--frames 2000] [--quick] [--max-tiles 32] [--blend feather|multiband]
                           [--work bench/out/memory] [--fresh] [--checkpoint-every N]

--quick: 300 frames (the first leg and a turn), a few minutes instead of about half an hour.

The outputs (mosaic.tif, mosaic.png, preview.png) are written strip by strip from the canvas
(offline.write_outputs), so "peak RSS" and "(before out)" differ only by what writing them adds.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent

#: The flight; `srmosaic simulate` options (see module docstring).
FLIGHT = ['--world', 'data/worlds/caliterra_IMG_9360.jpg', '--trajectory', 'lawnmower', '--width', '640',
          '--height', '480', '--rate', '4', '--altitude', '70', '--speed', '4.1', '--legs', '7',
          '--leg-length', '250', '--leg-spacing', '33', '--heading', '0', '--seed', '3',
          '--storage', 'sqlite3', '--transport', 'raw']


def _srmosaic() -> list[str]:
    exe = Path(sys.executable).parent / 'srmosaic'
    return [str(exe)] if exe.exists() else [sys.executable, '-m', 'srmosaic_ros.cli']


def _run(cmd: list[str], log: Path) -> tuple[int, float, float]:
    """Run cmd with output to log; (exit status, wall s, peak RSS MB of the child from wait4)."""
    t0 = time.perf_counter()
    with open(log, 'w') as handle:
        proc = subprocess.Popen(cmd, stdout=handle, stderr=subprocess.STDOUT, cwd=ROOT)
        _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return proc.returncode, time.perf_counter() - t0, usage.ru_maxrss / 1024.0


def simulate(bag: Path, frames: int, fresh: bool) -> dict[str, Any]:
    args = [*FLIGHT, '--frames', str(frames)]
    stamp = bag.parent / f'{bag.name}.args.json'
    if not fresh and bag.is_dir() and stamp.is_file() and json.loads(stamp.read_text()) == args:
        print(f'reusing the bag {bag} ({frames} frames)')
        return {'reused': True}
    shutil.rmtree(bag, ignore_errors=True)
    print(f'simulating {frames} frames into {bag} ...', flush=True)
    rc, wall, rss = _run([*_srmosaic(), 'simulate', *args, '--out', str(bag), '--no-progress'],
                         bag.parent / 'simulate.log')
    if rc != 0:
        sys.exit(f'srmosaic simulate failed (exit {rc}); see {bag.parent / "simulate.log"}')
    stamp.write_text(json.dumps(args))
    size = sum(f.stat().st_size for f in bag.rglob('*') if f.is_file()) / 1e6
    print(f'  {wall:.0f} s, peak RSS {rss:.0f} MB (the simulator holds every frame), bag {size:.0f} MB')
    return {'reused': False, 'wall_s': round(wall, 1), 'peak_rss_mb': round(rss, 1), 'bag_mb': round(size, 1)}


def process(bag: Path, work: Path, name: str, max_tiles: int, blend: str,
            checkpoint_every: int | None) -> dict[str, Any]:
    out = work / name
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    spill = work / 'spill'
    spill.mkdir(exist_ok=True)
    params = out.parent / f'{name}.params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    mosaic:\n'
                      f'      max_tiles_in_memory: {max_tiles}\n      spill_dir: {json.dumps(str(spill))}\n'
                      f'      blend: {blend}\n')
    stats = out.parent / f'{name}.tiles.json'
    cmd = [sys.executable, str(Path(__file__).resolve()), '--child-stats', str(stats), '--',
           'process', str(bag), '--out', str(out), '--params', str(params), '--no-progress']
    if checkpoint_every is not None:
        cmd += ['--checkpoint-every', str(checkpoint_every)]
    print(f'{name}: srmosaic process, mosaic.max_tiles_in_memory={max_tiles} ...', flush=True)
    rc, wall, rss = _run(cmd, out.parent / f'{name}.log')
    if rc != 0:
        sys.exit(f'srmosaic process failed (exit {rc}); see {out.parent / f"{name}.log"}')
    report = json.loads((out / 'report.json').read_text())
    tiles = json.loads(stats.read_text())
    segs = tiles['segments']  # one entry per canvas (georeferenced segments share one)
    main = max(report['segments'], key=lambda s: s['frames'])
    row = {
        'run': name, 'max_tiles_in_memory': max_tiles,
        'peak_rss_mb': report['peak_rss_mb'], 'peak_rss_mb_child_wait4': round(rss, 1),
        'peak_rss_mb_before_outputs': tiles['peak_rss_mb'],
        'frames_per_s': report['frames_per_s'], 'wall_s': report['wall_s'], 'wall_s_with_start': round(wall, 1),
        'frames_in': report['frames_in'], 'frames_registered': report['frames_registered'],
        'segments': len(report['segments']), 'mosaic_px': main['size_px'],
        'tiles': sum(s['tiles'] for s in segs), 'tiles_in_memory': sum(s['in_memory'] for s in segs),
        'tiles_on_disk': sum(s['on_disk_only'] for s in segs), 'spill_writes': sum(s['writes'] for s in segs),
        'spill_loads': sum(s['loads'] for s in segs),
        'tile_memory_mb': round(sum(s['memory_bytes'] for s in segs) / 1e6, 1),
        'spill_disk_mb': round(sum(s['disk_bytes'] for s in segs) / 1e6, 1),
        'spill_dir_left_behind': any(spill.iterdir()),
    }
    return row


def child(stats_path: Path, argv: list[str]) -> int:
    """`srmosaic process` with the tile figures recorded when the pipeline finishes."""
    sys.path.insert(0, str(ROOT))
    from srmosaic_ros import pipeline as pl
    from srmosaic_ros.cli import main as cli_main

    original = pl.Pipeline.finish

    def finish(self: Any) -> Any:
        result = original(self)
        stats = {'peak_rss_mb': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
                 'segments': [c.tile_stats() for c in {id(seg.canvas): seg.canvas for seg in result.segments}.values()]}
        stats_path.write_text(json.dumps(stats))
        return result

    pl.Pipeline.finish = finish  # type: ignore[method-assign]
    return int(cli_main(argv) or 0)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ['--child-stats']:
        return child(Path(argv[1]), argv[3:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--frames', type=int, default=None,
                    help='frames of the flight (default 2000, --quick 300; at most 2056)')
    ap.add_argument('--quick', action='store_true', help='300 frames unless --frames says otherwise')
    ap.add_argument('--max-tiles', type=int, default=32,
                    help='mosaic.max_tiles_in_memory of the bounded run (default 32)')
    ap.add_argument('--blend', choices=['feather', 'multiband'], default='feather',
                    help='mosaic.blend (default feather)')
    ap.add_argument('--checkpoint-every', type=int, default=None,
                    help='passed to `srmosaic process` (default: its own default)')
    ap.add_argument('--work', type=Path, default=ROOT / 'bench' / 'out' / 'memory',
                    help='bag, outputs and spill files (default bench/out/memory)')
    ap.add_argument('--fresh', action='store_true',
                    help='simulate the bag again even if one with these settings exists')
    ap.add_argument('--only', choices=['unbounded', 'bounded'], help='run one of the two')
    args = ap.parse_args(argv)
    if args.frames is None:
        args.frames = 300 if args.quick else 2000
    args.work.mkdir(parents=True, exist_ok=True)
    bag = args.work / f'flight_{args.frames}'
    t0 = time.perf_counter()
    sim = simulate(bag, args.frames, args.fresh)
    runs = []
    if args.only != 'bounded':
        runs.append(process(bag, args.work, 'unbounded', 0, args.blend, args.checkpoint_every))
    if args.only != 'unbounded':
        runs.append(process(bag, args.work, f'bound_{args.max_tiles}', args.max_tiles, args.blend,
                            args.checkpoint_every))
    same = None
    if len(runs) == 2:
        pngs = [(args.work / r['run'] / 'mosaic.png').read_bytes() for r in runs]
        same = pngs[0] == pngs[1]

    first = runs[0]
    print(f"\n{args.frames} frames 640x480, blend {args.blend}, mosaic {first['mosaic_px'][0]}x{first['mosaic_px'][1]} "
          f"px, {first['segments']} segment(s), {first['frames_registered']}/{first['frames_in']} registered")
    head = (f"{'run':<12} {'peak RSS MB':>11} {'(before out)':>12} {'fps':>6} {'wall s':>7} {'tiles mem/disk':>15} "
            f"{'tile MB':>8} {'writes/loads':>13} {'spill MB':>9}")
    print(head)
    for r in runs:
        print(f"{r['run']:<12} {r['peak_rss_mb']:>11.0f} {r['peak_rss_mb_before_outputs']:>12.0f} "
              f"{r['frames_per_s']:>6.2f} {r['wall_s']:>7.0f} {r['tiles_in_memory']:>7}/{r['tiles_on_disk']:<7} "
              f"{r['tile_memory_mb']:>8.0f} "
              f"{r['spill_writes']:>6}/{r['spill_loads']:<6} {r['spill_disk_mb']:>9.0f}")
    if same is not None:
        print(f"mosaic.png byte-identical between the runs: {'yes' if same else 'NO'}")
    if any(r['spill_dir_left_behind'] for r in runs):
        print('WARNING: spill files were left behind under', args.work / 'spill')
    print(f'total {time.perf_counter() - t0:.0f} s')
    (args.work / 'memory.json').write_text(json.dumps({'frames': args.frames, 'blend': args.blend, 'simulate': sim,
                                                       'runs': runs, 'mosaic_png_identical': same}, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
