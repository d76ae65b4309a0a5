"""The mosaic of a solved survey (`process FOLDER`, steps 5-6): each still painted by best view on a
north-up UTM raster, with exposure gains from thumbnails, and the files written from the canvas.

Memory: the canvas's tiles (spilled beyond :func:`tiles_in_memory`, which follows the stills' size,
not their number) and two stills in flight.
"""
from __future__ import annotations

import collections
import math
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from ..config import PipelineConfig
from ..core.georef.georeferencer import GeoRaster
from ..core.image_decode import ImageRefused
from ..core.mosaic.canvas import CanvasError, TiledCanvas
from ..core.mosaic.exposure import exposure_gains
from ..core.mosaic.scratch import release as release_scratch
from ..core.mosaic.tile_store import TileLayout
from ..core.survey.paint_plan import tiles_to_paint
from ..errors import InputError
from ..io.image_folder import ImageFolderReader
from ..io.outputs import MOSAIC_TIF_ZLEVEL, output_threads
from ..malloc_tuning import trim_heap
from .survey_read import full_from_reduced, read_reduced
from .survey_still import SurveyStill

__all__ = ['THUMB_MAX_SIDE_PX', 'TILES_PER_FOOTPRINT', 'TILE_MEMORY_BUDGET_BYTES', 'footprint_px', 'paint_and_write', 'still_gains',
           'tiles_in_memory']

#: Longest side of the thumbnails whose overlaps give the exposure gains (pixels).
THUMB_MAX_SIDE_PX = 256
#: The canvas keeps this many stills' footprints of tiles in memory (at least mosaic.max_tiles_in_memory).
TILES_PER_FOOTPRINT = 2.0
#: ... but no more tile bytes than this, so that tiles and the rest of a run stay within the run's
#: memory goal whatever the stills' size (docs/results.md, the survey's peak memory); beyond it tiles spill.
TILE_MEMORY_BUDGET_BYTES = 3 << 29  # 1.5 GiB


def footprint_px(corners_local: np.ndarray, raster_H_local: np.ndarray) -> float:
    """Area (mosaic px) of the bounding box of a still's footprint, corners (4, 2) on the survey plane."""
    pts = raster_H_local @ np.vstack([corners_local.T, np.ones(len(corners_local))])
    xy = pts[:2] / pts[2]
    return float(np.prod(xy.max(axis=1) - xy.min(axis=1)))


def tiles_in_memory(configured: int, tile_size: int, footprints_px: list[float], tile_bytes: int = 0) -> int:
    """The canvas's bound on tiles in memory: mosaic.max_tiles_in_memory, raised to TILES_PER_FOOTPRINT
    times the tiles of the median still's footprint (a still at its own GSD covers its pixel count over
    T^2 tiles: with fewer in memory the tiles of the still before last are spilled and read back as
    the next line overlaps them); 0 stays 0 (no bound). The bound does not grow with the number of
    stills, only with their size, and is raised no further than TILE_MEMORY_BUDGET_BYTES of tiles of
    ``tile_bytes`` each (0: no budget)."""
    if configured <= 0 or not footprints_px:
        return configured
    per_still = float(np.median(footprints_px)) / tile_size**2
    raised = math.ceil(TILES_PER_FOOTPRINT * per_still)
    if tile_bytes > 0:  # within the budget; the configured bound stands whatever it costs (the user's)
        raised = min(raised, TILE_MEMORY_BUDGET_BYTES // tile_bytes)
    return max(configured, raised)


def still_gains(stills: list[SurveyStill], placed: list[int], raster_H_frame: list[np.ndarray],
                mode: str, clean: set[int] | None = None) -> np.ndarray:
    """Exposure gains (len(placed), 3) float32 of the placed stills, RGB (core/mosaic/exposure.py).

    raster_H_frame: per placed still the (3, 3) homography full-size pixel -> mosaic raster pixel.
    Each still is decoded at the largest JPEG reduction (8) and shrunk to THUMB_MAX_SIDE_PX: the
    gains compare means over overlaps, which need no detail. A still that cannot be decoded keeps
    gain 1 (painting reports it).
    """
    if mode == 'none' or len(placed) < 2:
        return np.ones((len(placed), 3), np.float32)

    def thumb(k: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        try:
            img = read_reduced(stills[k].file, 8, listen=k not in (clean or ()))
        except InputError:
            return None, None
        f = min(1.0, THUMB_MAX_SIDE_PX / max(img.shape[:2]))
        if f < 1.0:
            img = cv2.resize(img, (max(1, round(img.shape[1] * f)), max(1, round(img.shape[0] * f))),
                             interpolation=cv2.INTER_AREA)
        sx, sy = stills[k].size[0] / img.shape[1], stills[k].size[1] / img.shape[0]
        full_H_thumb = np.array([[sx, 0.0, (sx - 1) / 2.0], [0.0, sy, (sy - 1) / 2.0], [0.0, 0.0, 1.0]])
        return img, full_H_thumb

    with ThreadPoolExecutor(output_threads(), thread_name_prefix='survey-thumbs') as pool:
        thumbs = list(pool.map(thumb, placed))
    return exposure_gains([t for t, _ in thumbs],
                          [None if h is None else H @ h for (_, h), H in zip(thumbs, raster_H_frame)], mode)


def paint_and_write(out: Path, config: PipelineConfig, stills: list[SurveyStill], sol: Any, epsg: int,
                     origin: tuple[float, float], *, progress: bool, georeferenced: bool,
                     left_out: set[int] | None = None,
                     reader: ImageFolderReader | None = None) -> tuple[dict[str, Any], list]:
    """Paint the placed stills on a north-up raster and write mosaic.png/.tif/.kml, preview.png,
    frames.csv; returns (the report without the survey entry, the frames.csv rows). The stills of
    ``left_out`` (indices: refused by the decoding guard) are neither placed nor painted."""
    from ..io.kml import write_kml_for_raster
    from ..io.mosaic_files import write_frames_csv, write_png
    from ..io.outputs import StripPreview, write_canvas

    scfg = config.survey
    n = len(stills)
    placed = [k for k in range(n) if sol.placed_by[k] and np.all(np.isfinite(sol.ground_H_frame[k]))
              and k not in (left_out or ())]
    # ground metres per full-size pixel at each still's centre
    gsd = {k: math.sqrt(abs(np.linalg.det(sol.ground_H_frame[k][:2, :2] / sol.ground_H_frame[k][2, 2])))
           / float(stills[k].K[0, 0]) for k in placed}
    corners = {}
    for k in placed:
        w, h = stills[k].size
        c = sol.ground_H_frame[k] @ np.linalg.inv(stills[k].K) @ np.array(
            [[-0.5, w - 0.5, w - 0.5, -0.5], [-0.5, -0.5, h - 0.5, h - 0.5], [1.0, 1, 1, 1]])
        corners[k] = (c[:2] / c[2]).T if np.all(c[2] > 0) else None
    placed = [k for k in placed if corners[k] is not None]
    if not placed:
        msg = ('no still could be placed: none registered with another and none carries a GPS position; '
               'check that the stills overlap, or give their positions (EXIF GPS or telemetry_from_exif.csv).')
        raise InputError(msg)
    pts = np.concatenate([corners[k] for k in placed])
    g = scfg.mosaic_gsd_m if math.isfinite(scfg.mosaic_gsd_m) else float(np.median([gsd[k] for k in placed]))
    e_min, n_min = pts.min(axis=0)
    e_max, n_max = pts.max(axis=0)
    area_px = (e_max - e_min) * (n_max - n_min) / g**2
    if area_px > scfg.max_mosaic_megapixels * 1e6:
        g *= math.sqrt(area_px / (scfg.max_mosaic_megapixels * 1e6))
    raster = GeoRaster(epsg or 32631, g, origin[0] + float(e_min), origin[1] + float(n_max))
    raster_H_local = raster.raster_H_utm @ np.array([[1.0, 0, origin[0]], [0, 1.0, origin[1]], [0, 0, 1]])
    tile_bytes = TileLayout(config.mosaic.tile_size, 3, scfg.blend == 'multiband').nbytes
    max_tiles = tiles_in_memory(config.mosaic.max_tiles_in_memory, config.mosaic.tile_size,
                                [footprint_px(corners[k], raster_H_local) for k in placed], tile_bytes)
    canvas = TiledCanvas(3, config.mosaic.tile_size, blend=scfg.blend, max_canvas_side_px=config.mosaic.max_canvas_side_px,
                         max_tiles_in_memory=max_tiles, spill_dir=config.mosaic.spill_dir, seams=config.mosaic.seams,
                         interpolation=config.mosaic.interpolation,
                         threads=min(output_threads(), 2))  # a still's tiles on two cores (the decoder mostly waits)
    canvas_H = {}
    refused: dict[int, str] = {}
    t_exposure = time.perf_counter()
    # stills whose first decode the decoder did not warn about are decoded again without listening to it
    clean = {k for k in placed if reader is None or not any(w.startswith(f'{stills[k].file.name}: ')
                                                             for w in reader.warned_about)}
    gains = still_gains(stills, placed, [raster_H_local @ sol.ground_H_frame[k] @ np.linalg.inv(stills[k].K)
                                         for k in placed], scfg.exposure, clean)
    t_exposure = time.perf_counter() - t_exposure
    t_start = time.perf_counter()
    reduction = {}
    for k in placed:
        reduction[k] = 1
        for cand in (8, 4, 2):  # the largest reduction that still resolves the mosaic's GSD
            if gsd[k] * cand <= g * 1.0001:
                reduction[k] = cand
                break
    plan = None
    t_plan = time.perf_counter()
    if scfg.blend == 'multiband' and scfg.paint_rank > 0:
        plan = tiles_to_paint([raster_H_local @ sol.ground_H_frame[k] @ np.linalg.inv(stills[k].K) for k in placed],
                              [stills[k].size for k in placed], config.mosaic.tile_size, rank=scfg.paint_rank)
    t_plan = time.perf_counter() - t_plan
    with canvas, ThreadPoolExecutor(1, thread_name_prefix='survey-decode') as decoder:
        # the next still is decoded (OpenCV, without the GIL) while this one is painted
        decoded = collections.deque(decoder.submit(read_reduced, stills[k].file, reduction[k], listen=k not in clean)
                                    for k in placed[:1])
        bar = tqdm(total=len(placed), unit='still', desc='survey: paint', disable=not progress)
        with bar:
            for i, k in enumerate(placed):
                if i + 1 < len(placed):
                    k1 = placed[i + 1]
                    decoded.append(decoder.submit(read_reduced, stills[k1].file, reduction[k1], listen=k1 not in clean))
                H = raster_H_local @ sol.ground_H_frame[k] @ np.linalg.inv(stills[k].K)
                r = reduction[k]
                try:
                    image = decoded.popleft().result()  # uint8: warped as integers, then exposed
                    canvas.paint(image, H @ full_from_reduced(r), scale=gains[i],
                                 tiles=None if plan is None else plan.tiles[i])
                    del image
                    canvas_H[k] = H
                except (InputError, CanvasError) as exc:
                    refused[k] = str(exc)
                    if isinstance(exc, ImageRefused) and reader is not None:
                        reader.refused(exc)
                bar.update(1)
        paint_s = time.perf_counter() - t_start
        t_write = time.perf_counter()
        # The render needs no painting scratch and reads tiles from disk one at a time: what painting
        # held goes back to the system before it (the tiles in memory, the scratch arrays, freed heap).
        canvas.spill(0)
        release_scratch()
        trim_heap()
        x0, y0, x1, y1 = canvas.bounds()
        mosaic_raster = raster.shifted(x0, y0)
        preview = StripPreview(y1 - y0, x1 - x0, canvas.channels, config.mosaic.preview_max_side_px)
        tif = out / 'mosaic.tif' if georeferenced else None
        write_canvas(canvas, tif, out / 'mosaic.png', mosaic_raster if georeferenced else None, preview,
                     threads=output_threads(), zlevel=MOSAIC_TIF_ZLEVEL)
        write_png(out / 'preview.png', preview.image())
        write_s = time.perf_counter() - t_write
        canvas_stats = canvas.tile_stats()
    if georeferenced:
        write_kml_for_raster(out / 'mosaic.kml', 'mosaic.png', mosaic_raster, x1 - x0, y1 - y0)
    shift = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1]])
    rows = []
    for k, s in enumerate(stills):
        H = shift @ canvas_H[k] if k in canvas_H else None
        rows.append({'stamp_ns': s.stamp_ns, 'ok': H is not None, 'inliers': 0, 'rms_px': float('nan'),
                     'mosaic_H_frame': H, 'meta_latlon': s.latlon if s.nadir_view and math.isfinite(s.latlon[0]) else None,
                     'placed_by': sol.placed_by[k] if H is not None else ''})
    write_frames_csv(out / 'frames.csv', rows)
    report: dict[str, Any] = {
        'frames_registered': int(sum(r['ok'] for r in rows)),
        'frames_painted_any_segment': int(sum(r['ok'] for r in rows)),
        'segments': [{'index': 0, 'frames': len(canvas_H), 'file': 'mosaic.png', 'georeferenced': georeferenced,
                      'size_px': [int(x1 - x0), int(y1 - y0)], 'origin_px': [0, 0]}],
        'placed_by': dict(collections.Counter(r['placed_by'] for r in rows if r['placed_by'])),
        'refused_by_canvas': {stills[k].file.name: why for k, why in refused.items()},
        'georeferenced': ({'method': 'global alignment', 'epsg': mosaic_raster.epsg, 'gsd_m_per_px': mosaic_raster.gsd_m_per_px,
                           'geotransform': list(mosaic_raster.geotransform)} if georeferenced else None),
        'canvas': canvas_stats,
        'exposure': {'mode': scfg.exposure, 'time_s': round(t_exposure, 3),
                     'gain_min': [round(float(v), 4) for v in gains.min(axis=0)],
                     'gain_max': [round(float(v), 4) for v in gains.max(axis=0)]},
        'paint_plan': ({'rank': scfg.paint_rank, 'tiles_painted': sum(len(p) for p in plan.tiles),
                        'tiles_touched': plan.touched, 'time_s': round(t_plan, 3)} if plan is not None else None),
        'paint_s': round(paint_s, 3),
        'write_s': round(write_s, 3),
    }
    return report, rows
