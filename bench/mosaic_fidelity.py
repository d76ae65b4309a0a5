"""Benchmark: is the mosaic as sharp as its frames? (issue 52, item 1)

Each video runs through the pipeline in this process (chained, no telemetry: the canvas is the
first frame's pixel plane), once per ``mosaic.interpolation`` asked for, the same frames each time.
Every paint is recorded (the image and mosaic_H_image the canvas was given, its paint index), so
each painted frame is found again under the best-view labels (``TiledCanvas.labels``: the frame
each mosaic pixel shows). Over the pixels of frame k that the mosaic shows from frame k (the
labels warped back onto the frame, eroded by ``ERODE_PX`` so that no sample near a seam reads
another frame, and ``BORDER_PX`` in from the frame's edge), luma PSNR (BT.601, 0..255):

- ``mosaic->frame``: the mosaic rendered back onto frame k's pixels (bicubic, clipped) against
  frame k: what the painting and blending lost;
- ``round trip``: frame k alone, painted as the canvas paints it (core/mosaic/resample.py) and
  sampled back the same way, against frame k: what the painting alone loses. The two agree where
  blending keeps the best view's interior;
- with ``--halve`` (the issue's goal): the video is halved first (area filter, no re-encode: the
  halved frames go straight into the pipeline), and the mosaic's bicubic onto the full-size grid
  of frame k (one warp from the mosaic, full-size pixel U = 2 u + 1/2) and frame k's own bicubic
  (cv2.resize) are both scored against the original full-size frame k over the same pixels; the
  goal is the mosaic's within 1 dB of the frame's.

PSNR is pooled (the mean squared error over every pixel counted, each mosaic pixel once, by the
frame it shows). Also printed: painting time, ms per paint and per input frame (the canvas's
``paint`` calls timed here; run with ``OMP_NUM_THREADS`` and the host's load in mind), and the
frames painted. ``--save DIR`` writes, per video and interpolation, a crop of the mosaic and of
the frame it shows there, side by side (PNG), for looking at.

Each configuration runs in a fresh process (``mosaic.interpolation`` x ``mosaic.resolution`` x
``mosaic.oversample``, the canvas's sampling: core/mosaic/resolution.py); printed with it: the
mosaic's size in pixels and tiles, and the process's peak RSS (and how much of it came after the
frames were read).

    python bench/mosaic_fidelity.py [VIDEO ...] [--frames 48] [--interpolations linear,cubic]
                                    [--resolutions first,finest] [--oversamples 1,1.5]
                                    [--halve] [--save DIR]
"""
from __future__ import annotations

import argparse
import hashlib
import logging
import math
import multiprocessing
import resource
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.mosaic import resample
from srmosaic_ros.core.mosaic.canvas import TiledCanvas
from srmosaic_ros.core.types import Frame
from srmosaic_ros.io.video import VideoReader
from srmosaic_ros.pipeline import Pipeline

REAL = ROOT.parent / 'shared' / 'data' / 'real'
VIDEOS = (REAL / 'klv' / 'aphill_short.ts', REAL / 'gopro' / 'karma.mp4')
ERODE_PX = 3  # a bicubic back-sample reads 2 px around it: keep clear of seams by one more
BORDER_PX = 3
_LUMA = np.array([0.299, 0.587, 0.114])
#: full-size pixel U of halved pixel u: U = 2 u + 1/2 (pixel centres at integers; cv2.resize's)
FULL_H_HALF = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])


def luma(rgb: np.ndarray) -> np.ndarray:
    """float64 (h, w) BT.601 luma of uint8 or 0..255 float RGB (h, w, 3)."""
    return rgb.astype(np.float64) @ _LUMA


@dataclass
class Pooled:
    """Sum of squared errors and pixel count, pooled over frames."""

    sse: float = 0.0
    n: int = 0

    def add(self, a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> None:
        d = a[mask] - b[mask]
        self.sse += float(d @ d)
        self.n += int(d.size)

    @property
    def psnr(self) -> float:
        return 10.0 * math.log10(255.0**2 / (self.sse / self.n)) if self.n and self.sse > 0 else math.nan


@dataclass
class Run:
    """What one pipeline run over one video gave."""

    paints: list[tuple[int, int, np.ndarray, np.ndarray]] = field(default_factory=list)  # canvas id, index, image, H
    paint_s: float = 0.0
    frames: int = 0
    canvas: TiledCanvas | None = None


def run_pipeline(frames: list[Frame], interpolation: str, resolution: str = 'first', oversample: float = 1.0) -> Run:
    """Feed ``frames`` through a Pipeline with mosaic.interpolation, mosaic.resolution and
    mosaic.oversample, recording every paint."""
    run = Run(frames=len(frames))
    original = TiledCanvas.paint

    def paint(self: TiledCanvas, image: np.ndarray, mosaic_H_frame: np.ndarray, **kw: Any) -> Any:
        t0 = time.perf_counter()
        res = original(self, image, mosaic_H_frame, **kw)
        run.paint_s += time.perf_counter() - t0
        run.paints.append((id(self), res.frame_index, image, np.asarray(mosaic_H_frame, np.float64)))
        return res

    TiledCanvas.paint = paint  # type: ignore[method-assign]
    try:
        pipe = Pipeline(pipeline_config({'mosaic.interpolation': interpolation, 'mosaic.resolution': resolution,
                                         'mosaic.oversample': oversample}))
        for f in frames:
            pipe.feed(f)
        pipe.flush()
        result = pipe.finish()
    finally:
        TiledCanvas.paint = original  # type: ignore[method-assign]
    seg = result.main_segment
    run.canvas = seg.canvas if seg is not None else None
    return run


def _digest(image: np.ndarray) -> str:
    return hashlib.blake2b(np.ascontiguousarray(image).tobytes(), digest_size=16).hexdigest()


def score(run: Run, frames: list[Frame], originals: list[np.ndarray] | None, save: Path | None, tag: str,
          ) -> dict[str, Any]:
    """Pooled PSNRs of one run (module docstring)."""
    canvas = run.canvas
    assert canvas is not None
    by_digest = {_digest(f.image): k for k, f in enumerate(frames)}
    fid, trip, mos_full, own_full = Pooled(), Pooled(), Pooled(), Pooled()
    x0c, y0c, x1c, y1c = canvas.bounds()
    best_crop: tuple[int, Any] | None = None
    scored = 0
    for cid, index, image, m in run.paints:
        if cid != id(canvas) or image.dtype != np.uint8 or image.ndim != 3:
            continue
        k = by_digest.get(_digest(image))
        if k is None:
            continue
        h, w = image.shape[:2]
        corners = np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]]) @ m.T
        xy = corners[:, :2] / corners[:, 2:]
        bx0, by0 = max(x0c, math.floor(xy[:, 0].min()) - 3), max(y0c, math.floor(xy[:, 1].min()) - 3)
        bx1, by1 = min(x1c, math.ceil(xy[:, 0].max()) + 4), min(y1c, math.ceil(xy[:, 1].max()) + 4)
        if bx1 - bx0 < 8 or by1 - by0 < 8:
            continue
        labels = canvas.labels((bx0, by0, bx1, by1))
        if not (labels == index).any():
            continue
        mosaic, _ = canvas.render((bx0, by0, bx1, by1))
        mosaic255 = np.clip(mosaic * 255.0, 0.0, 255.0).astype(np.float32)
        box_H_image = np.array([[1.0, 0.0, -bx0], [0.0, 1.0, -by0], [0.0, 0.0, 1.0]]) @ m
        inv = cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP
        back = np.clip(cv2.warpPerspective(mosaic255, box_H_image, (w, h), flags=inv, borderMode=cv2.BORDER_REPLICATE),
                       0, 255)
        shown = cv2.warpPerspective((labels == index).astype(np.uint8), box_H_image, (w, h),
                                    flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
        shown = cv2.erode(shown, np.ones((2 * ERODE_PX + 1,) * 2, np.uint8), borderValue=0) > 0
        shown[:BORDER_PX] = shown[-BORDER_PX:] = False
        shown[:, :BORDER_PX] = shown[:, -BORDER_PX:] = False
        if shown.sum() < 100:
            continue
        scored += 1
        ref = luma(image)
        fid.add(luma(back), ref, shown)
        alone = resample.warp(image, box_H_image, (bx1 - bx0, by1 - by0), canvas.interpolation).astype(np.float32)
        alone_back = np.clip(cv2.warpPerspective(alone, box_H_image, (w, h), flags=inv, borderMode=cv2.BORDER_REPLICATE),
                             0, 255)
        trip.add(luma(alone_back), ref, shown)
        if originals is not None:
            orig = originals[k]
            H, W = orig.shape[:2]
            full = np.clip(cv2.warpPerspective(mosaic255, box_H_image @ np.linalg.inv(FULL_H_HALF), (W, H), flags=inv,
                                               borderMode=cv2.BORDER_REPLICATE), 0, 255)
            own = np.clip(cv2.resize(image.astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC), 0, 255)
            shown_full = cv2.resize(shown.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0
            ref_full = luma(orig)
            mos_full.add(luma(full), ref_full, shown_full)
            own_full.add(luma(own), ref_full, shown_full)
        if save is not None and (best_crop is None or shown.sum() > best_crop[0]):
            best_crop = (int(shown.sum()), (image, back, shown))
    if save is not None and best_crop is not None:
        image, back, shown = best_crop[1]
        ys, xs = np.nonzero(shown)
        cy, cx = int(np.median(ys)), int(np.median(xs))
        h, w = image.shape[:2]
        s = min(96, h // 2, w // 2)
        y0, x0 = min(max(cy - s // 2, 0), h - s), min(max(cx - s // 2, 0), w - s)
        crop = np.concatenate([image[y0:y0 + s, x0:x0 + s], np.full((s, 4, 3), 255, np.uint8),
                               back[y0:y0 + s, x0:x0 + s].astype(np.uint8)], axis=1)
        crop = cv2.resize(crop, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST)
        save.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(save / f'{tag}_frame_vs_mosaic.png'), cv2.cvtColor(crop, cv2.COLOR_RGB2BGR))
    painted = sum(1 for cid, *_ in run.paints if cid == id(canvas))
    return {'frames': run.frames, 'painted': painted, 'scored': scored,
            'paint_ms_per_paint': 1000.0 * run.paint_s / max(len(run.paints), 1),
            'paint_ms_per_frame': 1000.0 * run.paint_s / max(run.frames, 1),
            'mosaic_to_frame_db': fid.psnr, 'round_trip_db': trip.psnr,
            'mosaic_bicubic_db': mos_full.psnr, 'frame_bicubic_db': own_full.psnr}


def read_frames(video: Path, count: int, halve: bool) -> tuple[list[Frame], list[np.ndarray] | None]:
    """The first ``count`` frames (halved with an area filter when ``halve``; then also the originals)."""
    frames: list[Frame] = []
    originals: list[np.ndarray] = []
    for f in VideoReader(video):
        img = f.image
        if halve:
            h, w = img.shape[:2]
            img = img[:h // 2 * 2, :w // 2 * 2]
            originals.append(img)
            img = cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        frames.append(Frame(f.stamp_ns, np.ascontiguousarray(img)))
        if len(frames) >= count:
            break
    return frames, (originals if halve else None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('videos', nargs='*', type=Path, default=list(VIDEOS))
    ap.add_argument('--frames', type=int, default=48, help='frames from the start of each video (default 48)')
    ap.add_argument('--interpolations', default='linear,cubic', help='mosaic.interpolation values, in turn')
    ap.add_argument('--halve', action='store_true', help='halve the frames and score against the originals')
    ap.add_argument('--save', type=Path, default=None, help='write side-by-side crops here')
    ap.add_argument('--resolutions', default='first', help='mosaic.resolution values, in turn (first, finest)')
    ap.add_argument('--oversamples', default='1', help='mosaic.oversample values, in turn')
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    ctx = multiprocessing.get_context('spawn')
    for video in args.videos:
        header = None
        for interp in args.interpolations.split(','):
            for resolution in args.resolutions.split(','):
                for oversample in (float(v) for v in args.oversamples.split(',')):
                    # each run in a fresh process: its peak memory is its own
                    with ctx.Pool(1) as pool:
                        out = pool.apply(run_one, (video, args.frames, args.halve, interp, resolution, oversample, args.save))
                    if header is None:
                        header = out['header']
                        print(header, flush=True)
                    print(out['line'], flush=True)


def run_one(video: Path, count: int, halve: bool, interp: str, resolution: str, oversample: float,
            save: Path | None) -> dict[str, str]:
    """One run over ``video``'s first ``count`` frames, scored: the lines to print (header, figures)."""
    logging.basicConfig(level=logging.WARNING)
    frames, originals = read_frames(video, count, halve)
    size = f'{frames[0].image.shape[1]}x{frames[0].image.shape[0]}'
    header = f'{video.name} ({len(frames)} frames, {size}{", halved" if halve else ""})'
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    run = run_pipeline(frames, interp, resolution, oversample)
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    name = f'{interp} {resolution} x{oversample:g}'
    if run.canvas is None:
        return {'header': header, 'line': f'  {name:20s} no mosaic'}
    r = score(run, frames, originals, save, f'{video.stem}_{size}_{interp}_{resolution}_x{oversample:g}')
    x0, y0, x1, y1 = run.canvas.bounds()
    line = (f'  {name:20s} painted {r["painted"]:3d} (scored {r["scored"]:3d}); '
            f'mosaic->frame {r["mosaic_to_frame_db"]:6.2f} dB, round trip {r["round_trip_db"]:6.2f} dB; '
            f'paint {r["paint_ms_per_paint"]:5.1f} ms per paint, {r["paint_ms_per_frame"]:5.1f} per frame'
            f'\n           mosaic {x1 - x0}x{y1 - y0} px ({len(run.canvas.tile_keys())} tiles); '
            f'peak RSS of the run {rss1:.0f} MiB ({rss1 - rss0:+.0f} over the frames read)')
    if halve:
        gap = r['mosaic_bicubic_db'] - r['frame_bicubic_db']
        line += (f'\n           vs original: mosaic bicubic {r["mosaic_bicubic_db"]:6.2f} dB, '
                 f'frame bicubic {r["frame_bicubic_db"]:6.2f} dB, gap {gap:+.2f} dB (goal >= -1)')
    run.canvas.close()
    return {'header': header, 'line': line}


if __name__ == '__main__':
    main()
