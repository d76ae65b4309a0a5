"""Benchmark: the oracle ladder of SR on a simulated video: what bounds SR's gain over the frame.

One simulated flight (bench/sr_sim_video.py's: 640x480, 25 fps, 48 frames) is encoded to H.264 at
each ``--crf`` and decoded; each decoded video is halved (area) and processed (no SR) for its
registration and mosaic; the SR tiles are planned once per CRF (64-px tiles, up to 17 frames, the
nearest first) and every tile is reconstructed by :func:`reconstruct_tile` with one thing at a time
replaced by the truth:

- **registration**: the frames' homographies from the simulator (each frame k placed through the
  reference frame r: ``tile_H_k = tile_H_r(estimated) @ r_H_world @ world_H_k``, so the tile stays
  where the estimated mosaic and the scoring put it, and the others superpose it exactly);
- **PSF**: the simulator's blur seen through the halving: a 2 x 2 HR box (the area filter)
  convolved with the render's Gaussian (sim/render.py ``effective_sigma_px``), against the
  Gaussian the ladder chose;
- **data**: the raw frames halved (no compression) against the decoded ones;
- **frames per tile**: 5, 8 (the default), 9, 17, the nearest to the tile; or 8 spread evenly in time
  over all the frames that hold the tile (``sr_tiles.frame_choice: spread``);
- **the prior's weight** (``sr.lambda_gamma``), the anchoring and the former clamp, with the estimates.

Every tile is scored against the true ground (no blur, noise or compression) in the reference frame's
pixels, against that frame's LR image upsampled (bicubic), as bench/sr_sim_video.py scores it; the
tiles are the same in every row of a CRF. The product's fallback is not applied (a tile refused by
the consistency test shows the reference upsampled and is counted).

    python bench/sr_oracle.py [--crf 18,28] [--frames 48] [--only 'true warps;raw frames;...'] [--out DIR]
"""
from __future__ import annotations

import argparse
import logging
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.app.evaluate_stills import gains_db, pooled_gain_db, sr_errors_against_originals
from srmosaic_ros.app.process import process_input
from srmosaic_ros.app.sr_process import PSF_TILES, _flight_psf
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.homography import translation
from srmosaic_ros.core.sr.fallback import frame_upsampled
from srmosaic_ros.core.sr.psf_select import TileFrames
from srmosaic_ros.core.sr.reconstruct import SRConfig, SRError, reconstruct_tile
from srmosaic_ros.core.sr.ringing import resolve_clamp
from srmosaic_ros.core.sr.scheduler import SRTileConfig, frame_centres, plan_tiles
from srmosaic_ros.io.mosaic_files import read_frames_csv, write_json, write_png
from srmosaic_ros.io.video import VideoReader, write_video
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.ortho_error import ortho_in_plane
from srmosaic_ros.sim.render import effective_sigma_px

FACTOR = 2
TILE = 64
MOST_FRAMES = 17
#: LR pixel (u, v) of a frame halved by the area filter is HR point (2 u + 0.5, 2 v + 0.5).
HR_H_LR = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Rung:
    """One row of the ladder: which truths replace the estimates, and the SR settings."""

    warps: str = 'estimated'      # 'estimated' | 'true'
    psf: str = 'chosen'           # 'chosen' | 'true'
    data: str = 'h264'            # 'h264' | 'raw'
    frames: int = 8
    choice: str = 'nearest'       # 'nearest' (the scheduler's) | 'spread' (evenly in time over the covering frames)
    settings: tuple[tuple[str, object], ...] = ()


LOCAL_OFF = (('local_align', 'off'),)  # with the true warps: the ECC's corrections left out
RUNGS: dict[str, Rung] = {
    'defaults (estimated warps, PSF chosen, 8 nearest frames)': Rung(),
    'clamp cell (the former default)': Rung(settings=(('clamp', 'cell'),)),
    'true warps': Rung(warps='true'),
    'true warps, local_align off': Rung(warps='true', settings=LOCAL_OFF),
    'true PSF': Rung(psf='true'),
    'true warps and PSF': Rung(warps='true', psf='true', settings=LOCAL_OFF),
    'raw frames': Rung(data='raw'),
    'raw frames, true warps and PSF': Rung(warps='true', psf='true', data='raw', settings=LOCAL_OFF),
    'raw frames, true warps and PSF, lambda_gamma 0.1': Rung(warps='true', psf='true', data='raw',
                                                           settings=(*LOCAL_OFF, ('lambda_gamma', 0.1))),
    '5 frames': Rung(frames=5),
    '9 frames': Rung(frames=9),
    '17 frames': Rung(frames=17),
    '17 frames, true warps and PSF': Rung(warps='true', psf='true', frames=17, settings=LOCAL_OFF),
    '8 frames spread in time': Rung(choice='spread'),
    'lambda_gamma 0.1': Rung(settings=(('lambda_gamma', 0.1),)),
    'lambda_gamma 1.0': Rung(settings=(('lambda_gamma', 1.0),)),
    'anchor off': Rung(settings=(('anchor', False),)),
}


def true_psf(sigma_hr: float) -> torch.Tensor:
    """(k, k) HR kernel, k even: the 2 x 2 box of the area halving convolved with a Gaussian of
    ``sigma_hr`` HR px (sampled at integer offsets), sum 1."""
    r = int(np.ceil(3.0 * sigma_hr))
    g = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma_hr) ** 2)
    k1 = np.convolve(g / g.sum(), [0.5, 0.5])  # length 2 r + 2: even, centred between two HR pixels
    return torch.from_numpy(np.outer(k1, k1).astype(np.float32))


@dataclass
class Flight:
    """The simulated flight's LR frames (RGB uint8) per data kind, its HR originals (BGR) per kind,
    the true ground each frame saw (BGR uint8), and the frames' true LR pixel -> world px maps."""

    lr: dict[str, list[np.ndarray]]
    hr: dict[str, dict[str, np.ndarray]]
    truth: dict[str, np.ndarray]
    world_H_lr: list[np.ndarray]
    names: list[str]
    psf_sigma_hr: float


def make_flight(work: Path, crfs: list[int], frames: int, seed: int) -> tuple[Flight, dict[int, Path]]:
    """Simulate once; encode at each CRF; write each CRF's halved stills folder (for `process`)."""
    flight = simulate(SimConfig(rate_hz=25.0, speed_m_s=3.0, frames=frames, altitude_m=80.0, seed=seed))
    raw = [f.image for f in flight.frames]
    kinds = {'raw': raw}
    for crf in crfs:
        path = work / f'flight_crf{crf}.mp4'
        write_video(path, iter(raw), fps=flight.config.rate_hz, crf=crf)
        kinds[f'crf{crf}'] = [f.image for f in VideoReader(path)]
    names = [f'{k:05d}.png' for k in range(len(raw))]
    h, w = raw[0].shape[:2]
    lr = {kind: [cv2.resize(im, (w // 2, h // 2), interpolation=cv2.INTER_AREA) for im in ims] for kind, ims in kinds.items()}
    hr = {kind: {n: cv2.cvtColor(im, cv2.COLOR_RGB2BGR) for n, im in zip(names, ims, strict=True)} for kind, ims in kinds.items()}
    folders = {}
    for crf in crfs:
        folder = work / f'crf{crf}_lr'
        (folder / 'images').mkdir(parents=True, exist_ok=True)
        for n, im in zip(names, lr[f'crf{crf}'], strict=True):
            cv2.imwrite(str(folder / 'images' / n), cv2.cvtColor(im, cv2.COLOR_RGB2BGR))
        folders[crf] = folder
    world = flight.world.image
    truth = {n: cv2.cvtColor(np.clip(ortho_in_plane(world, fr.world_px_H_frame, (w, h)) * 255.0 + 0.5, 0, 255).astype(np.uint8),
                             cv2.COLOR_RGB2BGR) for n, fr in zip(names, flight.truth.frames, strict=True)}
    world_H_lr = [np.asarray(fr.world_px_H_frame, float) @ HR_H_LR for fr in flight.truth.frames]
    return Flight(lr, hr, truth, world_H_lr, names, float(effective_sigma_px(flight.config.psf_sigma_px))), folders


def nearest_frames(plan, rows, size, n: int, choice: str = 'nearest') -> list[int]:
    """``n`` frames of ``plan``, the reference (the frame whose centre lands nearest the tile's, as the
    scoring and the scheduler pick it) first: the nearest, or spread evenly in time over all of them."""
    c = np.array([plan.x0 + (plan.width - 1) / 2, plan.y0 + (plan.height - 1) / 2])
    centres = frame_centres([rows[k]['mosaic_H_frame'] for k in plan.frames], [size] * len(plan.frames))
    order = [plan.frames[i] for i in np.argsort(np.hypot(*(centres - c).T), kind='stable')]
    if choice == 'nearest' or n >= len(order):
        return order[:n]
    spread = [plan.frames[int(round(i))] for i in np.linspace(0, len(plan.frames) - 1, n)]
    ref = order[0]
    spread[int(np.argmin([abs(k - ref) for k in spread]))] = ref
    return [ref] + [k for k in spread if k != ref]


def run_rung(rung: Rung, flight: Flight, crf: int, processed: Path, plans, chosen_sigma: float, dest: Path,
             solve: Callable[..., object] = reconstruct_tile) -> tuple[dict, int, float]:
    """SR of every planned tile under ``rung``, written as `process --sr` writes tiles (scored by
    evaluate_stills); returns (errors against the ground, tiles refused, seconds)."""
    if dest.exists():
        shutil.rmtree(dest)
    (dest / 'sr').mkdir(parents=True)
    for f in ('frames.csv', 'mosaic.png'):
        shutil.copy(processed / f, dest / f)
    rows = read_frames_csv(processed / 'frames.csv')
    data = 'raw' if rung.data == 'raw' else f'crf{crf}'
    lr = flight.lr[data]
    size = (lr[0].shape[1], lr[0].shape[0])
    # as `process --sr` resolves sr.clamp for a PSF chosen from the frames (ringing.resolve_clamp), the true
    # PSF included: one clamp for every rung, unless the rung sets it
    cfg = replace(SRConfig(psf_sigma=chosen_sigma, clamp=resolve_clamp('auto', psf_chosen=True)), **dict(rung.settings))
    psf = true_psf(flight.psf_sigma_hr) if rung.psf == 'true' else None
    entries, refused, t0 = [], 0, time.perf_counter()
    for plan in plans:
        use = nearest_frames(plan, rows, size, rung.frames, rung.choice)
        ref = use[0]
        use = sorted(use)
        tile_H_ref = translation(-plan.x0, -plan.y0) @ rows[ref]['mosaic_H_frame']
        if rung.warps == 'true':
            ref_H_world = np.linalg.inv(flight.world_H_lr[ref])
            hs = [tile_H_ref @ ref_H_world @ flight.world_H_lr[k] for k in use]
        else:
            hs = [translation(-plan.x0, -plan.y0) @ rows[k]['mosaic_H_frame'] for k in use]
        frames = [lr[k] for k in use]
        try:
            res = solve(frames, hs, (plan.height, plan.width), FACTOR, psf=psf, config=cfg, reference=use.index(ref))
            image = res.image.detach().cpu().permute(1, 2, 0).numpy()
        except SRError:
            refused += 1
            image = frame_upsampled(frames[use.index(ref)], hs[use.index(ref)], (plan.height, plan.width), FACTOR)
        name = f'tile_x{plan.x0:06d}_y{plan.y0:06d}.png'
        write_png(dest / 'sr' / name, image)
        entries.append({'file': name, 'x0': plan.x0, 'y0': plan.y0, 'width': plan.width, 'height': plan.height,
                        'factor': FACTOR})
    write_json(dest / 'sr' / 'tiles.json', entries)
    seconds = time.perf_counter() - t0
    return sr_errors_against_originals(dest, flight.hr[data], flight.truth), refused, seconds


def _row(label: str, errors: dict, refused: int, seconds: float) -> str:
    p_sr, p_frame, gain = pooled_gain_db(errors, baseline='frame')
    g = gains_db(errors, 'frame')
    return (f'| {label} | {p_sr:.2f} | {p_frame:.2f} | **{gain:+.2f}** | {g.min():+.2f} | {np.mean(g > 0):.0%} '
            f'| {refused} | {seconds:.1f} |')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--crf', default='18,28', help='H.264 CRFs, comma-separated')
    ap.add_argument('--frames', type=int, default=48)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--out', type=Path, default=None)
    ap.add_argument('--only', default='', help="the rungs to run, ';'-separated names of RUNGS (default: all)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    torch.set_num_threads(1)
    rungs = {k: v for k, v in RUNGS.items() if not args.only or k in args.only.split(';')}
    work = args.out or Path(tempfile.mkdtemp(prefix='bench_sr_oracle_'))
    work.mkdir(parents=True, exist_ok=True)
    crfs = [int(c) for c in args.crf.split(',')]
    flight, folders = make_flight(work, crfs, args.frames, args.seed)
    for crf in crfs:
        processed = work / f'crf{crf}_processed'
        config = pipeline_config({'sr_tiles.tile_size': TILE})
        process_input(folders[crf], processed, config, progress=False)
        rows = read_frames_csv(processed / 'frames.csv')
        mosaic = cv2.imread(str(processed / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
        size = (flight.lr['raw'][0].shape[1], flight.lr['raw'][0].shape[0])
        ok = {i: r['mosaic_H_frame'] for i, r in enumerate(rows) if r['ok']}
        plans = plan_tiles(ok, dict.fromkeys(ok, size), mosaic[:, :, 3] > 0,
                           SRTileConfig(tile_size=TILE, max_frames=1000, min_frames=MOST_FRAMES))
        # the PSF the product would choose on this CRF (the ladder on its best tiles, as process --sr)
        lr = flight.lr[f'crf{crf}']
        near = [(p, sorted(nearest_frames(p, rows, size, 8))) for p in plans[:PSF_TILES]]
        tiles = [TileFrames([lr[k] for k in use], [translation(-p.x0, -p.y0) @ rows[k]['mosaic_H_frame'] for k in use],
                            (p.height, p.width)) for p, use in near]
        chosen = _flight_psf(config, tiles, FACTOR)[0].psf_sigma
        covering = int(np.median([p.frames_covering for p in plans]))
        print(f'\n## H.264 CRF {crf}: {len(plans)} tiles of {TILE} px, each seen whole by {MOST_FRAMES}+ frames (median {covering}); '
              f'PSF chosen {chosen:g} LR px, true: box x Gaussian {flight.psf_sigma_hr:.3f} HR px')
        print('| rung | PSNR SR vs ground | frame bicubic | gain dB | worst tile | tiles gaining | refused | s |')
        print('|---|---|---|---|---|---|---|---|')
        for label, rung in rungs.items():
            errors, refused, seconds = run_rung(rung, flight, crf, processed, plans, chosen,
                                                work / f'crf{crf}_{label.replace(" ", "_").replace(",", "")}')
            print(_row(label, errors, refused, seconds), flush=True)


if __name__ == '__main__':
    main()
