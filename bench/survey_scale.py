"""Surveys of full-size stills: throughput and peak memory of `srmosaic process FOLDER` against the
number of stills, at 12 megapixels.

The caliterra stills (../shared/data/real/surveys/caliterra, 2000x1500, halved from the camera's
4000x3000) are brought back to 4000x3000 (bicubic, EXIF kept: it describes the 4000 px original)
and processed as the first half and as the whole survey. Memory must not grow with the number of
stills (the canvas tiles, a bounded feature cache and one still in flight); the issue's goal is at
least 1 still/s and at most 3 GB.

    .venv/bin/python bench/survey_scale.py [--out bench/out/survey_scale] [--megapixels 12]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
SURVEY = ROOT.parent / 'shared' / 'data' / 'real' / 'surveys' / 'caliterra' / 'images'
SRMOSAIC = ROOT / '.venv' / 'bin' / 'srmosaic'


def make_folder(dst: Path, files: list[Path], width: int) -> Path:
    (dst / 'images').mkdir(parents=True, exist_ok=True)
    for f in files:
        target = dst / 'images' / f.name
        if target.is_file():
            continue
        with Image.open(f) as im:
            exif = im.info.get('exif', b'')
            h = round(im.height * width / im.width)
            im.resize((width, h), Image.Resampling.BICUBIC).save(target, quality=92, exif=exif)
    return dst / 'images'


def run(folder: Path, out: Path) -> dict:
    subprocess.run([str(SRMOSAIC), 'process', str(folder), '--out', str(out), '--no-progress'], check=True,
                   stdout=subprocess.DEVNULL)
    r = json.loads((out / 'report.json').read_text())
    return {'stills': r['frames_in'], 'placed': r['frames_registered'], 'wall_s': r['wall_s'],
            'frames_per_s': r['frames_per_s'], 'peak_rss_mb': r['peak_rss_mb'],
            'mosaic_px': r['segments'][0]['size_px'], 'gsd_m': r['georeferenced']['gsd_m_per_px'],
            'time_s': r['survey']['time_s'], 'pairs_tried': r['survey']['pairs_tried']}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, default=ROOT / 'bench' / 'out' / 'survey_scale')
    ap.add_argument('--megapixels', type=float, default=12.0)
    args = ap.parse_args()
    files = sorted(SURVEY.iterdir())
    width = round((args.megapixels * 1e6 * 4 / 3) ** 0.5)
    rows = []
    for n in (len(files) // 2, len(files)):
        folder = make_folder(args.out / f'stills_{n}', files[:n], width)
        rows.append(run(folder, args.out / f'out_{n}'))
        r = rows[-1]
        print(f"{r['stills']} stills of {width}x{round(width * 3 / 4)}: {r['placed']} placed, {r['wall_s']} s, "
              f"{r['frames_per_s']} stills/s, peak {r['peak_rss_mb']} MB, mosaic {r['mosaic_px']} px at "
              f"{r['gsd_m']:.4f} m, {r['pairs_tried']} pairs, times {r['time_s']}")
    (args.out / 'figures.json').write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
