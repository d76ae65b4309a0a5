"""A folder of survey stills in one georeferenced mosaic, by global alignment (`srmosaic process FOLDER`).

Chaining consecutive stills (the video pipeline) breaks where a survey is hardest: line turns,
wide baselines, textureless fields end a segment and segments are never joined. Here:

1. Metadata: each still's GPS position at its capture time, intrinsics and attitude (EXIF/XMP,
   io/exif.py via io/image_folder.py).
2. Working resolution: stills are decoded reduced by JPEG DCT scaling (OpenCV's IMREAD_REDUCED_*)
   to at most ``survey.working_megapixels`` and described once; a bounded cache keeps the features
   of the last ``survey.feature_cache_frames`` (a frame evicted and needed again is described again).
3. Pairs: consecutive stills first, which give the survey's scale (GPS baseline over registered
   displacement: the height above ground, which a drifting GPS altitude cannot give); then every
   pair whose predicted footprints overlap (core/survey/pairs.py).
4. One solve (core/survey/global_align.py): every still's ground homography from all pairs and
   the GPS positions, wrong matches dropped; stills in no pair placed by their position and
   heading (frames.csv ``placed_by`` 'pose'). Ground control points (an OpenDroneMap
   gcp_list.txt, app/ground_control.py) add their picks as constraints: without GPS they alone
   put the survey on the ground (report.json ``gcp``: control and check points' residuals).
5. The mosaic: a north-up UTM raster at the stills' ground sampling distance; each still decoded
   again at the reduction that still resolves that GSD, painted by best view (max-weight masks,
   eq. 4.7) and blended across the seams (Table 2), the next still decoded meanwhile. Memory: the
   canvas tiles (spilled beyond mosaic.max_tiles_in_memory, raised to TILES_PER_FOOTPRINT stills'
   footprints: it follows the stills' size, not their number) and two stills in flight.
6. The files: the tiles spilled and the painting scratch freed first, the mosaic is rendered once,
   strip by strip, and written on output_threads() threads (io/outputs.write_canvas): mosaic.png
   streamed while rendering, mosaic.tif compressed by GDAL threads at MOSAIC_TIF_ZLEVEL.

Outputs follow the `process` contract: mosaic.png and mosaic.tif (one grid), mosaic.kml,
preview.png, frames.csv (with ``placed_by``), report.json (``survey``: pairs, solve, timings).
There is no poses.csv: the solve places footprints on the ground, not camera poses.

The steps live in modules of their own: the stills and their metadata (app/survey_read.py), the
registrations and priors (app/survey_register.py), the mosaic and its files (app/survey_paint.py);
this module runs them (:func:`process_survey`) and keeps their public names importable from here.
"""
from __future__ import annotations

import collections
import logging
import math
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..config import PipelineConfig
from ..core.survey.global_align import solve_survey
from ..io.image_folder import ImageFolderReader
from .ground_control import GCP_REJECT_SIGMA, SurveyControl
from .survey_paint import TILE_MEMORY_BUDGET_BYTES, TILES_PER_FOOTPRINT, paint_and_write, still_gains, tiles_in_memory
from .survey_read import metadata_scale, read_reduced, reduction_for, survey_stills
from .survey_register import register_survey
from .survey_still import SurveyStill

__all__ = ['TILE_MEMORY_BUDGET_BYTES', 'TILES_PER_FOOTPRINT', 'SurveyStill', 'metadata_scale', 'process_survey', 'read_reduced',
           'reduction_for', 'register_survey', 'still_gains', 'survey_stills', 'tiles_in_memory', 'use_global_alignment']

_LOG = logging.getLogger(__name__)


def use_global_alignment(reader: ImageFolderReader, config: PipelineConfig, *, ground_control: bool = False) -> bool:
    """Whether `process` aligns this folder globally (survey.mode, 'auto': >= 3 stills with GPS, or
    ground control points)."""
    mode = config.survey.mode
    if mode != 'auto':
        return mode == 'global'
    return ground_control or sum(1 for m in reader.meta if m is not None and m.has_position) >= 3 \
        or len(reader.telemetry) >= 3


def process_survey(path: Path, out: Path, config: PipelineConfig, reader: ImageFolderReader, *,
                   progress: bool = True, gcp_file: Path | None = None,
                   check_points: str | None = None) -> dict[str, Any]:
    """Align, mosaic and write a folder of stills (module docstring); returns the report (the caller
    adds timings and writes report.json). gcp_file: ground control points (OpenDroneMap's
    gcp_list.txt; None: none); check_points: the targets held out of the control
    (app/ground_control.py's check_point_names)."""
    t0 = time.perf_counter()
    scfg = config.survey
    stills, epsg, origin = survey_stills(reader)
    n = len(stills)
    ground = None
    if gcp_file is not None:  # read before the registrations: a malformed file fails in seconds
        ground = SurveyControl.load(gcp_file, stills, epsg, origin, check_points)
        epsg, origin = ground.epsg, ground.origin
    reg = register_survey(stills, config, progress=progress, control=None if ground is None else ground.control,
                          reader=reader)
    pairs, registrations, reduction, more = reg.pairs, reg.registrations, reg.reduction, reg.more
    scale, scale_source, has_gps, georef_note = reg.scale, reg.scale_source, reg.has_gps, reg.georef_note
    t_reg = reg.register_s
    t_solve = time.perf_counter()
    sol = solve_survey(n, pairs, reg.priors, control=None if ground is None else ground.control,
                       control_reject_sigma=GCP_REJECT_SIGMA)
    t_solve = time.perf_counter() - t_solve
    by_control = bool(sol.figures.get('control_placed_survey'))
    if by_control:
        georef_note = ''
    georeferenced = has_gps or by_control

    t_paint = time.perf_counter()
    report, rows = paint_and_write(out, config, stills, sol, epsg, origin, progress=progress,
                                    georeferenced=georeferenced, left_out=set(reg.unreadable), reader=reader)
    t_paint = time.perf_counter() - t_paint
    pairs_of = collections.Counter()
    for p, u in zip(pairs, sol.pair_used):
        if u:
            pairs_of[p.i] += 1
            pairs_of[p.j] += 1
    # counted per kind: 'perspective change # exceeds #', not one key per value
    failures = collections.Counter(re.sub(r'\d+(\.\d+)?', '#', reg.reason.split(' (')[0])
                                   for reg in registrations.values() if not reg.ok)
    if georef_note:
        report['not_georeferenced_reason'] = f'{georef_note}; the survey is aligned on its first still\'s plane only.'
    report['survey'] = {
        'method': 'global alignment' + ('' if has_gps else ' on ground control (no GPS)' if by_control
                                        else ' (no GPS: not georeferenced)'),
        'working_reduction': collections.Counter(reduction).most_common(1)[0][0],
        'working_megapixels': scfg.working_megapixels,
        'scale_m': scale,
        'scale_source': scale_source + ('; the ground control points set the survey\'s scale' if by_control else ''),
        'scale_is_guess': reg.scale_is_guess and not by_control,
        'height_above_ground_m': scale if reg.focal_known else None,
        'position_sigma_m': float(np.median(reg.priors.position_sigma_m)),
        'pairs_tried': len(registrations), 'pairs_registered': len(pairs),
        'pairs_consecutive_tried': n - 1, 'pairs_by_footprint_tried': len(more),
        # the OpenCV registrar's second opinion: pairs it registered (also those of the consecutive
        # pass of a survey without GPS), and the pairs by footprint it was asked about ([i, j, registered])
        'pairs_by_second_opinion': sum(reg.ok and reg.extras.get('fallback_opencv') == 1.0
                                       for reg in registrations.values()),
        'pairs_second_opinion': reg.second_opinions,
        'registration_failures': dict(failures),
        'frames_described': reg.described, 'feature_cache_frames': scfg.feature_cache_frames,
        'unreadable': {stills[k].file.name: why for k, why in reg.unreadable.items()},
        'median_pairs_per_frame': float(np.median([pairs_of[k] for k in range(n)])) if n else 0.0,
        **sol.figures,
        'pairs_graph': [[[p.i, p.j], bool(u)] for p, u in zip(pairs, sol.pair_used)],  # frame indices, used
        # beside pairs_graph, pair by pair: [inliers, RMS residual (px)] of its registration
        'pairs_quality': [[int(p.inliers), _rounded(getattr(registrations.get((p.i, p.j)), 'rms_px', math.nan))]
                          for p in pairs],
        'time_s': {'register': round(t_reg, 3), 'solve': round(t_solve, 3), 'paint': report.pop('paint_s'),
                   'write': report.pop('write_s'), 'paint_and_write': round(t_paint, 3),
                   'total': round(time.perf_counter() - t0, 3)},
    }
    report['frames_in'] = n
    report['registration'] = {
        'median_inliers': float(np.median([p.inliers for p in pairs])) if pairs else None,
        'median_rms_px': float(np.median([r.rms_px for r in registrations.values() if r.ok])) if pairs else None,
        'median_ms': float(np.median([r.time_s for r in registrations.values()]) * 1e3) if registrations else None,
    }
    _LOG.info('survey: %d of %d stills placed (%d by registration, %d by pose), %d of %d pairs used, '
              'position residual %.2f m RMS', sum(r['ok'] for r in rows), n, sol.placed_by.count('registration'),
              sol.placed_by.count('pose'), int(sol.pair_used.sum()), len(pairs),
              sol.figures['position_residual_rms_m'] or math.nan)
    if ground is not None:
        gsd = report['georeferenced']['gsd_m_per_px'] if report.get('georeferenced') else math.nan
        report['gcp'] = ground.report(sol, gsd)
    return report


def _rounded(v: float, digits: int = 3) -> float | None:
    return round(float(v), digits) if math.isfinite(v) else None
