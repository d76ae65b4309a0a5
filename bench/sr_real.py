"""Benchmark: super-resolution on real stills, against their own higher-resolution originals.

The sequences in data/sequences (640 px wide, real cameras, real parallax, lighting and lens) are
halved (area average, then JPEG quality 98) into LR stills and processed with `--sr` (factor 2,
64-px tiles). The truth of a tile is the HR (640 px) still of its reference frame (the one whose
centre is nearest the tile's, which the mosaic shows there), sampled at the tile's pixels through
that frame's registered homography: HR pixel = 2 * LR pixel + 0.5. The baseline is mosaic.png
sampled bicubically at the same points. No simulation anywhere: this is how far SR gets on real
imagery, where the frames disagree by more than noise.

Runs per sequence: the defaults; the consistency gate off (`sr.consistency 0`: what the refused
tiles would have looked like); lambda's residual not capped by the noise (`sr.lambda_noise_cap 0`,
(5.6) as before); `sr.psf_sigma` 0.3 (about the blur of the halving: a 2-px box is
0.29 LR px); and `sr.lambda_gamma` x 1/3 and x 3. Prints pooled PSNR (dB) over the tiles each run
made, and on the tiles the gate refuses.

    python bench/sr_real.py [--out /tmp/bench_sr_real]
"""
from __future__ import annotations

import argparse
import logging
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.config import pipeline_config  # noqa: E402
from srmosaic_ros.evaluate import _tile_grid_H  # noqa: E402
from srmosaic_ros.io.mosaic_files import read_frames_csv  # noqa: E402
from srmosaic_ros.offline import process_input  # noqa: E402

SEQUENCES = ('caliterra', 'brighton_beach')
RUNS: dict[str, dict[str, Any]] = {
    'default': {},
    'gate off': {'sr.consistency': 0.0},
    'lambda cap off': {'sr.lambda_noise_cap': 0.0},
    'psf 0.3': {'sr.psf_sigma': 0.3},
    'gamma 0.033': {'sr.lambda_gamma': 0.1 / 3},
    'gamma 0.3': {'sr.lambda_gamma': 0.3},
}


def halve_sequence(src: Path, dst: Path) -> tuple[Path, dict[str, np.ndarray]]:
    """LR copy of a stills folder (telemetry kept); returns it and the HR images by file name."""
    (dst / 'images').mkdir(parents=True, exist_ok=True)
    shutil.copy(src / 'telemetry_from_exif.csv', dst / 'telemetry_from_exif.csv')
    hr = {}
    for f in sorted((src / 'images').iterdir()):
        img = cv2.imread(str(f))
        hr[f.name] = img
        h, w = img.shape[:2]
        cv2.imwrite(str(dst / 'images' / f.name), cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA),
                    [cv2.IMWRITE_JPEG_QUALITY, 98])
    return dst, hr


def _sample(img: np.ndarray, img_H_tile: np.ndarray, shape: tuple[int, int]) -> np.ndarray:  # noqa: N803
    out = cv2.warpPerspective(img.astype(np.float32), img_H_tile, (shape[1], shape[0]),
                              flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    return np.clip(out, 0, 255)


def tile_errors(out: Path, hr: dict[str, np.ndarray], names: list[str]) -> dict[str, tuple[float, float, int]]:
    """Per SR tile file: (SSE of SR, SSE of bicubic, values) against the HR reference still."""
    import json

    rows = [r for r in read_frames_csv(out / 'frames.csv')]
    ok = [(names[i], r['mosaic_H_frame']) for i, r in enumerate(rows) if r['ok']]
    mosaic = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)[:, :, :3]
    lr_size = next(iter(hr.values())).shape[1] // 2, next(iter(hr.values())).shape[0] // 2
    result = {}
    for entry in json.loads((out / 'sr' / 'tiles.json').read_text()):
        sr = cv2.imread(str(out / 'sr' / entry['file']))[:, :, :3].astype(np.float64)
        grid_H = _tile_grid_H(entry)  # tile px -> mosaic px  # noqa: N806
        c = np.array([entry['x0'] + (entry['width'] - 1) / 2, entry['y0'] + (entry['height'] - 1) / 2])
        centre = np.array([(lr_size[0] - 1) / 2, (lr_size[1] - 1) / 2, 1.0])

        def dist(item: tuple[str, np.ndarray]) -> float:
            p = item[1] @ centre
            return float(np.hypot(*(p[:2] / p[2] - c)))

        name, mosaic_H_frame = min(ok, key=dist)  # noqa: N806
        hr_H_lr = np.array([[2.0, 0, 0.5], [0, 2.0, 0.5], [0, 0, 1]])  # noqa: N806
        truth = _sample(hr[name], hr_H_lr @ np.linalg.inv(mosaic_H_frame) @ grid_H, sr.shape[:2])
        bicubic = _sample(mosaic, grid_H, sr.shape[:2])
        result[entry['file']] = (float(((sr - truth) ** 2).sum()), float(((bicubic - truth) ** 2).sum()), truth.size)
    return result


def _psnr(sse: float, n: int) -> float:
    return 10 * np.log10(255.0**2 / max(sse / max(n, 1), 1e-12))


def run_sequence(name: str, work: Path) -> None:
    lr_dir, hr = halve_sequence(ROOT / 'data' / 'sequences' / name, work / f'{name}_lr')
    names = sorted(hr)
    per_run = {}
    refused: set[str] = set()
    for label, overrides in RUNS.items():
        out = work / f'{name}_{label.replace(" ", "_")}'
        config = pipeline_config({'sr_tiles.tile_size': 64, **overrides})
        report = process_input(lr_dir, out, config, sr_factor=2, progress=False)
        per_run[label] = tile_errors(out, hr, names)
        if label == 'default':
            refused = {f"tile_x{t['x0']:06d}_y{t['y0']:06d}.png" for t in report['sr']['per_tile'] if 'error' in t}
            planned = report['sr']['tiles_planned']
    print(f'\n## {name}: LR {next(iter(hr.values())).shape[1] // 2} px wide, {planned} tiles planned, '
          f'{len(refused)} refused by the consistency gate')
    print('| run | tiles | PSNR SR | PSNR bicubic | gain dB | on the refused tiles: SR / bicubic (gain) |')
    print('|---|---|---|---|---|---|')
    for label, errs in per_run.items():
        common = [f for f in errs if f not in refused]
        sse_sr, sse_bi, n = (sum(errs[f][i] for f in common) for i in range(3))
        ref = [f for f in errs if f in refused]
        ref_txt = '-'
        if ref:
            r_sr, r_bi, r_n = (sum(errs[f][i] for f in ref) for i in range(3))
            ref_txt = f'{_psnr(r_sr, r_n):.2f} / {_psnr(r_bi, r_n):.2f} ({_psnr(r_sr, r_n) - _psnr(r_bi, r_n):+.2f})'
        print(f'| {label} | {len(common)} | {_psnr(sse_sr, n):.2f} | {_psnr(sse_bi, n):.2f} | '
              f'{_psnr(sse_sr, n) - _psnr(sse_bi, n):+.2f} | {ref_txt} |')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, help='work folder (default: a temporary one)')
    args = ap.parse_args()
    logging.getLogger('srmosaic_ros').setLevel(logging.ERROR)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.out or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for name in SEQUENCES:
            run_sequence(name, work)


if __name__ == '__main__':
    main()
