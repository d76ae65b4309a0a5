"""Benchmark: super-resolution on real stills, against their own higher-resolution originals.

The sequences in data/sequences (640 px wide, real cameras, real parallax, lighting and lens) are
halved into LR stills and processed with `--sr` (factor 2, 64-px tiles); every SR tile is compared
with the 640-px original of its reference frame (srmosaic_ros/app/evaluate_stills.py), against
mosaic.png sampled bicubically and the reference frame's own LR image sampled bicubically (the
usual single-frame baseline). No simulation anywhere: this is how far SR gets on real
imagery, where the frames disagree by more than noise.

Runs per sequence: the defaults; the consistency gate off (`sr.consistency 0`: what the refused
tiles would have looked like); lambda's residual capped at the noise (`sr.lambda_noise_cap 1`, the
default before 2026-12-03); `sr.psf_sigma` 0.3 (about the blur of the halving: a 2-px box is
0.29 LR px); `sr.lambda_gamma` x 1/3 and x 3; each frame not aligned to the reference on the tile
(`sr.local_align off`) or not matched to its exposure (`sr.photometric off`), the defaults before
2026-12-04. Prints pooled PSNR (dB) over the tiles each run
made, and on the tiles the gate refuses.

    python bench/sr_real.py [--out /tmp/bench_sr_real] [--only 'gamma 0.3;align off']
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.app.evaluate_stills import halve_stills, pooled_gain_db, sr_errors_against_originals
from srmosaic_ros.app.process import process_input

SEQUENCES = ('caliterra', 'brighton_beach')
RUNS: dict[str, dict[str, Any]] = {
    'default': {},
    'anchor compression': {'sr.anchor_compression': True},
    'gate off': {'sr.consistency': 0.0},
    'noise cap 1': {'sr.lambda_noise_cap': 1.0},
    'psf 0.3': {'sr.psf_sigma': 0.3},
    'gamma 0.033': {'sr.lambda_gamma': 0.1 / 3},
    'gamma 0.3': {'sr.lambda_gamma': 0.3},
    'align off': {'sr.local_align': 'off'},
    'anchor noise 0': {'sr.anchor_noise': 0.0},
    'anchor noise 1': {'sr.anchor_noise': 1.0},
    'photometric off': {'sr.photometric': False},
}


def run_sequence(name: str, work: Path) -> None:
    lr_dir = work / f'{name}_lr'
    hr = halve_stills(ROOT / 'data' / 'sequences' / name, lr_dir)
    per_run = {}
    refused: set[str] = set()
    planned = 0
    for label, overrides in RUNS.items():
        out = work / f'{name}_{label.replace(" ", "_")}'
        config = pipeline_config({'sr_tiles.tile_size': 64, **overrides})
        report = process_input(lr_dir, out, config, sr_factor=2, progress=False)
        per_run[label] = sr_errors_against_originals(out, hr)
        if label == 'default':
            refused = {f"tile_x{t['x0']:06d}_y{t['y0']:06d}.png" for t in report['sr']['per_tile'] if 'error' in t}
            planned = report['sr']['tiles_planned']
    print(f'\n## {name}: LR {next(iter(hr.values())).shape[1] // 2} px wide, {planned} tiles planned, '
          f'{len(refused)} refused by the consistency gate')
    print('| run | tiles | PSNR SR | PSNR bicubic of mosaic | gain dB | PSNR bicubic of frame | gain dB | '
          'on the refused tiles: SR / bicubic of mosaic (gain) |')
    print('|---|---|---|---|---|---|---|---|')
    for label, errs in per_run.items():
        common = [f for f in errs if f not in refused]
        p_sr, p_bi, gain = pooled_gain_db(errs, common)
        _, p_fr, gain_fr = pooled_gain_db(errs, common, baseline='frame')
        ref = [f for f in errs if f in refused]
        ref_txt = '-'
        if ref:
            r_sr, r_bi, r_gain = pooled_gain_db(errs, ref)
            ref_txt = f'{r_sr:.2f} / {r_bi:.2f} ({r_gain:+.2f})'
        print(f'| {label} | {len(common)} | {p_sr:.2f} | {p_bi:.2f} | {gain:+.2f} | {p_fr:.2f} | {gain_fr:+.2f} | {ref_txt} |')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, help='work folder (default: a temporary one)')
    ap.add_argument('--only', default='', help="the runs to make, ';'-separated names of RUNS ('default' is always made)")
    args = ap.parse_args()
    if args.only:
        for name in set(RUNS) - {'default', *args.only.split(';')}:
            del RUNS[name]
    logging.getLogger('srmosaic_ros').setLevel(logging.ERROR)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.out or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for name in SEQUENCES:
            run_sequence(name, work)


if __name__ == '__main__':
    main()
