"""Benchmark: oblique cameras with GPS and intrinsics but no measured attitude (issue 17).

Simulated straight lines (160x120, 40 frames at 2 Hz, 80 m, HFOV 40, 2 deg gusts; optionally over
buildings) are written as rosbag2 and run through `process` without their Imu topic, as a flight
whose metadata has positions and a camera but no attitude. Each camera elevation is run three ways:

- ``nadir assumed``: the pose check's mount test off (pose_check.MOUNT_TOLERANCE_DEG set to 90):
  the drift control's NIS alone decides whether the filter places the frames, as before the
  frames' mount existed (the geotag fit still refuses a chain they show tilted: before, a line 55
  deg below the horizon refused by the NIS went to its geotags and landed 70.5 m off);
- ``now``: the defaults (the frames' mount refuses a wrong one; the run starts again with it);
- ``no restart``: georef.mount_from_frames false (chained when refused).

Printed per row: the frames' mount (elevation, azimuth from the travel, spread of the normals),
how the run was placed (filter / geotags / not), the corner error mean against the truth (px) and
the map RMS (m) from `srmosaic evaluate --truth`.

    python bench/mount_from_frames.py [--elevations -55 -70 -75 -78 -80 -90] [--buildings 0]
                                      [--building-height 10]

About 25 s for the six default lines on this machine; docs/results.md ("Poses checked against
the frames") has the tables (with --buildings 20 / 40 too).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.app.process import process_input
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.georef import pose_check
from srmosaic_ros.io.bags import TopicConfig
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.record import write_flight


def _run(bag: Path, out: Path, overrides: dict, *, nadir_assumed: bool = False) -> str:
    """One process + evaluate; the row's cell."""
    tolerance = pose_check.MOUNT_TOLERANCE_DEG
    if nadir_assumed:
        pose_check.MOUNT_TOLERANCE_DEG = 90.0
    try:
        report = process_input(bag, out, pipeline_config(overrides), topics=TopicConfig(imu=''), progress=False)
    finally:
        pose_check.MOUNT_TOLERANCE_DEG = tolerance
    fig = evaluate_dir(out, bag / 'ground_truth.json')
    placed = (report.get('georeferenced') or {}).get('method', 'not')
    where = f"{fig['georef_error_rms_m']:.2f} m" if fig.get('georef_error_rms_m') is not None else '-'
    nis = report.get('pose_placement', {}).get('median_nis')
    restarted = ' (started again)' if 'mount_from_frames' in report else ''
    return f"{placed}{restarted}, NIS {nis}: {fig['corner_error_mean_px']:.3f} px, {where}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--elevations', type=float, nargs='+', default=[-55.0, -70.0, -75.0, -78.0, -80.0, -90.0])
    ap.add_argument('--buildings', type=int, default=0)
    ap.add_argument('--building-height', type=float, default=10.0)
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    work = Path(tempfile.mkdtemp(prefix='mount_from_frames_'))
    print('| camera elevation | frames\' mount (el, az, spread) | nadir assumed | now | no restart |')
    print('|---|---|---|---|---|')
    for elevation in args.elevations:
        cfg = SimConfig(trajectory='line', frames=40, rate_hz=2.0, altitude_m=80.0, hfov_deg=40.0, width=160,
                        height=120, gimbal_elevation_deg=elevation, seed=4, buildings=args.buildings,
                        building_height_m=args.building_height)
        bag = write_flight(simulate(cfg), work / f'bag{elevation:g}')
        before = _run(bag, work / f'a{elevation:g}', {}, nadir_assumed=True)
        now_out = work / f'b{elevation:g}'
        now = _run(bag, now_out, {})
        placement = json.loads((now_out / 'report.json').read_text())
        shown = (placement.get('mount_from_frames') or {}).get('first_check', placement.get('pose_placement', {}))
        shown = shown.get('frames_mount')
        mount = '-' if shown is None else f"{shown['elevation_deg']}, {shown['azimuth_deg']}, {shown['spread_deg']}"
        chained = _run(bag, work / f'c{elevation:g}', {'georef.mount_from_frames': False})
        print(f'| {elevation:g} | {mount} | {before} | {now} | {chained} |', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
