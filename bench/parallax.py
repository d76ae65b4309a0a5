"""Benchmark: a homography mosaic of ground with buildings, against the true orthophoto (issue 17, parallax).

A simulated oblique orbit over ground with buildings (`srmosaic simulate --buildings N`) is mosaicked
by the pipeline in its first frame's plane (georeferencing off, so mosaic pixel p is world pixel
``world_px_H_frame_0 @ inv(seg_H_frame_0) @ p``), with each blend. The mosaic is compared with the
true orthophoto (the world with the roofs painted) by kind of ground (sim/ortho_error.py): open
ground, ground near a building (within --near metres: walls and displaced roofs fall there, and the
ground is hidden from some views) and roofs. Beside each blend: the best single frame, placed with
its TRUE homography (the best a single view can do in that plane, per region, over the ground it
and the mosaic cover; among the frames covering at least a fifth of the region), and in brackets
the mosaic's PSNR over that frame's pixels (the same ground for both: the mosaic's own figure
includes the rim that only far-field views see). Also: the
registration's corner error against the truth (does it lock onto the ground plane?) and the same
flight without buildings as the control.

With --vehicles N the flight has traffic too (cars kept off the buildings), and each mosaic is also
compared with the same flight's mosaic without the cars: the share of the ground some car covered
in some frame (the trail area) that the mosaic shows differently by more than 25 grey levels (the
vehicle ghosts; bench/traffic.py's measure). With --crf Q every frame goes through H.264 at that
constant rate factor (28: a few Mbit/s at 640x480; 18: visually lossless) and back.

    python bench/parallax.py [--buildings 12] [--height 15] [--frames 42] [--size 640x480]
                             [--vehicles 20] [--crf 28]
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

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.homography import corner_shift_px
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.buildings import paint_roofs
from srmosaic_ros.io.video import VideoReader, write_video
from srmosaic_ros.sim.ortho_error import REGIONS, ortho_in_plane, region_errors, region_masks
from srmosaic_ros.sim.traffic import vehicle_mask

RUNS = {'feather': {'mosaic.blend': 'feather'}, 'multiband': {'mosaic.blend': 'multiband'},
        'bestview': {'mosaic.blend': 'bestview'},
        'bestview, cut': {'mosaic.blend': 'bestview', 'mosaic.seams': 'cut'},
        'bestview, tukey, cut': {'mosaic.blend': 'bestview', 'registration.photometric_loss': 'tukey', 'mosaic.seams': 'cut'},
        'bestview, tukey': {'mosaic.blend': 'bestview', 'registration.photometric_loss': 'tukey'},
        'bestview, tukey, moving 0.05': {'mosaic.blend': 'bestview', 'registration.photometric_loss': 'tukey',
                                         'mosaic.moving': 0.05},
        'bestview, tukey, moving 0.1': {'mosaic.blend': 'bestview', 'registration.photometric_loss': 'tukey',
                                        'mosaic.moving': 0.1},
        'bestview, tukey, moving 0.05, history 9': {'mosaic.blend': 'bestview', 'registration.photometric_loss': 'tukey',
                                                    'mosaic.moving': 0.05, 'mosaic.moving_history': 9}}


def run(flight, overrides: dict):
    pipe = Pipeline(pipeline_config({'georef.enabled': False, **overrides}))
    for frame in flight.frames:
        pipe.feed_frame(frame)
    seg = pipe.finish().main_segment
    return seg


def through_h264(flight, crf: int, work: Path):
    """The flight with every frame encoded to H.264 at ``crf`` and decoded back (in place)."""
    path = work / f'flight_crf{crf}.mp4'
    write_video(path, (f.image for f in flight.frames), fps=flight.config.rate_hz, crf=crf)
    for frame, decoded in zip(flight.frames, VideoReader(path), strict=True):
        frame.image = decoded.image
    return flight


def ghosts(seg, clean_seg, truth) -> tuple[float, float]:
    """Share of the trail area (ground some vehicle covered in some frame) shown > 25 grey levels off
    the traffic-free flight's mosaic, and the same share over the ground no vehicle covered (the
    floor: where the two mosaics differ without traffic, by their registrations and frame choices)."""
    x0, y0, x1, y1 = seg.canvas.bounds()
    image, covered = seg.canvas.render((x0, y0, x1, y1))
    clean, clean_covered = clean_seg.canvas.render((x0, y0, x1, y1))
    h0 = truth.frames[0].world_px_H_frame @ np.linalg.inv(seg.seg_H_frames[0]) @ np.array(
        [[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1.0]])
    trail = np.zeros((y1 - y0, x1 - x0), bool)
    for f in truth.frames:
        trail |= vehicle_mask(truth.vehicles, (f.stamp_ns - truth.frames[0].stamp_ns) * 1e-9, h0, (x1 - x0, y1 - y0))
    both = covered & clean_covered
    trail &= both
    differs = np.abs(image - clean).max(axis=2) * 255.0 > 25.0
    return (float(differs[trail].mean()) if trail.any() else float('nan'),
            float(differs[both & ~trail].mean()) if (both & ~trail).any() else float('nan'))


def measure(flight, near_m: float, out_dir: Path, tag: str, regions_of=None, clean=None) -> None:
    """Print the table row of every blend; ``regions_of``: the buildings whose footprints set the regions
    (default: the flight's own); ``clean``: the same flight without traffic (vehicle ghosts)."""
    truth = flight.truth
    ortho = paint_roofs(flight.world.image, truth.buildings, truth.world_gsd_m) if truth.buildings else flight.world.image
    region_buildings = truth.buildings if regions_of is None else regions_of
    size = (truth.camera.width, truth.camera.height)
    print(f'\n### {tag}: {len(flight.frames)} frames, {len(truth.buildings)} buildings\n')
    print('| mosaic | frames in the main mosaic | corner error px mean / max | PSNR dB open / near / roofs '
          '| best single frame (true H; the mosaic on its pixels) open / near / roofs | pixels open / near / roofs | vehicle ghosts (floor) '
          '| open ground > 25 off the true orthophoto: trail / elsewhere / trail from a frame with a car there (truth) |')
    print('|---|---|---|---|---|---|---|---|')
    for blend, overrides in RUNS.items():
        t0 = time.perf_counter()
        seg = run(flight, overrides)
        x0, y0, x1, y1 = seg.canvas.bounds()
        image, covered = seg.canvas.render((x0, y0, x1, y1))
        world_H_seg = truth.frames[0].world_px_H_frame @ np.linalg.inv(seg.seg_H_frames[0])
        world_H_region = world_H_seg @ np.array([[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1.0]])
        region_size = (x1 - x0, y1 - y0)
        true_img = ortho_in_plane(ortho, world_H_region, region_size)
        masks = region_masks(region_buildings, world_H_region, region_size, truth.world_gsd_m, near_m)
        errors = region_errors(image, covered, true_img, masks)
        # against the truth itself: open ground some vehicle covered, shown > 25 grey levels off the
        # true orthophoto, beside the same share over open ground no vehicle covered
        trail = np.zeros(covered.shape, bool)
        for f in truth.frames:
            trail |= vehicle_mask(truth.vehicles, (f.stamp_ns - truth.frames[0].stamp_ns) * 1e-9, world_H_region,
                                  region_size)
        off = np.abs(image - true_img).max(axis=2) * 255.0 > 25.0
        open_ground = masks['open'] & covered
        vs_truth = (f'{off[open_ground & trail].mean():.1%} / {off[open_ground & ~trail].mean():.1%}'
                    if (open_ground & trail).any() else '-')
        if (open_ground & trail).any() and seg.canvas.blend != 'feather':  # the truth's count (Truth.vehicles_shown)
            shown = truth.vehicles_shown(seg.canvas.labels((x0, y0, x1, y1)), seg.frames, world_H_region)
            vs_truth += f' / {shown[open_ground & trail].mean():.2%}'
        corner = []
        for k, seg_H in seg.seg_H_frames.items():
            true_H = np.linalg.inv(world_H_seg) @ truth.frames[k].world_px_H_frame
            corner.append(corner_shift_px(np.linalg.inv(true_H) @ seg_H, np.eye(3), *size))  # in frame k's pixels
        # the best single view per region: each frame warped into the region by its true homography
        best = {r: -np.inf for r in REGIONS}
        same = dict.fromkeys(REGIONS, float('nan'))  # the mosaic's PSNR over that best frame's own pixels
        region_H_world = np.linalg.inv(world_H_region)
        for k, frame in enumerate(flight.frames):
            H = region_H_world @ truth.frames[k].world_px_H_frame
            img = cv2.warpPerspective(frame.image.astype(np.float32) / 255.0, H, region_size, flags=cv2.INTER_LINEAR)
            inside = cv2.warpPerspective(np.ones(frame.image.shape[:2], np.uint8), H, region_size,
                                         flags=cv2.INTER_NEAREST) > 0
            e = region_errors(img, inside & covered, true_img, masks)
            for r in REGIONS:
                if e.pixels[r] > 0.2 * max(errors.pixels[r], 1) and e.psnr_db[r] > best[r]:
                    best[r] = e.psnr_db[r]
                    same[r] = region_errors(image, inside & covered, true_img, masks).psnr_db[r]
        fmt = ' / '.join(f'{errors.psnr_db[r]:.2f}' for r in REGIONS)
        fmt_best = ' / '.join(f'{best[r]:.2f} ({same[r]:.2f})' for r in REGIONS)
        n = ' / '.join(str(errors.pixels[r]) for r in REGIONS)
        ghost = '{:.1%} ({:.1%})'.format(*ghosts(seg, run(clean, overrides), truth)) if clean is not None else '-'
        print(f'| {blend} | {len(seg.frames)}/{len(flight.frames)} | {np.mean(corner):.3f} / {np.max(corner):.3f} '
              f'| {fmt} | {fmt_best} | {n} | {ghost} | {vs_truth} |  ({time.perf_counter() - t0:.0f} s)', flush=True)
        side = np.hstack([np.clip(image, 0, 1), true_img])
        cv2.imwrite(str(out_dir / f'parallax_{tag}_{blend.replace(", ", "_")}.png'),
                    cv2.cvtColor((side * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--buildings', type=int, default=12)
    ap.add_argument('--height', type=float, default=15.0, help='tallest building (m)')
    ap.add_argument('--frames', type=int, default=None, help='default: the whole orbit (1.1 laps)')
    ap.add_argument('--size', default='640x480')
    ap.add_argument('--near', type=float, default=15.0, help='"near" ground: within this many metres of a footprint')
    ap.add_argument('--vehicles', type=int, default=0)
    ap.add_argument('--crf', type=int, default=None, help='H.264 constant rate factor of every frame (default: none)')
    ap.add_argument('--no-control', action='store_true', help='skip the flat-ground control flight')
    ap.add_argument('--only', default='', help="the runs to make, ';'-separated names of RUNS (default: all)")
    args = ap.parse_args()
    if args.only:
        for name in set(RUNS) - set(args.only.split(';')):
            del RUNS[name]
    w, h = (int(v) for v in args.size.split('x'))
    cfg = SimConfig(trajectory='orbit', orbit_radius_m=60.0, laps=1.1, altitude_m=80.0, hfov_deg=50.0, width=w,
                    height=h, speed_m_s=10.0, rate_hz=1.0, frames=args.frames, seed=4, buildings=args.buildings,
                    building_height_m=args.height, vehicles=args.vehicles)
    out_dir = ROOT / 'bench' / 'out'
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    flight = simulate(cfg)
    clean = simulate(cfg.replace(vehicles=0)) if args.vehicles else None
    if args.crf is not None:
        flight = through_h264(flight, args.crf, out_dir)
        clean = through_h264(clean, args.crf, out_dir) if clean is not None else None
    print(f'simulated in {time.perf_counter() - t0:.0f} s; orbit 60 m radius, 80 m up, {w}x{h}, '
          f'buildings up to {args.height:g} m, near = {args.near:g} m, {args.vehicles} vehicles, '
          f'H.264 crf {args.crf}')
    measure(flight, args.near, out_dir, 'buildings', clean=clean)
    if not args.no_control:
        control = simulate(cfg.replace(buildings=0, vehicles=0))
        if args.crf is not None:
            control = through_h264(control, args.crf, out_dir)
        measure(control, args.near, out_dir, 'flat', regions_of=flight.truth.buildings)  # same regions, flat ground


if __name__ == '__main__':
    main()
