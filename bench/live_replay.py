"""Benchmark: bench/live.py's flight replayed offline through the mosaic node's pipeline, frame by frame.

The live bench says where a node falls behind (`--plot`); this one says why. The same simulated
flight (bench/live.py's flight options and `--flight-cache`) goes through `Pipeline` in this
process as the mosaic node runs it (the parameter file's settings, the painter thread, one torch
thread), telemetry and frames merged by stamp, with no DDS and no clock: the work per frame
only. Printed: per span of the flight the mean ms per frame of each stage (report.json's
stage_times: describe, register, fuse on the worker; paint on the painter), the keyframes
registered to the mosaic and applied, and the placement error of the main segment against the
truth (mean corner error after the best-fitting plane homography, mosaic px; as
`srmosaic evaluate`), and the main segment's mosaic against the true orthophoto (PSNR over the
pixels it covers, its plane placed by the first frame's truth). `--plot PNG` draws the stages per
frame along the flight.

    OMP_NUM_THREADS=1 python bench/live_replay.py --fps 30 --seconds 60 --width 1280 --height 720 \\
        --params-file params/live_hd.yaml --flight-cache /tmp/flight720.pkl [--set mosaic.keyframe_interval=10]
        [--span 5] [--plot stages.png]
"""
from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'bench'))

from live import add_flight_arguments, flight_from_arguments

STAGES = ('describe', 'register', 'fuse', 'paint')


def replay(flight, overrides: dict) -> dict:
    """Feed the flight through a Pipeline configured by ``overrides``; per-frame stage seconds, the
    records and the keyframe outcomes."""
    import torch

    from srmosaic_ros.config import pipeline_config
    from srmosaic_ros.core.types import Frame
    from srmosaic_ros.pipeline import Pipeline

    torch.set_num_threads(1)  # as the node (live.torch_threads)
    pipe = Pipeline(pipeline_config(overrides), paint_thread=True)
    items = [(f.stamp_ns, 0, f) for f in flight.fixes] + [(m.stamp_ns, 0, m) for m in flight.imus] + \
            [(f.stamp_ns, 1, Frame(f.stamp_ns, f.image, flight.camera, 'camera')) for f in flight.frames]
    items.sort(key=lambda item: (item[0], item[1]))
    last = flight.frames[-1].stamp_ns
    pipe.feed(flight.camera)
    t0 = time.perf_counter()
    for stamp, is_frame, item in items:
        if stamp > last:
            break
        pipe.feed(item)
        if is_frame:
            pipe.clock.end_frame()
    pipe.flush()
    result = pipe.finish()
    wall = time.perf_counter() - t0
    samples = {s: pipe.clock.per_frame_ms(s) for s in STAGES}
    return {'samples': samples, 'records': pipe.records, 'wall_s': wall, 'result': result}


def mosaic_psnr(flight, result) -> tuple[float, float]:
    """(PSNR in dB of the main segment's mosaic against the true orthophoto in its plane, over the
    pixels it covers; those pixels in Mpx). The plane is placed by the first frame's truth, so
    drift along the flight costs PSNR too."""
    from srmosaic_ros.sim.ortho_error import ortho_in_plane

    seg = result.main_segment
    first = seg.frames[0]
    world_H_seg = flight.truth.frames[first].world_px_H_frame @ np.linalg.inv(seg.seg_H_frames[first])
    x0, y0, x1, y1 = seg.canvas.bounds()
    image, covered = seg.canvas.render((x0, y0, x1, y1))
    truth = ortho_in_plane(flight.world.image, world_H_seg @ np.array([[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1.0]]),
                           (x1 - x0, y1 - y0))
    err = (np.asarray(image, np.float32) - truth) ** 2
    mse = float(err.reshape(*covered.shape, -1).mean(axis=2)[covered].mean())
    return 10.0 * np.log10(1.0 / mse), float(covered.sum()) / 1e6


def placement_error(flight, records: list) -> tuple[np.ndarray, np.ndarray]:
    """(frame indices, mean corner error in mosaic px) of the main segment's frames against the truth."""
    from srmosaic_ros.core.metrics import mosaic_corner_errors

    placed = [r for r in records if r.seg_H_frame is not None]
    main = collections.Counter(r.segment for r in placed).most_common(1)[0][0]
    placed = [r for r in placed if r.segment == main]
    truth = {t.stamp_ns: t for t in flight.truth.frames}
    h, w = flight.frames[0].image.shape[:2]
    err, _ = mosaic_corner_errors([r.seg_H_frame for r in placed], [truth[r.stamp_ns].world_px_H_frame for r in placed],
                                  w, h)
    return np.array([r.index for r in placed]), err


def plot(samples: dict, fps: float, path: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.5))
    n = min(len(v) for v in samples.values())
    t = np.arange(n) / fps
    k = max(1, int(round(fps / 2)))  # half-second means: single frames are noise
    for stage in STAGES:
        v = np.convolve(samples[stage][:n], np.ones(k) / k, mode='same')
        ax.plot(t, v, label=stage)
    ax.axhline(1e3 / fps, color='grey', ls='--', lw=0.8, label='frame period')
    ax.set_xlabel('s into the flight')
    ax.set_ylabel('ms per frame (half-second mean)')
    ax.legend(loc='upper left', fontsize=8, ncol=5)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_flight_arguments(ap)
    ap.add_argument('--params-file', type=Path, default=None, help='the nodes\' parameter file (e.g. params/live_hd.yaml)')
    ap.add_argument('--set', action='append', default=[], metavar='KEY=VALUE', help='a parameter on top; repeatable')
    ap.add_argument('--span', type=float, default=5.0, help='seconds of flight per printed row (default 5)')
    ap.add_argument('--plot', type=Path, default=None, help='PNG of the stages per frame along the flight')
    args = ap.parse_args()
    import yaml

    from srmosaic_ros.param_files import load_params

    if args.params_file is not None and not args.params_file.is_file():
        ap.error(f'--params-file {args.params_file}: no such file')
    overrides = load_params(args.params_file) if args.params_file is not None else {}
    overrides = {k: v for k, v in overrides.items() if not k.startswith('live.')}
    for item in args.set:
        key, sep, value = item.partition('=')
        if not sep:
            ap.error(f'--set {item!r}: use KEY=VALUE')
        overrides[key] = yaml.safe_load(value)
    flight = flight_from_arguments(args)
    print(f'replaying {len(flight.frames)} frames with {overrides} ...', flush=True)
    out = replay(flight, overrides)
    samples, records = out['samples'], out['records']
    per = max(1, int(round(args.span * args.fps)))
    print(f"{'span s':>12} " + ' '.join(f'{s:>9}' for s in STAGES) + f" {'worker':>8}  (mean ms per frame)")
    for a in range(0, len(samples['describe']), per):
        row = {s: float(samples[s][a:a + per].mean()) for s in STAGES}
        worker = row['describe'] + row['register'] + row['fuse']
        print(f'{a / args.fps:5.1f}-{(a + per) / args.fps:5.1f} ' + ' '.join(f'{row[s]:9.1f}' for s in STAGES)
              + f' {worker:8.1f}')
    keyframes = [r.keyframe for r in records if getattr(r, 'keyframe', None) is not None]
    applied = sum(k.seg_H_frame is not None for k in keyframes)
    index, err = placement_error(flight, records)
    print(f'{len(records)} frames in {out["wall_s"]:.1f} s; keyframes registered to the mosaic {len(keyframes)}, '
          f'applied {applied}; main segment {len(index)} frames, corner error against the truth mean '
          f'{err.mean():.3f} px, max {err.max():.3f} px (mosaic px)')
    psnr, mpx = mosaic_psnr(flight, out['result'])
    print(f'main segment mosaic against the true orthophoto: PSNR {psnr:.2f} dB over {mpx:.2f} Mpx')
    if args.plot is not None:
        plot(samples, args.fps, args.plot)
        print(f'stages plot -> {args.plot}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
