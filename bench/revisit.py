"""Benchmark: a flight that comes back over its own ground after a lap, and what the keyframe
corrections there do to the mosaic, painted at once or with the correction spread back
(`mosaic.revisit_spread_frames`, core/mosaic/revisit.py). Issue 16, live revisits.

A simulated nadir orbit (2.2 laps at 1 frame/s, 60 m radius, 80 m up) over ground with buildings:
their parallax pulls the plane registrations a little each frame, so the chain has drifted by
pixels when the flight is back over its first frames (a flat world drifts by hundredths). Each
configuration runs the pipeline in its first frame's plane (georeferencing off: nothing but the
mosaic itself can close the loop) and prints, against the truth:

- corner error of every placement (px, in each frame's pixels, after the first frame's plane);
- the tear: the largest error of one frame's placement relative to the one before it (px), the
  step a correction applied to one frame alone leaves in the strip being painted;
- the mosaic's PSNR against the true orthophoto on open ground (dB), and the keyframe report.

With --georef the flight's GPS and IMU are fused too (drift control pulls the chain toward the
poses on the UTM raster; the errors are still taken after the first frame's placement).

The mosaics are written side by side to bench/out/revisit_<config>.png.

With --look-at the camera looks at the orbit's centre from 53 degrees down (a loiter): every
footprint stays on that ground and turns with the aircraft, a full turn a lap.

    python bench/revisit.py [--buildings 12] [--laps 2.2] [--spread 10] [--max-correction 60] [--georef] [--look-at]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.app.process import keyframe_report
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.homography import corner_shift_px
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.buildings import paint_roofs
from srmosaic_ros.sim.ortho_error import ortho_in_plane, region_errors, region_masks


def run(flight, overrides: dict, georef: bool = False):
    pipe = Pipeline(pipeline_config({'georef.enabled': georef, **overrides}))
    if georef:  # frames and telemetry in time order, as a bag gives them
        for item in sorted([*flight.frames, *flight.fixes, *flight.imus], key=lambda m: m.stamp_ns):
            pipe.feed(item)
    else:
        for frame in flight.frames:
            pipe.feed_frame(frame)
    return pipe.finish()


def measure(flight, result, name: str, out_dir: Path, wall_s: float) -> dict:
    truth = flight.truth
    seg = result.main_segment
    size = (truth.camera.width, truth.camera.height)
    first = seg.frames[0]
    world_H_seg = truth.frames[first].world_px_H_frame @ np.linalg.inv(seg.seg_H_frames[first])
    corner, tear, tear_at = [], [], []
    prev = None
    for k in seg.frames:
        true_H = np.linalg.inv(world_H_seg) @ truth.frames[k].world_px_H_frame
        corner.append(corner_shift_px(np.linalg.inv(true_H) @ seg.seg_H_frames[k], np.eye(3), *size))
        if prev is not None and prev == k - 1:  # frame k relative to frame k-1, against the truth's
            rel = np.linalg.inv(seg.seg_H_frames[prev]) @ seg.seg_H_frames[k]
            true_rel = np.linalg.inv(truth.frames[prev].world_px_H_frame) @ truth.frames[k].world_px_H_frame
            tear.append(corner_shift_px(np.linalg.inv(true_rel) @ rel, np.eye(3), *size))
            tear_at.append(k)
        prev = k
    x0, y0, x1, y1 = seg.canvas.bounds()
    image, covered = seg.canvas.render((x0, y0, x1, y1))
    world_H_region = world_H_seg @ np.array([[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1.0]])
    ortho = paint_roofs(flight.world.image, truth.buildings, truth.world_gsd_m) if truth.buildings else flight.world.image
    true_img = ortho_in_plane(ortho, world_H_region, (x1 - x0, y1 - y0))
    masks = region_masks(truth.buildings, world_H_region, (x1 - x0, y1 - y0), truth.world_gsd_m, 15.0)
    psnr = region_errors(image, covered, true_img, masks).psnr_db['open']
    side = np.hstack([np.clip(image, 0, 1), true_img])
    cv2.imwrite(str(out_dir / f'revisit_{"".join(c if c.isalnum() else "_" for c in name)}.png'),
                cv2.cvtColor((side * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))
    kf = keyframe_report(result.records)
    row = {'config': name, 'frames': f'{len(seg.frames)}/{len(flight.frames)}', 'corner_mean': float(np.mean(corner)),
           'corner_max': float(np.max(corner)), 'tear_max': float(np.max(tear)), 'tear_p99': float(np.percentile(tear, 99)),
           'psnr_open': psnr, 'keyframes': kf, 'wall_s': wall_s, 'tear_frame': tear_at[int(np.argmax(tear))]}
    print(f'| {name} | {row["frames"]} | {row["corner_mean"]:.2f} / {row["corner_max"]:.2f} | {row["tear_max"]:.2f} '
          f'| {psnr:.2f} | {kf["applied"]}/{kf["tried"]}, max {kf["shift_px_max"]} {kf["not_applied"] or ""} | {kf["frames_moved_back"]} '
          f'| {wall_s:.0f} |', flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--buildings', type=int, default=12)
    ap.add_argument('--height', type=float, default=15.0, help='tallest building (m)')
    ap.add_argument('--laps', type=float, default=2.2)
    ap.add_argument('--spread', default='10', help='mosaic.revisit_spread_frames values to compare with 0 and the default')
    ap.add_argument('--seed', type=int, default=4)
    ap.add_argument('--look-at', action='store_true', help='the camera looks at the orbit\'s centre (oblique, as a loiter)')
    ap.add_argument('--only', default='', help='configuration names to run, separated by semicolons (default: all)')
    ap.add_argument('--georef', action='store_true', help='with the GPS and IMU (drift control on the UTM raster)')
    ap.add_argument('--max-correction', type=float, default=0.0,
                    help='also run these with mosaic.keyframe_max_correction_px at this value (0: not)')
    args = ap.parse_args()
    cfg = SimConfig(trajectory='orbit', orbit_radius_m=60.0, laps=args.laps, altitude_m=80.0, hfov_deg=50.0,
                    orbit_look_at=args.look_at, speed_m_s=10.0, rate_hz=1.0, seed=args.seed, buildings=args.buildings,
                    building_height_m=args.height)
    out_dir = ROOT / 'bench' / 'out'
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    flight = simulate(cfg)
    view = 'oblique orbit looking at its centre' if args.look_at else 'nadir orbit'
    print(f'simulated {len(flight.frames)} frames in {time.perf_counter() - t0:.0f} s: {view} of {args.laps:g} '
          f'laps, 60 m radius, 80 m up, {args.buildings} buildings up to {args.height:g} m\n')
    print('| configuration | frames | corner error px mean / max | tear px max | PSNR open ground dB '
          '| keyframes applied/tried, largest shift px | frames moved back | s |')
    print('|---|---|---|---|---|---|---|---|')
    configs = {'no keyframes': {'mosaic.keyframe_interval': 0},
               'keyframes up to 10 px, painted at once (before)': {'mosaic.keyframe_max_correction_px': 10.0,
                                                                   'mosaic.revisit_spread_frames': 0},
               'keyframes, painted at once': {'mosaic.revisit_spread_frames': 0}}
    for n in (int(v) for v in args.spread.split(',') if v):
        configs[f'keyframes, spread over {n}'] = {'mosaic.revisit_spread_frames': n}
    configs['defaults'] = {}
    if args.max_correction > 0:
        configs[f'keyframes up to {args.max_correction:g} px, painted at once'] = {
            'mosaic.keyframe_max_correction_px': args.max_correction, 'mosaic.revisit_spread_frames': 0}
        configs[f'keyframes up to {args.max_correction:g} px, spread as the defaults'] = {
            'mosaic.keyframe_max_correction_px': args.max_correction}
    if args.only:
        configs = {name: configs[name] for name in args.only.split(';')}
    results, rows = {}, {}
    for name, overrides in configs.items():
        t0 = time.perf_counter()
        results[name] = run(flight, overrides, args.georef)
        rows[name] = measure(flight, results[name], name, out_dir, time.perf_counter() - t0)
    # the same ground, full resolution, around the worst tear of the corrections painted at once
    at_once = 'keyframes, painted at once'
    if at_once not in results or 'defaults' not in results:
        return
    seg = results[at_once].main_segment
    k = rows[at_once]['tear_frame']
    c = seg.seg_H_frames[k] @ np.array([size / 2 for size in (flight.truth.camera.width, flight.truth.camera.height)] + [1.0])
    x, y = int(c[0] / c[2]), int(c[1] / c[2])
    crops = [results[n].main_segment.canvas.render((x - 300, y - 300, x + 300, y + 300))[0] for n in (at_once, 'defaults')]
    cv2.imwrite(str(out_dir / 'revisit_tear.png'), cv2.cvtColor((np.hstack(crops).clip(0, 1) * 255).astype(np.uint8),
                                                                 cv2.COLOR_RGB2BGR))
    print(f'\nbench/out/revisit_tear.png: the ground around frame {k}, {at_once} | defaults')


if __name__ == '__main__':
    main()
