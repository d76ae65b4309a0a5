"""Benchmark: vehicles in the mosaic, against the simulator's truth (issue 17).

A simulated flight with traffic (`srmosaic simulate --vehicles`) is mosaicked by the pipeline in
its first frame's plane (georeferencing off, so that mosaic pixel p is world pixel
``world_px_H_frame_0 @ p``) with each blend. Over the ground some vehicle covered in some frame
(the trail area), the mosaic is compared with the static ground: a trail pixel "shows traffic"
when it differs from the traffic-free flight's mosaic by more than 25 grey levels (any channel).
The goal: below 1 % of the trail area. Also printed: the same count over the ground no vehicle
ever covered (the floor: two mosaics of the same static ground differ there only where their
frames' choice differs), the trail pixels seen by at least 3 frames (fewer cannot outvote a car),
and PSNR of the whole mosaic against the traffic-free one. The truth's own count, without that
floor: the trail pixels the mosaic takes from a frame in which a vehicle covers that ground
(TiledCanvas.labels and Truth.vehicles_shown: the simulator's vehicle masks at each frame's time; best view and
multiband, whose pixels each come from one frame, blended with its neighbours across seams).

    python bench/traffic.py [--vehicles 30] [--frames 40]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.traffic import vehicle_mask


RUNS = {'feather': {'mosaic.blend': 'feather'}, 'multiband': {'mosaic.blend': 'multiband'},
        'bestview': {'mosaic.blend': 'bestview'}, 'bestview, cut': {'mosaic.blend': 'bestview', 'mosaic.seams': 'cut'},
        'bestview, moving 0.05, cut': {'mosaic.blend': 'bestview', 'mosaic.moving': 0.05, 'mosaic.seams': 'cut'},
        'bestview, moving 0.1': {'mosaic.blend': 'bestview', 'mosaic.moving': 0.1},
        'bestview, moving 0.05': {'mosaic.blend': 'bestview', 'mosaic.moving': 0.05},
        'bestview, moving 0.03': {'mosaic.blend': 'bestview', 'mosaic.moving': 0.03}}


def canvas_of(flight, overrides: dict):
    pipe = Pipeline(pipeline_config({'georef.enabled': False, **overrides}))
    for frame in flight.frames:
        pipe.feed_frame(frame)
    seg = pipe.finish().main_segment
    assert seg is not None and len(seg.frames) == len(flight.frames), 'every frame must be in one mosaic'
    return seg


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--vehicles', type=int, default=30)
    ap.add_argument('--frames', type=int, default=40)
    ap.add_argument('--speed', type=float, default=8.0)
    ap.add_argument('--only', default='', help="the runs to make, ';'-separated names of RUNS (default: all)")
    args = ap.parse_args()
    runs = {name: RUNS[name] for name in args.only.split(';')} if args.only else RUNS
    cfg = SimConfig(frames=args.frames, vehicles=args.vehicles, vehicle_speed_m_s=args.speed, seed=5)
    cars, empty = simulate(cfg), simulate(cfg.replace(vehicles=0))
    truth = cars.truth
    print(f'{args.frames} frames, {args.vehicles} vehicles at {args.speed} m/s\n')
    print('| blend | trail area (px) | trail pixels showing traffic | of those seen by >= 3 frames | elsewhere (floor) '
          '| trail pixels from a frame with a vehicle there (truth) | PSNR vs traffic-free mosaic (dB) |')
    print('|---|---|---|---|---|---|---|')
    for blend, overrides in runs.items():
        seg = canvas_of(cars, overrides)
        canvas = seg.canvas
        x0, y0, x1, y1 = canvas.bounds()
        image, covered = canvas.render((x0, y0, x1, y1))
        clean, clean_covered = canvas_of(empty, overrides).canvas.render((x0, y0, x1, y1))
        covered &= clean_covered
        # trail: mosaic pixels some vehicle covered in some frame (frame 0's plane = the mosaic's)
        h0 = truth.frames[0].world_px_H_frame @ np.array([[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1.0]])
        trail = np.zeros((y1 - y0, x1 - x0), bool)
        for k in range(len(truth.frames)):
            trail |= vehicle_mask(truth.vehicles, truth.time_s(k), h0, (x1 - x0, y1 - y0))
        # the truth's count: mosaic pixels taken from a frame in which a vehicle covers that ground
        from_vehicle = (truth.vehicles_shown(canvas.labels((x0, y0, x1, y1)), seg.frames, h0)
                        if canvas.blend != 'feather' else np.zeros(trail.shape, bool))
        seen = np.zeros(trail.shape, np.int32)  # frames over each mosaic pixel (their true footprints)
        for f in truth.frames:
            frame_H_mosaic = np.linalg.inv(f.world_px_H_frame) @ h0
            seen += cv2.warpPerspective(np.ones((cfg.height, cfg.width), np.uint8), np.linalg.inv(frame_H_mosaic),
                                        (x1 - x0, y1 - y0), flags=cv2.INTER_NEAREST)
        floor = covered & ~trail
        trail &= covered
        differs = np.abs(image - clean).max(axis=2) * 255.0 > 25.0
        shows, shows3 = differs[trail].mean(), differs[trail & (seen >= 3)].mean()
        mse = float(np.mean((image[covered] - clean[covered]) ** 2))
        vehicle = f'{from_vehicle[trail].mean():.2%}' if canvas.blend != 'feather' else 'n/a'
        print(f'| {blend} | {int(trail.sum())} | {shows:.1%} | {shows3:.1%} | {differs[floor].mean():.2%} '
              f'| {vehicle} | {10 * np.log10(1 / max(mse, 1e-12)):.2f} |', flush=True)
        out = ROOT / 'bench' / 'out' / f'traffic_{blend.replace(", ", "_").replace(" ", "_")}.png'
        out.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out), cv2.cvtColor((np.clip(image, 0, 1) * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))


if __name__ == '__main__':
    main()
