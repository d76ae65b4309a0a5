"""Benchmark: the halved-video SR check of bench/sr_video.py on a simulated video, scored twice: against
the compressed originals (as on real footage) and against the true ground.

On real footage the only truth is the original frame, and the original carries its own sensor noise
and compression: a tile that copies the reference frame's artefacts scores there, and a tile that
removes them is charged for it. The simulator knows the ground. A flight (640x480, 25 fps, slow,
noise and PSF as the simulator's defaults) is encoded to H.264 at ``--crf`` (none: raw frames) and
decoded; the decoded frames are the originals, halved (area) into a folder of PNG stills as
bench/sr_video.py halves a real video, processed with `--sr` (factor 2, 64-px tiles, no metadata),
and every SR tile is compared with (a) its reference frame's original and (b) the true ground that
frame saw (the orthophoto sampled at its pixels, anti-aliased: no optical blur, no noise, no
compression), each against the bicubic of the mosaic and of the reference frame's LR image.

With ``--vehicles N`` cars drive over the ground (sim/traffic.py); the truth of a frame is then the
ground with the cars where they were at that frame's time (what the tile, anchored to that frame,
should show), and the SR error is also given over the moving-object pixels: the ground any car
covered in any frame of the flight (the trail), seen from the reference frame, where a tile could
show a ghost or a trail; beside the two bicubics' errors there.

    python bench/sr_sim_video.py [--crf 18,28,none] [--frames 48] [--vehicles N] [--only 'default;...'] [--out DIR]
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.app.evaluate_stills import gains_db, pooled_gain_db, sr_errors_against_originals, tile_comparisons
from srmosaic_ros.app.process import process_input
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.io.video import VideoReader, write_video
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.ortho_error import ortho_in_plane
from srmosaic_ros.sim.traffic import paint_vehicles, restore_world, vehicle_mask

RUNS: dict[str, dict[str, Any]] = {
    'default': {},
    'anchor compression': {'sr.anchor_compression': True},
    'anchor off': {'sr.anchor': False},
    'moving 0.05': {'sr.moving': 0.05},
    'clamp cell (before 2026-12-08)': {'sr.clamp': 'cell'},
    'clamp wide': {'sr.clamp': 'wide'},
    'frames spread in time': {'sr_tiles.frame_choice': 'spread'},
    'lambda_gamma 0.4': {'sr.lambda_gamma': 0.4},
    'PSF 0.35 given, clamp off': {'sr.psf_ladder': [], 'sr.psf_sigma': 0.35, 'sr.clamp': 'off'},
    'lambda_gamma 0.5': {'sr.lambda_gamma': 0.5},
    'least squares, lambda_gamma 0.1 (before 2026-12-07)': {'sr.robust_pixels': 'off', 'sr.lambda_gamma': 0.1,
                                                           'sr.reweight_at': [3]},
}


class _Lazy(Mapping):
    """name -> image made on first use (only the tiles' reference frames are asked for)."""

    def __init__(self, names: list[str], make) -> None:
        self._names, self._make, self._done = names, make, {}

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._done:
            self._done[name] = self._make(self._names.index(name))
        return self._done[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


def simulated_video(work: Path, crf: int | None, frames: int, seed: int,
                    vehicles: int = 0) -> tuple[Path, dict[str, np.ndarray], Mapping, Mapping | None]:
    """The halved stills folder, the HR originals (decoded, BGR), the true HR frames (BGR) and, with
    vehicles, each frame's trail mask (uint8 BGR, 255 on ground some car covered in some frame), by name."""
    flight = simulate(SimConfig(rate_hz=25.0, speed_m_s=3.0, frames=frames, altitude_m=80.0, seed=seed,
                                vehicles=vehicles))
    images = [f.image for f in flight.frames]  # RGB uint8 (480, 640, 3)
    if crf is not None:
        path = work / f'flight_crf{crf}.mp4'
        write_video(path, iter(images), fps=flight.config.rate_hz, crf=crf)
        images = [f.image for f in VideoReader(path)]
    lr = work / f'crf{crf}_lr'
    (lr / 'images').mkdir(parents=True, exist_ok=True)
    hr = {}
    for k, rgb in enumerate(images):
        name = f'{k:05d}.png'
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        h, w = bgr.shape[:2]
        hr[name] = bgr
        cv2.imwrite(str(lr / 'images' / name), cv2.resize(bgr, (w // 2, h // 2), interpolation=cv2.INTER_AREA))
    truth = flight.truth
    names = sorted(hr)
    world = flight.world.image.copy()  # cars are painted into it frame by frame

    def true_frame(k: int) -> np.ndarray:
        saved = paint_vehicles(world, truth.vehicles, truth.time_s(k)) if truth.vehicles else []
        true = ortho_in_plane(world, truth.frames[k].world_px_H_frame, (w, h))
        restore_world(world, saved)
        return cv2.cvtColor(np.clip(true * 255.0 + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_RGB2BGR)

    def trail(k: int) -> np.ndarray:
        H = truth.frames[k].world_px_H_frame
        mask = np.zeros((h, w), bool)
        for j in range(len(truth.frames)):
            mask |= vehicle_mask(truth.vehicles, truth.time_s(j), H, (w, h))
        return np.repeat((mask * np.uint8(255))[..., None], 3, axis=2)

    return lr, hr, _Lazy(names, true_frame), _Lazy(names, trail) if truth.vehicles else None


def _on_trail(out: Path, hr: dict, truth: Mapping, trail: Mapping) -> str:
    """PSNR of SR / bicubic of the mosaic / of the frame against the truth over the tiles' trail pixels."""
    sse, n = np.zeros(3), 0
    for t, m in zip(tile_comparisons(out, hr, truth), tile_comparisons(out, hr, trail), strict=True):
        on = m.truth[..., 0] > 127
        n += int(on.sum()) * 3
        sse += [float(((x - t.truth)[on] ** 2).sum()) for x in (t.sr, t.mosaic_bicubic, t.frame_bicubic)]
    if n == 0:
        return 'no trail pixels | |'
    p = 10 * np.log10(255.0**2 * n / np.maximum(sse, 1e-9))
    return f'{p[0]:.2f} | {p[1]:.2f} / {p[2]:.2f} | {n // 3}'


def _cells(errors: dict) -> str:
    p_sr, p_mos, _ = pooled_gain_db(errors)
    _, p_frame, gain_frame = pooled_gain_db(errors, baseline='frame')
    g = gains_db(errors, 'frame')
    return (f'{p_sr:.2f} | {p_mos:.2f} / {p_frame:.2f} | {gain_frame:+.2f} | {g.min():+.2f} | '
            f'{np.mean(g > 0):.0%}')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--crf', default='18,28,none', help="H.264 CRFs, comma-separated ('none': raw frames)")
    ap.add_argument('--frames', type=int, default=48)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--vehicles', type=int, default=0, help='cars driving over the ground (default none)')
    ap.add_argument('--out', type=Path, default=None)
    ap.add_argument('--only', default='', help="the runs to make, ';'-separated names of RUNS (default: all)")
    args = ap.parse_args()
    runs = {k: v for k, v in RUNS.items() if not args.only or k in args.only.split(';')}
    logging.basicConfig(level=logging.ERROR)
    work = args.out or Path(tempfile.mkdtemp(prefix='bench_sr_sim_video_'))
    work.mkdir(parents=True, exist_ok=True)
    for crf_text in args.crf.split(','):
        crf = None if crf_text.strip() == 'none' else int(crf_text)
        lr, hr, truth, trail = simulated_video(work, crf, args.frames, args.seed, args.vehicles)
        print(f'\n## simulated video, {len(hr)} frames 640x480 halved to 320x240, '
              f'{"raw" if crf is None else f"H.264 CRF {crf}"}'
              f'{f", {args.vehicles} cars" if args.vehicles else ""}')
        extra = (' trail pixels: PSNR SR | bicubic of mosaic / of frame | pixels |', '---|---|---|') if trail else ('', '')
        print('| run | PSF sigma | tiles | against the originals: PSNR SR | bicubic of mosaic / of frame '
              '| gain over frame dB | worst tile | tiles gaining | against the ground: PSNR SR '
              '| bicubic of mosaic / of frame | gain over frame dB | worst tile | tiles gaining |' + extra[0])
        print('|---|---|---|---|---|---|---|---|---|---|---|---|---|' + extra[1])
        for label, overrides in runs.items():
            out = work / f'crf{crf}_{label.replace(" ", "_").replace(",", "")}'
            report = process_input(lr, out, pipeline_config({'sr_tiles.tile_size': 64, **overrides}), sr_factor=2,
                                   progress=False)
            vs_original = sr_errors_against_originals(out, hr)
            vs_ground = sr_errors_against_originals(out, hr, truth)
            if not vs_original:
                print(f'| {label} | | 0 | | | | | | | | | | |')
                continue
            print(f'| {label} | {report["sr"]["psf_sigma_px"]:g} | {len(vs_original)} | {_cells(vs_original)} '
                  f'| {_cells(vs_ground)} |' + (f' {_on_trail(out, hr, truth, trail)} |' if trail else ''), flush=True)


if __name__ == '__main__':
    main()
