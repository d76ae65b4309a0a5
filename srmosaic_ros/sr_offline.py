"""`srmosaic process ... --sr`: super-resolved tiles of the finished mosaic (DIR/sr/).

Tiles are chosen by the SR scheduler (core/sr/scheduler.py); the frames they need are read again
from the input in a second pass (only those frames are kept), and each tile is reconstructed by
MAP with the Huber prior (core/sr/reconstruct.py). Output contract (DESIGN.md): DIR/sr/tiles.json,
a list of {"file", "x0", "y0", "width", "height", "factor"} where (x0, y0, width, height) is the
tile's region in mosaic.png pixels and tile pixel (u, v) shows mosaic point
(x0 + (u + 0.5) / factor - 0.5, y0 + (v + 0.5) / factor - 0.5); DIR/sr/preview.png the mosaic
upscaled by the factor (bicubic) with the SR tiles pasted in, downscaled for viewing.
"""
from __future__ import annotations

import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from .config import PipelineConfig
from .core.sr.reconstruct import SRError, reconstruct_tile
from .core.sr.scheduler import plan_tiles
from .core.types import Frame
from .io.mosaic_files import read_frames_csv, write_json, write_png

__all__ = ['super_resolve_mosaic']

MAX_PREVIEW_PIXELS = 40_000_000


def _translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def super_resolve_mosaic(out: Path, items: Iterable[Any], config: PipelineConfig, *, factor: int,
                         progress: bool = True) -> dict[str, Any]:
    """Reconstruct the scheduled tiles of out/mosaic.png from the frames in `items` (second pass)."""
    rows = [r for r in read_frames_csv(out / 'frames.csv') if r['ok']]
    mosaic = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    coverage = mosaic[:, :, 3] > 0
    stamps = {r['stamp_ns']: i for i, r in enumerate(rows)}
    # Frame sizes are needed for planning: take them from the second pass lazily (first frame seen).
    frames: dict[int, np.ndarray] = {}
    sizes: dict[int, tuple[int, int]] = {}
    cfg_tiles = config.sr_tiles.__class__(**{**vars(config.sr_tiles), 'factor': factor})
    needed: set[int] | None = None
    plans = []
    buffered: dict[int, np.ndarray] = {}
    for item in items:
        if not isinstance(item, Frame) or item.stamp_ns not in stamps:
            continue
        k = stamps[item.stamp_ns]
        sizes[k] = (item.image.shape[1], item.image.shape[0])
        buffered[k] = item.image  # kept until planning: frames of one flight share a size
        if needed is None and len(sizes) == 1:
            # All frames of a flight have the first frame's size (a size change ends a video run).
            size = sizes[k]
            plans = plan_tiles({i: r['mosaic_H_frame'] for i, r in enumerate(rows)},
                               {i: size for i in range(len(rows))}, coverage, cfg_tiles)
            needed = {f for p in plans for f in p.frames}
        if needed is not None:
            for j in list(buffered):
                if j in needed:
                    frames[j] = buffered[j]
            buffered.clear()
    s = factor
    tiles_dir = out / 'sr'
    tiles_dir.mkdir(parents=True, exist_ok=True)
    h, w = coverage.shape
    big = h * w * s * s <= MAX_PREVIEW_PIXELS
    rgb = cv2.cvtColor(mosaic[:, :, :3], cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    upscaled = cv2.resize(rgb, (w * s, h * s), interpolation=cv2.INTER_CUBIC) if big else None
    entries, figures = [], []
    for plan in tqdm(plans, unit='tile', desc='super-resolve', disable=not progress):
        t0 = time.perf_counter()
        use = [k for k in plan.frames if k in frames]
        tile_H = [_translation(-plan.x0, -plan.y0) @ rows[k]['mosaic_H_frame'] for k in use]  # noqa: N806
        try:
            res = reconstruct_tile([frames[k] for k in use], tile_H, (plan.height, plan.width), s, config=config.sr)
        except SRError as exc:
            figures.append({'x0': plan.x0, 'y0': plan.y0, 'error': str(exc)})
            continue
        image = res.image.detach().cpu().numpy().transpose(1, 2, 0)
        image = np.clip(image, 0.0, 1.0)
        name = f'tile_x{plan.x0:06d}_y{plan.y0:06d}.png'
        write_png(tiles_dir / name, image)
        entries.append({'file': name, 'x0': plan.x0, 'y0': plan.y0, 'width': plan.width, 'height': plan.height,
                        'factor': s})
        last = res.history[-1] if res.history else None
        weights = np.asarray(res.frame_weights, dtype=float)
        figures.append({'file': name, 'frames': len(use), 'frames_covering': plan.frames_covering,
                        'iterations': len(res.history) - 1 if res.history else 0, 'stop_reason': res.stop_reason,
                        'lambda': float(getattr(last, 'lam', float('nan'))) if last is not None else None,
                        'min_frame_weight': float(weights[np.isfinite(weights)].min()) if weights.size else None,
                        'time_s': round(time.perf_counter() - t0, 3)})
        if upscaled is not None and image.shape[2] == upscaled.shape[2]:
            upscaled[plan.y0 * s:(plan.y0 + plan.height) * s, plan.x0 * s:(plan.x0 + plan.width) * s] = image
    write_json(tiles_dir / 'tiles.json', entries)
    if upscaled is not None:
        cov_up = cv2.resize(coverage.astype(np.uint8), (w * s, h * s), interpolation=cv2.INTER_NEAREST) > 0
        from .offline import preview_image

        write_png(tiles_dir / 'preview.png', preview_image(upscaled, cov_up, 2048))
    return {'factor': s, 'tiles': len(entries), 'tiles_planned': len(plans), 'frames_read': len(frames),
            'solver': config.sr.solver, 'iterations_cap': config.sr.iterations, 'per_tile': figures}
