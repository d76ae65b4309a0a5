"""Benchmark: end-to-end throughput of `srmosaic process` on HD video, per stage, with the truth.

Simulated flights (srmosaic_ros.sim, the code `srmosaic simulate --video` runs) over the caliterra
orthophoto, a straight line at 100 m and 10 m/s, 60 deg horizontal field of view, 2 deg RMS gusts,
encoded as H.264 with an I-frame every 12 frames and a telemetry sidecar (noisy GNSS and IMU
attitude), at the sizes and rates payloads record:

    640x480 at 30 fps, 1280x720 at 30 fps, 1920x1080 at 25 fps, 3840x2160 at 25 fps

`process VIDEO --select all --telemetry SIDECAR --hfov 60` (default parameters, no SR, no
checkpoints) runs on each in a fresh process, as a user runs it; with --baseline REF the same
command of the code at git REF (a temporary worktree, the same virtual environment) runs beside
it, the two taking turns flight by flight so that load on a shared machine hits both alike.
Printed per run: frames/s end to end (frames over the process's wall time, start-up included)
beside the video's own rate, the mean per-frame time of each stage (report.json's
stage_times; a baseline without them shows the total only), the mean corner error over the
registered frames in full-size frame pixels (srmosaic_ros.app.evaluate against the truth), the frames
in the main mosaic, the peak memory, and where the process's wall time went outside the frames: its
start-up before the run's clock, the outputs stage, and its exit after report.json (report.json's
modification time splits the three), with the share of the outputs and the exit in the wall time.
The figures go to --work/throughput.json.

    OMP_NUM_THREADS=2 python bench/throughput.py [--sizes 640x480,1280x720,1920x1080,3840x2160]
                                                 [--frames 150] [--baseline REF] [--work DIR] [--fresh]
                                                 [--set KEY=VALUE ...] [--set-baseline-too]

Simulating takes longer than processing (about 20 s per 150 frames at 640x480, 45 s at 1080p and
3 minutes at 4K); later runs with the same settings reuse the videos (--fresh redoes them).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.app.evaluate import evaluate_dir

#: (width, height, frames/s of the video)
SIZES = {'640x480': (640, 480, 30.0), '1280x720': (1280, 720, 30.0), '1920x1080': (1920, 1080, 25.0),
         '3840x2160': (3840, 2160, 25.0)}
FLIGHT = ['--trajectory', 'line', '--altitude', '100', '--speed', '10', '--hfov', '60', '--gop', '12']
STAGES = ('decode', 'describe', 'register', 'fuse', 'paint', 'outputs')


def make_flight(work: Path, size: str, frames: int, fresh: bool) -> tuple[Path, Path, Path]:
    """(video, telemetry sidecar, ground_truth.json) of the flight at ``size``, simulated once."""
    w, h, fps = SIZES[size]
    folder = work / f'flight_{size}_{frames}'
    video, sidecar, truth = folder / 'flight.mp4', folder / 'flight.csv', folder / 'bag' / 'ground_truth.json'
    if not fresh and video.is_file() and sidecar.is_file() and truth.is_file():
        return video, sidecar, truth
    folder.mkdir(parents=True, exist_ok=True)
    print(f'simulating {frames} frames {size} at {fps:g} fps ...', flush=True)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', 'simulate', *FLIGHT, '--frames', str(frames),
                    '--rate', str(fps), '--width', str(w), '--height', str(h), '--seed', '5', '--no-progress',
                    '--overwrite', '--out', str(folder / 'bag'), '--video', str(video)], check=True, cwd=ROOT)
    print(f'  {time.perf_counter() - t0:.0f} s', flush=True)
    return video, sidecar, truth


def run_process(code: Path, video: Path, sidecar: Path, out: Path, params: Path | None) -> dict[str, Any]:
    """`srmosaic process` of the code in folder ``code``, in a fresh process; its report.json and wall time."""
    cmd = [sys.executable, '-m', 'srmosaic_ros.cli', 'process', str(video), '--telemetry', str(sidecar),
           '--hfov', '60', '--select', 'all', '--checkpoint-every', '0', '--no-progress', '--out', str(out)]
    if params is not None:
        cmd += ['--params', str(params)]
    env = {**os.environ, 'PYTHONPATH': str(code)}
    t0, clock0 = time.perf_counter(), time.time()
    subprocess.run(cmd, check=True, cwd=code, env=env, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    report = json.loads((out / 'report.json').read_text())
    report['process_wall_s'] = wall
    # report.json is written last (then moved into --out): its time splits the process's wall time into
    # the start-up before the run's own clock (wall_s) started, the run, and the exit after report.json
    written = (out / 'report.json').stat().st_mtime - clock0
    report['exit_s'] = max(wall - written, 0.0)
    report['startup_s_outside'] = max(written - report['wall_s'], 0.0)
    return report


def row(name: str, size: str, report: dict[str, Any], truth: Path, out: Path) -> dict[str, Any]:
    ev = evaluate_dir(out, truth)
    frames = report['frames_in']
    stages = report.get('stage_times', {})
    return {'code': name, 'size': size, 'video_fps': SIZES[size][2], 'frames': frames,
            'fps': frames / report['process_wall_s'], 'fps_loop': report.get('frames_per_s'),
            'stage_ms': {s: round(stages[s]['total_s'] / max(stages[s]['frames'], 1) * 1e3, 2) for s in STAGES if s in stages},
            'stage_p95_ms': {s: stages[s]['p95_ms'] for s in STAGES if s in stages},
            'corner_error_mean_px': ev['corner_error_mean_px'], 'pair_error_mean_px': ev['pair_corner_error_mean_px'],
            'frames_registered': report['frames_registered'], 'segments': len(report['segments']),
            'peak_rss_mb': report.get('peak_rss_mb'), 'process_wall_s': round(report['process_wall_s'], 3),
            'wall_s': report['wall_s'], 'startup_s': round(report['startup_s_outside'], 3),
            'exit_s': round(report['exit_s'], 3), 'outputs_s': stages.get('outputs', {}).get('total_s'),
            # what the user waits for once the frames are done: the outputs stage and the exit after report.json
            'outputs_share': round((stages.get('outputs', {}).get('total_s', 0.0) + report['exit_s'])
                                   / report['process_wall_s'], 4)}


def print_table(rows: list[dict[str, Any]]) -> None:
    head = (f"{'size':>10} {'code':<9} {'video':>5} {'fps':>6} {'run fps':>7} " + ' '.join(f'{s[:8]:>8}' for s in STAGES)
            + f" {'err px':>7} {'pair px':>7} {'in mos':>6} {'MB':>6} {'wall':>6} {'start':>5} {'out s':>5} {'exit':>5} {'out %':>5}")
    print(head)
    print('-' * len(head))
    for r in rows:
        stages = ' '.join(f"{r['stage_ms'][s]:8.1f}" if s in r['stage_ms'] else f"{'-':>8}" for s in STAGES)
        pair = r['pair_error_mean_px']
        print(f"{r['size']:>10} {r['code']:<9} {r['video_fps']:5.0f} {r['fps']:6.1f} {r['fps_loop'] or 0:7.1f} {stages} "
              f"{r['corner_error_mean_px']:7.3f} {(pair if pair is not None else float('nan')):7.4f} "
              f"{r['frames_registered']:>3}/{r['frames']:<3}{r['peak_rss_mb'] or 0:7.0f} {r['process_wall_s']:6.1f} "
              f"{r['startup_s']:5.1f} {r['outputs_s'] or 0:5.2f} {r['exit_s']:5.2f} {100 * r['outputs_share']:5.1f}")
    print('fps: frames per second end to end (process start-up included); run fps: report.json\'s (from the '
          'input opened to report.json written: start-up of Python and torch left out); stage columns: mean ms per '
          'input frame, on whichever thread (decode: the reader\'s wait; paint: the painter\'s work); '
          'err px: mean corner error of the mosaic placement, pair px: of consecutive frames, in '
          'full-size frame pixels; in mos: frames in the main mosaic; MB: peak memory; wall: the process\'s seconds; '
          'start: before the run\'s clock (Python, imports); out s: the outputs stage (mosaic files, CSVs, report.html); '
          'exit: after report.json was written (the interpreter\'s exit); out %: outputs and exit, of the wall')


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--sizes', default=','.join(SIZES), help='comma-separated WxH of ' + ', '.join(SIZES))
    ap.add_argument('--frames', type=int, default=150, help='frames per flight (default 150)')
    ap.add_argument('--baseline', default=None, help='git ref whose `process` runs beside this tree\'s')
    ap.add_argument('--work', type=Path, default=ROOT / 'bench' / 'out' / 'throughput',
                    help='flights, outputs and throughput.json (default bench/out/throughput)')
    ap.add_argument('--fresh', action='store_true', help='simulate again even if the flights exist')
    ap.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                    help='parameter for this tree\'s runs (e.g. registration.level=0); repeatable')
    ap.add_argument('--set-baseline-too', action='store_true',
                    help='the --set parameters for the baseline\'s runs as well (a code change under the same settings)')
    args = ap.parse_args(argv)
    sizes = args.sizes.split(',')
    bad = [s for s in sizes if s not in SIZES]
    if bad or args.frames < 2:
        ap.error(f'unknown sizes {bad} (known: {", ".join(SIZES)}) or --frames < 2')
    if os.environ.get('OMP_NUM_THREADS') is None:
        print('note: OMP_NUM_THREADS is not set; set it to the cores the pipeline may use')
    args.work.mkdir(parents=True, exist_ok=True)
    params = None
    if args.set:
        import yaml

        nested: dict[str, Any] = {}
        for item in args.set:
            key, _, value = item.partition('=')
            section, _, name = key.partition('.')
            nested.setdefault(section, {})[name] = yaml.safe_load(value)
        params = args.work / 'params.yaml'
        params.write_text(yaml.safe_dump({'/**': {'ros__parameters': nested}}))
    codes: dict[str, Path] = {'this': ROOT}
    worktree = None
    if args.baseline:
        worktree = Path(tempfile.mkdtemp(prefix='srmosaic-baseline-'))
        subprocess.run(['git', 'worktree', 'add', '--detach', str(worktree), args.baseline], check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL)
        codes = {'baseline': worktree, 'this': ROOT}
    rows = []
    try:
        for size in sizes:
            frames = args.frames if size != '3840x2160' else min(args.frames, 60)
            video, sidecar, truth = make_flight(args.work, size, frames, args.fresh)
            for name, code in codes.items():
                out = args.work / f'out_{size}_{name}'
                print(f'{size}: process ({name}) ...', flush=True)
                report = run_process(code, video, sidecar, out, params if name == 'this' or args.set_baseline_too else None)
                rows.append(row(name, size, report, truth, out))
                print(f"  {rows[-1]['fps']:.1f} frames/s, error {rows[-1]['corner_error_mean_px']:.3f} px", flush=True)
    finally:
        if worktree is not None:
            subprocess.run(['git', 'worktree', 'remove', '--force', str(worktree)], cwd=ROOT, check=False)
    print()
    print_table(rows)
    summary = {'rows': rows, 'baseline': args.baseline, 'set': args.set, 'flight': FLIGHT}
    (args.work / 'throughput.json').write_text(json.dumps(summary, indent=2, default=str))
    print(f"figures -> {args.work / 'throughput.json'}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
