"""Picture: the mosaic's detail against its frame, per canvas sampling (mosaic.resolution, mosaic.oversample).

The video is halved (as ``bench/mosaic_fidelity.py --halve``) and run through the pipeline once per
sampling asked for. One late frame k (the last by default: the finest on the first frame's plane, and
the newest where it looks, so the mosaic shows it over most of its view) is
rendered back from each mosaic onto k's full-size grid (bicubic, one warp, as the fidelity bench's
"mosaic bicubic"), and a square of it where the mosaic shows frame k is put side by side with the same
square of the original full-size frame and of the halved frame's own bicubic. Labels above each,
with the PSNR of that square against the original (luma, 0..255).

    python bench/mosaic_sampling_picture.py VIDEO OUT.jpg [--frames 90] [--frame -1]
                                            [--samplings first:1,finest:1,finest:1.5] [--side 128]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'bench'))

from mosaic_fidelity import FULL_H_HALF, _digest, luma, read_frames, run_pipeline

from srmosaic_ros.core.sr.quality import side_by_side


def mosaic_on_full_frame(run, k_digest: str, full_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """(the mosaic rendered onto frame k's full-size grid, float32 (H, W, 3) 0..255; where the mosaic shows
    frame k, bool (H, W)), or None when frame k was not painted."""
    canvas = run.canvas
    for cid, index, image, m in run.paints:
        if cid != id(canvas) or _digest(image) != k_digest:
            continue
        h, w = image.shape[:2]
        c = np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]]) @ m.T
        xy = c[:, :2] / c[:, 2:]
        x0, y0 = np.floor(xy.min(axis=0)).astype(int) - 3
        x1, y1 = np.ceil(xy.max(axis=0)).astype(int) + 4
        box_H_image = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ m
        mosaic, _ = canvas.render((x0, y0, x1, y1))
        W, H = full_size
        box_H_full = box_H_image @ np.linalg.inv(FULL_H_HALF)
        inv = cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP
        full = cv2.warpPerspective(np.clip(mosaic * 255.0, 0, 255).astype(np.float32), box_H_full, (W, H), flags=inv,
                                   borderMode=cv2.BORDER_REPLICATE)
        shown = cv2.warpPerspective((canvas.labels((x0, y0, x1, y1)) == index).astype(np.uint8), box_H_full, (W, H),
                                    flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP) > 0
        return np.clip(full, 0, 255), shown
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('video', type=Path)
    ap.add_argument('out', type=Path)
    ap.add_argument('--frames', type=int, default=90)
    ap.add_argument('--frame', type=int, default=-1, help='the frame shown (index among the frames read; -1: the last, '
                    'which no newer frame covers)')
    ap.add_argument('--samplings', default='first:1,finest:1,finest:1.5', help='resolution:oversample, in turn')
    ap.add_argument('--side', type=int, default=128, help='side of the square, full-size pixels')
    args = ap.parse_args()
    frames, originals = read_frames(args.video, args.frames, halve=True)
    assert originals is not None
    k = args.frame % len(frames)
    orig = originals[k]
    H, W = orig.shape[:2]
    own = np.clip(cv2.resize(frames[k].image.astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC), 0, 255)
    renders = []
    for spec in args.samplings.split(','):
        resolution, oversample = spec.split(':')
        run = run_pipeline(frames, 'cubic', resolution, float(oversample))
        got = mosaic_on_full_frame(run, _digest(frames[k].image), (W, H))
        x0, y0, x1, y1 = run.canvas.bounds()
        run.canvas.close()
        if got is None:
            sys.exit(f'frame {k} was not painted with {spec}; choose another --frame')
        print(f'{spec}: mosaic {x1 - x0}x{y1 - y0} px', flush=True)
        renders.append((f'mosaic {resolution} x{float(oversample):g}', *got))
    shown = np.logical_and.reduce([s for _, _, s in renders])
    shown = cv2.erode(shown.astype(np.uint8), np.ones((9, 9), np.uint8), borderValue=0) > 0
    if not shown.any():
        sys.exit(f'frame {k} is shown by no mosaic at one place; choose another --frame')
    # the square where the mosaics show frame k with the most detail (gradient energy of the original)
    s = min(args.side, H, W)
    g = cv2.Laplacian(luma(orig).astype(np.float32), cv2.CV_32F) ** 2
    score = cv2.boxFilter(g * shown, -1, (s, s), normalize=False) - 1e12 * cv2.boxFilter((~shown).astype(np.float32), -1, (s, s))
    cy, cx = np.unravel_index(int(np.argmax(score)), score.shape)
    y0, x0 = int(np.clip(cy - s // 2, 0, H - s)), int(np.clip(cx - s // 2, 0, W - s))

    def crop(img: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(img[y0:y0 + s, x0:x0 + s]).astype(np.uint8)

    def psnr(img: np.ndarray) -> float:
        d = luma(crop(img)) - luma(crop(orig))
        return 10.0 * np.log10(255.0**2 / float(np.mean(d * d)))

    tiles = [crop(orig), crop(own)] + [crop(r) for _, r, _ in renders]
    labels = ['original frame', f'frame bicubic {psnr(own):.1f} dB'] + [f'{name}: {psnr(r):.1f} dB' for name, r, _ in renders]
    zoomed = [cv2.resize(t, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST) for t in tiles]
    picture = side_by_side(zoomed, labels)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])
    print(f'frame {k}, square at ({x0}, {y0}) side {s}: ' + '; '.join(labels) + f' -> {args.out}')


if __name__ == '__main__':
    main()
