"""Benchmark: frame selection on H.264 video, I-frames against all frames (the reference's Table 23).

One synthetic flight (srmosaic_ros.sim; the same code `srmosaic simulate --video --gop G` runs) is
encoded as H.264 with an I-frame every G frames for each G of --gops; the frames come from one
simulation, so the videos differ only in their GOP. The flight: a straight line east at 100 m
above the caliterra orthophoto, 640 x 480 RGB frames, 60 deg horizontal field of view
(0.18 m per frame pixel, a 115 m x 87 m footprint), 15 frames/s at 7 m/s (2.6 px of motion
between frames), 2 deg RMS gusts; 601 frames by default (40 s, 280 m), so that frame 600, the
last, is an I-frame for G = 12, 20 and 30 and every selection ends on the same frame.

`process` (srmosaic_ros.app.process.process_input, called in this process with the default
parameters, `--hfov 60`, no telemetry: the pure registration chain, as in the reference, and no
checkpoints) then runs on each video with:

- ``all``: every frame (G - 1 of every G are P-frames, decoded and registered);
- ``iframes``: I-frames only (the decoder skips the others, section 4.3 / Appendix A);
- ``every:G``: the same frames as ``iframes`` but decoded through the P-frames (a control: the
  difference from ``iframes`` is decoding time and the coding quality of the frames, not which
  frames are used);
- ``overlap:F`` (--overlap, 0 to skip): adaptive selection when the overlap with the last
  selected frame falls below F.

Figures per run: frames selected and registered, wall time of `process` (s: decoding,
registration, mosaic and outputs, as report.json's wall_s), frames selected per second, the
end-of-flight geometric error (px: corner error of the last registered frame's mosaic homography
against the truth, after the mosaic plane is related to the ground by a fitted homography; see
srmosaic_ros.app.evaluate and core.metrics.mosaic_corner_errors), the mean and max corner error over
the selected frames, the mean corner error between consecutive selected frames, and the number of
mosaic segments. The figures go to --work/video_selection.json (default bench/out/video_selection).

    OMP_NUM_THREADS=1 python bench/video_selection.py [--quick] [--frames 601] [--gops 12,20,30]
                                                      [--overlap 0.8] [--work DIR] [--fresh]

--quick: 121 frames, GOPs 12 and 30 (about a minute). The default takes about 6 minutes on two cores, half
of it simulating and encoding the videos, which later runs with the same settings reuse (--fresh redoes them).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.io.mosaic_files import read_frames_csv
from srmosaic_ros.app.process import process_input
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.cli import _write_video_and_sidecar
from srmosaic_ros.sim.truth import save_truth

#: The flight (see the module docstring); frames and seed come from the command line.
FLIGHT = {'trajectory': 'line', 'rate_hz': 15.0, 'speed_m_s': 7.0, 'altitude_m': 100.0, 'heading_deg': 0.0,
          'width': 640, 'height': 480, 'hfov_deg': 60.0}


def make_videos(work: Path, frames: int, gops: list[int], seed: int, fresh: bool) -> tuple[dict[int, Path], Path]:
    """Simulate the flight once and encode it for each GOP; reuse earlier files with the same settings.

    Returns ({gop: video path}, ground_truth.json path).
    """
    stamp = work / 'flight.args.json'
    args = {**FLIGHT, 'frames': frames, 'seed': seed}
    truth = work / 'ground_truth.json'
    videos = {g: work / f'flight_gop{g}.mp4' for g in gops}
    previous = json.loads(stamp.read_text()) if stamp.is_file() else None
    if not fresh and previous == args and truth.is_file() and all(v.is_file() for v in videos.values()):
        print(f'reusing the {frames}-frame videos in {work}')
        return videos, truth
    print(f'simulating {frames} frames ...', flush=True)
    t0 = time.perf_counter()
    flight = simulate(SimConfig(**args), progress=False)
    print(f'  {time.perf_counter() - t0:.0f} s', flush=True)
    for g, path in videos.items():
        t0 = time.perf_counter()
        _write_video_and_sidecar(flight, path, g)
        print(f'  {path.name}: GOP {g}, {path.stat().st_size / 1e6:.1f} MB, {time.perf_counter() - t0:.0f} s',
              flush=True)
    save_truth(flight.truth, truth)
    stamp.write_text(json.dumps(args))
    return videos, truth


def run_one(video: Path, truth: Path, out: Path, select: str, rate_hz: float, config: Any) -> dict[str, Any]:
    """`process VIDEO --select SELECT` in this process, evaluated against the truth; one table row."""
    report = process_input(video, out, config, select=select, hfov_deg=FLIGHT['hfov_deg'], progress=False)
    ev = evaluate_dir(out, truth)
    rows = read_frames_csv(out / 'frames.csv')
    ok = [r for r in rows if r['ok']]
    last_frame = round(ok[-1]['stamp_ns'] * rate_hz / 1e9) if ok else None
    selected = report['video']['frames_selected']
    return {
        'select': select, 'frames_selected': selected, 'frames_decoded': report['video']['frames_decoded'],
        'frames_registered': report['frames_registered'], 'segments': len(report['segments']),
        'wall_s': report['wall_s'], 'frames_per_s': round(selected / report['wall_s'], 2),
        'end_error_px': ev.get('corner_error_last_px'), 'last_frame_index': last_frame,
        'mean_error_px': ev['corner_error_mean_px'], 'max_error_px': ev['corner_error_max_px'],
        'pair_error_mean_px': ev['pair_corner_error_mean_px'], 'peak_rss_mb': report['peak_rss_mb'],
    }


def _fmt(value: float | None, spec: str) -> str:
    return 'n/a' if value is None or value != value else format(value, spec)  # NaN != NaN


def print_table(results: list[dict[str, Any]]) -> None:
    head = (f"{'GOP':>4} {'select':<12} {'frames':>6} {'reg.':>5} {'wall s':>7} {'frames/s':>9} "
            f"{'end err px':>10} {'(frame)':>7} {'mean err px':>11} {'max px':>7} {'pair px':>8} {'segs':>4}")
    print(head)
    print('-' * len(head))
    for r in results:
        print(f"{r['gop']:>4} {r['select']:<12} {r['frames_selected']:>6} {r['frames_registered']:>5} "
              f"{r['wall_s']:>7.1f} {r['frames_per_s']:>9.1f} {_fmt(r['end_error_px'], '.3f'):>10} "
              f"{str(r['last_frame_index']):>7} {_fmt(r['mean_error_px'], '.3f'):>11} "
              f"{_fmt(r['max_error_px'], '.3f'):>7} {_fmt(r['pair_error_mean_px'], '.4f'):>8} {r['segments']:>4}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--frames', type=int, default=None, help='frames of the flight (default 601; --quick 121)')
    ap.add_argument('--gops', default=None, help='comma-separated GOP lengths (default 12,20,30; --quick 12,30)')
    ap.add_argument('--overlap', type=float, default=0.8,
                    help='F of the overlap:F run (default 0.8; 0 skips that run)')
    ap.add_argument('--seed', type=int, default=3, help='simulator seed (default 3)')
    ap.add_argument('--quick', action='store_true', help='121 frames, GOPs 12 and 30')
    ap.add_argument('--work', type=Path, default=ROOT / 'bench' / 'out' / 'video_selection',
                    help='videos, truth, outputs and the JSON (default bench/out/video_selection)')
    ap.add_argument('--fresh', action='store_true', help='simulate and encode again even if the videos exist')
    args = ap.parse_args(argv)
    frames = args.frames or (121 if args.quick else 601)
    gops = [int(g) for g in (args.gops or ('12,30' if args.quick else '12,20,30')).split(',')]
    if frames < 2 or any(g < 1 for g in gops):
        ap.error(f'need --frames >= 2 and GOPs >= 1, got {frames} and {gops}')
    if not 0.0 <= args.overlap < 1.0:
        ap.error(f'--overlap must be in [0, 1), got {args.overlap}')
    if os.environ.get('OMP_NUM_THREADS') is None:
        print('note: OMP_NUM_THREADS is not set; on a shared machine set it to 1 for comparable timings')
    args.work.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    videos, truth = make_videos(args.work, frames, gops, args.seed, args.fresh)
    config = pipeline_config()  # params/default.yaml, read once: every run uses the same parameters
    results = []
    for g in gops:
        selects = ['all', 'iframes', f'every:{g}'] + ([f'overlap:{args.overlap:g}'] if args.overlap > 0 else [])
        for select in selects:
            print(f'GOP {g}: process --select {select} ...', flush=True)
            out = args.work / f'gop{g}_{select.replace(":", "")}'
            row = {'gop': g, **run_one(videos[g], truth, out, select, FLIGHT['rate_hz'], config)}
            print(f"  {row['frames_selected']} frames, {row['wall_s']:.1f} s, end error "
                  f"{_fmt(row['end_error_px'], '.3f')} px", flush=True)
            results.append(row)
    print(f'\n{frames} frames {FLIGHT["width"]}x{FLIGHT["height"]} at {FLIGHT["rate_hz"]:g} Hz, line flight, '
          'H.264 (libx264); errors in frame pixels against the ground truth')
    print_table(results)
    total = time.perf_counter() - t_start
    print(f'total {total:.0f} s')
    summary = {'frames': frames, 'gops': gops, 'flight': {**FLIGHT, 'seed': args.seed}, 'results': results,
               'total_s': round(total, 1), 'config': {'registration': vars(config.registration),
                                                      'mosaic': vars(config.mosaic)}}
    (args.work / 'video_selection.json').write_text(json.dumps(summary, indent=2, default=str))
    print(f"figures -> {args.work / 'video_selection.json'}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
