"""`srmosaic process ... --sr`: super-resolved tiles of the finished mosaic (DIR/sr/).

A tile SR cannot improve shows its best frame upsampled instead (core/sr/fallback.py); tiles.json
says so after the contract's keys ("source": "sr" or "frame", "fallback": null or the reason).

Tiles are chosen by the SR scheduler (core/sr/scheduler.py); the frames they need are read again
from the input in a second pass (only those frames are kept), and each tile is reconstructed by
MAP with the Huber prior (core/sr/reconstruct.py). Output contract (DESIGN.md): DIR/sr/tiles.json,
a list of {"file", "x0", "y0", "width", "height", "factor"} where (x0, y0, width, height) is the
tile's region in mosaic.png pixels and tile pixel (u, v) shows mosaic point
(x0 + (u + 0.5) / factor - 0.5, y0 + (v + 0.5) / factor - 0.5).

Also written:
- DIR/sr/mosaic_sr.tif, the SR mosaic: the whole mosaic upsampled by the factor (bicubic, the
  same pixel convention: its pixel (u, v) shows mosaic point ((u + 0.5) / factor - 0.5, ...)) with
  the SR tiles pasted in, alpha from the mosaic's coverage; tiled with overviews, written strip by
  strip. With georeferencing it is a GeoTIFF on mosaic.tif's grid refined by the factor (same CRS,
  gsd / factor), so GIS tools lay it over mosaic.tif;
- with georeferencing, each tile as a GeoTIFF too (the PNG's name with .tif), placed on the map;
- DIR/sr/preview.png: mosaic_sr.tif downscaled for viewing (longer side 2048 px).
"""
from __future__ import annotations

import logging
import time
from dataclasses import replace
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from ..core.homography import translation as _translation
from ..config import PipelineConfig
from ..core.sr.psf_select import TileFrames, choose_psf_sigma
from ..core.sr.reconstruct import SRError
from ..core.sr.fallback import FALLBACK_REASONS, super_resolve_or_fallback
from ..core.sr.ringing import resolve_clamp
from ..core.sr.scheduler import plan_tiles
from ..core.types import CameraIntrinsics, Frame
from ..core.undistort import Undistorter
from ..io.geotiff import MOSAIC_BLOCK_PX, read_raster, write_geotiff, write_geotiff_blocks
from ..io.mosaic_files import read_frames_csv, write_json, write_png
from ..io.outputs import StripPreview
from ..live.sr import SRTilePlacement

__all__ = ['sr_mosaic_strips', 'super_resolve_mosaic']

#: Mosaic rows upsampled (and written to mosaic_sr.tif) at a time.
SR_STRIP_ROWS = 128
_LOG = logging.getLogger(__name__)
_CUBIC_MARGIN = 3  # mosaic rows of context above and below a strip (bicubic reads 2)


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
    undistorter, camera = Undistorter(config.undistort), None  # the frames as the first pass saw them
    for item in items:
        if isinstance(item, CameraIntrinsics):
            camera = item
        if not isinstance(item, Frame) or item.stamp_ns not in stamps:
            continue
        item = undistorter.frame(item, camera)
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
    raster = read_raster(out / 'mosaic.tif') if (out / 'mosaic.tif').is_file() else None

    def tile_inputs(plan: Any) -> TileFrames:
        use = [k for k in plan.frames if k in frames]
        return TileFrames([frames[k] for k in use],
                          [_translation(-plan.x0, -plan.y0) @ rows[k]['mosaic_H_frame'] for k in use],
                          (plan.height, plan.width))

    sr_config, selection = _flight_psf(config, [tile_inputs(p) for p in plans[:PSF_TILES]], s)
    entries, figures, pasted = [], [], []
    holdouts = max(sr_config.fallback, sr_config.self_check)
    for plan in tqdm(plans, unit='tile', desc='super-resolve', disable=not progress):
        t0 = time.perf_counter()
        tile = tile_inputs(plan)
        if not tile.frames:
            figures.append({'x0': plan.x0, 'y0': plan.y0, 'frames': 0, 'error': 'no frame of the tile was read again',
                            'frames_disagree': False, 'not_better_than_mosaic': False})
            continue
        outcome = super_resolve_or_fallback(tile.frames, tile.tile_H_frames, tile.tile_shape, s, sr_config,
                                            holdouts=holdouts)
        image = outcome.image
        name = f'tile_x{plan.x0:06d}_y{plan.y0:06d}.png'
        write_png(tiles_dir / name, image)
        if raster is not None:
            # tile pixel (u, v) is mosaic pixel (x0 + (u + 0.5) / s - 0.5, ...): a similarity of the grid
            place = SRTilePlacement(0, plan.x0, plan.y0, plan.width, plan.height, s)
            write_geotiff(tiles_dir / name.replace('.png', '.tif'), image[:, :, 0] if image.shape[2] == 1 else image,
                          raster.transformed(place.plane_H_tile()))
        # the contract's keys first; then what the tile shows: 'sr', or 'frame' (its best frame
        # upsampled) with the reason (core/sr/fallback.py)
        entries.append({'file': name, 'x0': plan.x0, 'y0': plan.y0, 'width': plan.width, 'height': plan.height,
                        'factor': s, 'source': 'frame' if outcome.fallback else 'sr',
                        'fallback': outcome.fallback or None})
        pasted.append((plan.x0, plan.y0, np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8)))
        held_out = {'held_out_rms_by': outcome.held_out_rms} if outcome.held_out_rms else {}
        if outcome.result is None:
            figures.append({'file': name, 'x0': plan.x0, 'y0': plan.y0, 'frames': len(tile.frames),
                            'error': outcome.detail, 'frames_disagree': outcome.fallback == 'frames_disagree',
                            'not_better_than_mosaic': False, 'fallback': outcome.fallback, **held_out,
                            'time_s': round(time.perf_counter() - t0, 3)})
            continue
        res = outcome.result
        last = res.history[-1] if res.history else None
        weights = np.asarray(res.frame_weights, dtype=float)
        figures.append({'file': name, 'frames': len(tile.frames), 'frames_covering': plan.frames_covering,
                        'frames_consistent': int(np.count_nonzero(res.frame_consistent)),
                        'agrees_with_mosaic': bool(res.consistency.get('reference_kept', 1.0)),
                        'anchored': bool(np.isfinite(res.anchor_rms)),
                        'anchor_residual': round(255.0 * res.anchor_rms, 2) if np.isfinite(res.anchor_rms) else None,
                        'noise': round(255.0 * res.consistency['noise'], 2) if 'noise' in res.consistency else None,
                        'iterations': len(res.history), 'stop_reason': res.stop_reason,
                        'lambda': float(getattr(last, 'lam', float('nan'))) if last is not None else None,
                        'min_frame_weight': float(weights[np.isfinite(weights)].min()) if weights.size else None,
                        'held_out_rms': [round(v, 3) if np.isfinite(v) else None for v in res.held_out_rms],
                        **held_out, 'fallback': '',
                        'time_s': round(time.perf_counter() - t0, 3)})
    write_json(tiles_dir / 'tiles.json', entries)
    h, w = coverage.shape
    rgb = mosaic[:, :, 2::-1]  # BGR(A) -> RGB, a view
    preview = StripPreview(h * s, w * s, 3, 2048)

    def strips() -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        for row, image, cov in sr_mosaic_strips(rgb, coverage, s, pasted):
            preview.add(row, image.astype(np.float32) * (1.0 / 255.0), cov)
            yield row, image, cov

    whole = SRTilePlacement(0, 0, 0, w, h, s)  # the SR mosaic: the whole mosaic as one tile
    write_geotiff_blocks(tiles_dir / 'mosaic_sr.tif', strips(), None if raster is None else
                         raster.transformed(whole.plane_H_tile()), h * s, w * s, block_px=MOSAIC_BLOCK_PX)
    write_png(tiles_dir / 'preview.png', preview.image())
    refused = sum(1 for f in figures if f.get('frames_disagree'))
    fallbacks = {reason: sum(1 for f in figures if f.get('fallback') == reason) for reason in FALLBACK_REASONS}
    failed = [f['error'] for f in figures if 'error' in f and not f.get('fallback')]
    if sum(fallbacks.values()):
        _LOG.warning('%d of %d SR tiles show their best frame upsampled instead of SR (%s); named in sr/tiles.json '
                     '"fallback", the reasons in report.json sr.per_tile', sum(fallbacks.values()), len(plans),
                     ', '.join(f'{n} {r}' for r, n in fallbacks.items() if n))
    if failed:
        _LOG.warning('%d of %d SR tiles failed: %s', len(failed), len(plans), failed[0])
    return {'factor': s, 'tiles': len(entries), 'tiles_planned': len(plans), 'tiles_refused': refused,
            'tiles_frames_disagree': refused, 'tiles_not_better_than_mosaic': 0,
            'tiles_sr': sum(1 for e in entries if e['source'] == 'sr'),
            'tiles_fallback': sum(fallbacks.values()), 'tiles_fallback_by_reason': fallbacks,
            'fallback_holdouts': holdouts,
            'frames_read': len(frames),
            'solver': config.sr.solver, 'iterations_cap': config.sr.iterations,
            'psf_sigma_px': sr_config.psf_sigma, 'psf_selection': selection,
            'settings': {k: list(v) if isinstance(v, tuple) else v for k, v in vars(sr_config).items()},
            'tile_settings': dict(vars(cfg_tiles)), 'per_tile': figures}


#: Tiles (the best covered) on which the flight's PSF is chosen.
PSF_TILES = 3


def _flight_psf(config: PipelineConfig, tiles: list[TileFrames], factor: int) -> tuple[Any, dict[str, Any]]:
    """The SR settings with the flight's PSF: chosen from ``sr.psf_ladder`` by predicting held-out frames
    (core/sr/psf_select.py), or ``sr.psf_sigma`` as given, and the clamp ``sr.clamp: auto`` resolves to
    for it (core/sr/ringing.py); and what the report says about the choice."""
    ladder = tuple(config.sr.psf_ladder)
    given = replace(config.sr, clamp=resolve_clamp(config.sr.clamp, psf_chosen=False))
    if len(ladder) < 2:
        return given, {'method': 'given'}
    t0 = time.perf_counter()
    try:
        choice = choose_psf_sigma(tiles, factor, config.sr, ladder)
    except SRError as exc:
        _LOG.warning('sr.psf_sigma %.2f kept: %s', config.sr.psf_sigma, exc)
        return given, {'method': 'given', 'ladder_failed': str(exc)}
    _LOG.info('PSF chosen from the frames: sigma %.2f LR px (held-out RMS per sigma: %s)', choice.sigma,
              ', '.join(f'{s:g}: {255 * r:.3f}' for s, r in zip(choice.ladder, choice.rms, strict=True)))
    # a PSF chosen by predicting held-out frames is not the over-estimated one that rings (ringing.py)
    return replace(config.sr, psf_sigma=choice.sigma, clamp=resolve_clamp(config.sr.clamp, psf_chosen=True)), {
        'method': 'held_out_frames', 'ladder': list(choice.ladder),
        'held_out_rms': [round(255.0 * r, 4) for r in choice.rms], 'predictions': choice.predictions,
        'time_s': round(time.perf_counter() - t0, 2)}


def sr_mosaic_strips(mosaic_rgb: np.ndarray, coverage: np.ndarray, factor: int,
                     tiles: Sequence[tuple[int, int, np.ndarray]], *,
                     rows: int = SR_STRIP_ROWS) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """The SR mosaic in strips, top to bottom: the mosaic upsampled by ``factor`` with the tiles pasted in.

    mosaic_rgb: (H, W, C) uint8 mosaic; coverage: (H, W) bool; tiles: (x0, y0, image) with image
    (h s, w s, C or 1) uint8, the SR tile of mosaic region (x0, y0, w, h). Yields (row, strip
    (n, W s, C) uint8, coverage (n, W s) bool), n = rows * factor (less at the bottom), row in SR
    pixels. Upsampling is OpenCV's bicubic (SR pixel (u, v) shows mosaic point ((u + 0.5) / s - 0.5,
    ...), the convention of the tiles); each strip is resized from its rows plus a margin of
    context, so the strips are exactly the rows of one resize of the whole mosaic, which is never
    held. Coverage is upsampled by pixel replication.
    """
    s = int(factor)
    h, w = coverage.shape
    channels = mosaic_rgb.shape[2]
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        a, b = max(0, r0 - _CUBIC_MARGIN), min(h, r1 + _CUBIC_MARGIN)
        up = cv2.resize(np.ascontiguousarray(mosaic_rgb[a:b]), (w * s, (b - a) * s), interpolation=cv2.INTER_CUBIC)
        strip = np.ascontiguousarray(up.reshape(up.shape[0], up.shape[1], channels)[(r0 - a) * s:(r1 - a) * s])
        cov = np.repeat(np.repeat(coverage[r0:r1], s, axis=0), s, axis=1)
        top, bottom = r0 * s, r1 * s
        for x0, y0, tile in tiles:
            t0, t1 = max(top, y0 * s), min(bottom, y0 * s + tile.shape[0])
            if t0 >= t1:
                continue
            part = tile[t0 - y0 * s:t1 - y0 * s]
            if part.ndim == 2 or part.shape[2] != channels:   # a grey tile in an RGB mosaic
                part = np.repeat(part.reshape(part.shape[0], part.shape[1], -1)[:, :, :1], channels, axis=2)
            strip[t0 - top:t1 - top, x0 * s:x0 * s + tile.shape[1]] = part
        yield top, strip, cov
