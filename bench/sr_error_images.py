"""Pictures of SR tiles against their originals: what the PSNR figures of bench/sr_video.py and
bench/sr_real.py are made of.

For a run directory of either benchmark, one row per tile (at most ``--tiles``): the HR original of
the tile's reference frame (truth) | that frame's LR image upsampled bicubically | the SR tile |
mosaic.png upsampled bicubically | the frame bicubic's error and SR's error (x4, grey = 0). A
coloured error image where the frame bicubic's is grey is a colour the SR tile took from other
frames; a tinted one, an exposure; doubled edges, a misalignment. Prints each tile's PSNR and mean
error per channel (B, G, R), and the errors pooled over all tiles split at the LR frames' band: the
low band (the tile area-halved and upsampled bicubically back: what the LR reference itself carries)
and the high band (the rest: what only SR can bring), beside the original's own high-band energy (the
error of no detail at all).

    python bench/sr_error_images.py RUN_DIR (--video VIDEO [--every 1] [--frames 48] | --stills DIR) \\
        [--tiles 8] [--png bench/out/sr_errors.png]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'bench'))

from srmosaic_ros.app.evaluate_stills import halve_stills, tile_comparisons


def _low_band(img: np.ndarray) -> np.ndarray:
    """What an LR frame of half the size carries of ``img`` (H, W, 3): area-halved, bicubic back."""
    h, w = img.shape[:2]
    half = cv2.resize(img.astype(np.float32), (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    return cv2.resize(half, (w, h), interpolation=cv2.INTER_CUBIC).astype(np.float64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('run', type=Path, help='an output directory of bench/sr_video.py or bench/sr_real.py')
    ap.add_argument('--video', type=Path, help='the video the run was made from (bench/sr_video.py)')
    ap.add_argument('--every', type=int, default=1)
    ap.add_argument('--frames', type=int, default=48)
    ap.add_argument('--stills', type=Path, help='the stills folder the run was made from (bench/sr_real.py)')
    ap.add_argument('--tiles', type=int, default=8)
    ap.add_argument('--png', type=Path, default=ROOT / 'bench' / 'out' / 'sr_errors.png')
    args = ap.parse_args()
    if (args.video is None) == (args.stills is None):
        ap.error('give the source of the run: --video or --stills')
    with tempfile.TemporaryDirectory() as tmp:
        if args.video is not None:
            from sr_video import halve_video
            hr = halve_video(args.video, Path(tmp), every=args.every, frames=args.frames)
        else:
            hr = halve_stills(args.stills, Path(tmp))
    rows = []
    bands = np.zeros(5)  # squared errors: SR high, frame high, SR low, frame low; the truth's high-band energy
    count = 0
    for t in tile_comparisons(args.run, hr):
        truth_low, sr_low, frame_low = (_low_band(x) for x in (t.truth, t.sr, t.frame_bicubic))
        bands += [(((t.sr - sr_low) - (t.truth - truth_low)) ** 2).sum(),
                  (((t.frame_bicubic - frame_low) - (t.truth - truth_low)) ** 2).sum(),
                  ((sr_low - truth_low) ** 2).sum(), ((frame_low - truth_low) ** 2).sum(),
                  ((t.truth - truth_low) ** 2).sum()]
        count += t.truth.size
        if len(rows) >= args.tiles:
            continue

        def psnr(a: np.ndarray, t: object = t) -> float:
            return float(10 * np.log10(255.0**2 / max(np.mean((a - t.truth) ** 2), 1e-12)))

        print(f'{t.file} (reference {t.reference}): PSNR SR {psnr(t.sr):.2f}, frame bicubic {psnr(t.frame_bicubic):.2f}, '
              f'mosaic bicubic {psnr(t.mosaic_bicubic):.2f} dB; mean error SR {np.round((t.sr - t.truth).mean(axis=(0, 1)), 1)}, '
              f'frame bicubic {np.round((t.frame_bicubic - t.truth).mean(axis=(0, 1)), 1)}')
        err = [np.clip(128 + 4 * (x - t.truth), 0, 255) for x in (t.frame_bicubic, t.sr)]
        rows.append(np.hstack([t.truth, t.frame_bicubic, t.sr, t.mosaic_bicubic, *err]))
    if not rows:
        sys.exit(f'no SR tile of {args.run} could be compared with its original')
    db = 10 * np.log10(255.0**2 / np.maximum(bands / count, 1e-12))
    print(f'pooled over {count // 3} pixels: high band SR {db[0]:.2f} / frame bicubic {db[1]:.2f} / no detail '
          f'{db[4]:.2f} dB; low band SR {db[2]:.2f} / frame bicubic {db[3]:.2f} dB')
    args.png.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.png), np.vstack(rows).astype(np.uint8))
    print(f'truth | frame bicubic | SR | mosaic bicubic | frame error x4 | SR error x4: {args.png}')


if __name__ == '__main__':
    main()
