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
"""
from __future__ import annotations

import collections
import logging
import math
import re
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from ..config import PipelineConfig
from ..core.georef.frames import R_enu_from_cam_aviation
from ..core.georef.georeferencer import GeoRaster, utm_epsg
from ..core.georef.geotag_fit import GEOTAG_MIN_EXTENT_M, geotags_at
from ..core.image_decode import ImageRefused, decode_file
from ..core.mosaic.canvas import CanvasError, TiledCanvas
from ..core.mosaic.exposure import exposure_gains
from ..core.mosaic.scratch import release as release_scratch
from ..core.mosaic.tile_store import TileLayout
from ..core.registration import make_registrar
from ..core.survey.global_align import (GroundControl, PairConstraint, SurveyPriors, attitude_ground_H,
                                       estimate_scale, pair_constraint, solve_survey)
from .ground_control import GCP_REJECT_SIGMA, SurveyControl
from .survey_still import SurveyStill
from ..core.survey.pairs import predicted_pairs
from ..core.survey.paint_plan import tiles_to_paint
from ..errors import InputError
from ..io.image_folder import ImageFolderReader
from ..io.metadata import RECORDED_ATTITUDE_SIGMA_DEG
from ..io.outputs import MOSAIC_TIF_ZLEVEL, output_threads
from ..malloc_tuning import trim_heap

__all__ = ['SurveyStill', 'metadata_scale', 'process_survey', 'read_reduced', 'reduction_for', 'still_gains',
           'survey_stills', 'tiles_in_memory', 'use_global_alignment']

_LOG = logging.getLogger(__name__)
_REDUCED = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4,
            8: cv2.IMREAD_REDUCED_COLOR_8}
#: A pair by footprint that the torch registrar fails gets the OpenCV registrar's second opinion
#: when one of its stills has fewer registered pairs than this.
SECOND_OPINION_BELOW_PAIRS = 3
#: Longest side of the thumbnails whose overlaps give the exposure gains (pixels).
THUMB_MAX_SIDE_PX = 256
#: The canvas keeps this many stills' footprints of tiles in memory (at least mosaic.max_tiles_in_memory).
TILES_PER_FOOTPRINT = 2.0
#: ... but no more tile bytes than this (stills of 20 MP and more at their own sampling would pass
#: the 3 GB goal of a whole run: the rest of a run takes about 1 GB); beyond it tiles spill.
TILE_MEMORY_BUDGET_BYTES = 3 << 29  # 1.5 GiB
#: Unknown focal length: the normalised coordinates use this many pixels per unit of the longer
#: side (about a 55 deg field of view); the scale the solve finds is then not a height.
NOMINAL_FOCAL_PER_SIDE = 1.0


def reduction_for(width: int, height: int, max_megapixels: float) -> int:
    """The smallest JPEG reduction (1, 2, 4, 8) that brings width x height to at most max_megapixels."""
    for r in (1, 2, 4, 8):
        if math.ceil(width / r) * math.ceil(height / r) <= max_megapixels * 1e6:
            return r
    return 8


def read_reduced(file: Path, reduction: int, warn: Callable[[str, str], None] | None = None, *,
                 listen: bool = True) -> np.ndarray:
    """RGB uint8 (H, W, 3) of a still decoded reduced by 1, 2, 4 or 8 (JPEG: in the DCT, without
    decoding the full image; other formats: decoded, then reduced by OpenCV), as stored (no
    EXIF rotation: intrinsics and angles refer to the sensor).

    Decoded under the guard of core/image_decode.py: a truncated or damaged still, or one without
    content, raises ImageRefused (an InputError); ``warn(name, message)`` hears the decoder's other
    warnings; ``listen=False``: the still was heard decoding cleanly before, decode it without reading
    the decoder's stderr (core/image_decode.py: in parallel)."""
    decoded = decode_file(file, _REDUCED[reduction] | cv2.IMREAD_IGNORE_ORIENTATION, reduction=reduction,
                          listen=listen)
    if warn is not None:
        for message in decoded.warnings:
            warn(file.name, message)
    return cv2.cvtColor(decoded.pixels, cv2.COLOR_BGR2RGB)


def _full_from_reduced(r: int) -> np.ndarray:
    """(3, 3) pixel of an image reduced by r -> pixel of the full image (pixel centres at integers)."""
    return np.array([[r, 0.0, (r - 1) / 2.0], [0.0, r, (r - 1) / 2.0], [0.0, 0.0, 1.0]])


def use_global_alignment(reader: ImageFolderReader, config: PipelineConfig, *, ground_control: bool = False) -> bool:
    """Whether `process` aligns this folder globally (survey.mode, 'auto': >= 3 stills with GPS, or
    ground control points)."""
    mode = config.survey.mode
    if mode != 'auto':
        return mode == 'global'
    return ground_control or sum(1 for m in reader.meta if m is not None and m.has_position) >= 3 \
        or len(reader.telemetry) >= 3


def survey_stills(reader: ImageFolderReader) -> tuple[list[SurveyStill], int, tuple[float, float]]:
    """Every still of the folder with its metadata; (stills, UTM EPSG, plane origin (e0, n0) in UTM m)."""
    from pyproj import Transformer

    stills_meta = []
    fixes = []
    for i, file in enumerate(reader.files):
        meta = reader.meta[i]
        stamp = reader.stamp_ns(i, file.name)
        row = reader.telemetry.get(file.name)
        lat = lon = alt = math.nan
        if row:
            try:
                lat, lon = float(row['lat']), float(row['lon'])
                fixes.append((stamp, lon, lat))
                alt = float(row.get('alt_msl') or 'nan')
            except (KeyError, ValueError):
                pass
        elif meta is not None and meta.has_position:
            fixes.append((reader.fix_stamp_ns(i, stamp), meta.longitude_deg, meta.latitude_deg))
            alt = meta.altitude_m
        stills_meta.append((file, meta, stamp, alt))
    fixes.sort()
    dedup = [f for k, f in enumerate(fixes) if k == 0 or f[1:] != fixes[k - 1][1:]]  # a tag repeating the last fix
    stamps = np.array([s for _, _, s, _ in stills_meta], dtype=np.int64)
    if dedup:
        lonlat = geotags_at(np.array([f[0] for f in dedup], dtype=np.int64), np.array([f[1:] for f in dedup]),
                            stamps, max_gap_s=30.0)
    else:
        lonlat = np.full((len(stamps), 2), np.nan)
    ok = np.isfinite(lonlat).all(axis=1)
    epsg, to_utm = 0, None
    origin = (0.0, 0.0)
    if ok.any():
        lon0, lat0 = np.median(lonlat[ok], axis=0)
        epsg = utm_epsg(float(lat0), float(lon0))
        to_utm = Transformer.from_crs(4326, epsg, always_xy=True)
        e, n = to_utm.transform(lonlat[ok, 0], lonlat[ok, 1])
        origin = (float(np.round(np.mean(e))), float(np.round(np.mean(n))))
    stills = []
    for k, (file, meta, stamp, alt) in enumerate(stills_meta):
        w, h = (meta.width_px, meta.height_px) if meta is not None else reader.size(k)
        camera = reader.camera(meta, w, h) if meta is not None else None
        if camera is not None:
            K = np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])
        else:
            f = NOMINAL_FOCAL_PER_SIDE * max(w, h)
            K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
        pos = np.array([math.nan, math.nan])
        if ok[k] and to_utm is not None:
            e, n = to_utm.transform(lonlat[k, 0], lonlat[k, 1])
            pos = np.array([e - origin[0], n - origin[1]])
        nadir = meta is None or meta.gimbal_ypr_deg is None or abs(meta.gimbal_ypr_deg[1] + 90.0) <= 10.0
        R = None
        if meta is not None and meta.gimbal_ypr_deg is not None:
            R = R_enu_from_cam_aviation(*meta.gimbal_ypr_deg)
        height = meta.relative_altitude_m if meta is not None else math.nan
        stills.append(SurveyStill(file, (w, h), int(stamp), K, camera is not None, pos,
                                  (float(lonlat[k, 1]), float(lonlat[k, 0])), nadir, R, float(height), float(alt)))
    return stills, epsg, origin


class _FeatureCache:
    """Features of the working-resolution stills, the last ``size`` described kept (LRU)."""

    def __init__(self, registrar: Any, stills: list[SurveyStill], reduction: list[int], size: int,
                 max_features: int, reader: ImageFolderReader) -> None:
        self.registrar, self.stills, self.reduction, self.size = registrar, stills, reduction, size
        self.reader = reader
        self.max_features = max_features
        self.cache: collections.OrderedDict[int, Any] = collections.OrderedDict()
        self.described = 0
        self.unreadable: dict[int, str] = {}

    def get(self, k: int) -> Any:
        if k in self.unreadable:
            return None
        if k in self.cache:
            self.cache.move_to_end(k)
            return self.cache[k]
        try:
            image = read_reduced(self.stills[k].file, self.reduction[k], self.reader.decoder_warning)
        except InputError as exc:
            self.unreadable[k] = exc.why if isinstance(exc, ImageRefused) else str(exc)
            if isinstance(exc, ImageRefused):
                self.reader.refused(exc)
            return None
        feats = _compact(self.registrar.describe(image), self.max_features)
        self.described += 1
        self.cache[k] = feats
        while len(self.cache) > self.size:
            self.cache.popitem(last=False)
        return feats


def _compact(features: Any, max_features: int) -> Any:
    """Torch features described up to max_features at once, without the scale-space gradients kept
    for describing more later (7.5 of 12 MB for a 1000x750 still): a cached still costs its
    pyramid, templates and descriptors only (about 5 MB)."""
    import dataclasses

    primary = getattr(features, 'primary', features)
    if hasattr(primary, 'candidates') and hasattr(primary, 'extend'):
        primary.extend(max_features)
        c = primary.candidates
        # new empty tensors: a slice would keep the whole buffer alive
        primary.candidates = dataclasses.replace(c, xy=c.xy[:0].clone(), sub_level=c.sub_level[:0].clone(),
                                                 octave=c.octave[:0].clone(), response=c.response[:0].clone(),
                                                 tall=c.tall[:, :, :0].clone(), count=None)
    return features


def _footprint_px(corners_local: np.ndarray, raster_H_local: np.ndarray) -> float:
    """Area (mosaic px) of the bounding box of a still's footprint, corners (4, 2) on the survey plane."""
    pts = raster_H_local @ np.vstack([corners_local.T, np.ones(len(corners_local))])
    xy = pts[:2] / pts[2]
    return float(np.prod(xy.max(axis=1) - xy.min(axis=1)))


def tiles_in_memory(configured: int, tile_size: int, footprints_px: list[float], tile_bytes: int = 0) -> int:
    """The canvas's bound on tiles in memory: mosaic.max_tiles_in_memory, raised to TILES_PER_FOOTPRINT
    times the tiles of the median still's footprint (a 12 MP still at its own GSD covers ~190 tiles
    of 256 px: with 256 in memory the tiles of the still before last are spilled and read back as
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


def metadata_scale(stills: list[SurveyStill], config: PipelineConfig, reader: ImageFolderReader | None, *,
                   why: str) -> tuple[float, str, bool]:
    """The survey's scale (metres per normalised unit: the height above the ground of a nadir still)
    from the metadata, when no GPS baseline gives it (``why``); (scale, its source, whether it is a guess).

    In order: the stills' height above take-off (DJI XMP RelativeAltitude, Camera:AboveGroundAltitude;
    io/exif.py) with their intrinsics, the median over the stills that carry it; then their GPS
    altitude above the ground height prior (georef.ground_altitude_m, else the one the metadata
    implies, io/image_folder.py); then, a guess, georef.nominal_agl_m. Without the intrinsics a
    height is no scale (the normalised coordinates use a nominal focal length): the guess it is.
    """
    nominal = float(config.georef.nominal_agl_m)
    if not all(s.focal_known for s in stills):
        return nominal, f'georef.nominal_agl_m ({nominal:g} m), a guess: {why}, and the intrinsics are unknown', True
    rel = [s.height_m for s in stills if math.isfinite(s.height_m) and s.height_m > 0.0]
    if rel:
        return (float(np.median(rel)), f'the stills\' height above take-off (XMP RelativeAltitude; median of {len(rel)} '
                f'of {len(stills)}) with their intrinsics: {why}', False)
    ground, source = float(config.georef.ground_altitude_m), 'georef.ground_altitude_m'
    summary = getattr(reader, 'summary', None)
    if not math.isfinite(ground) and summary is not None and math.isfinite(summary.ground_altitude_m):
        ground, source = float(summary.ground_altitude_m), summary.ground_altitude_source
    above = [s.altitude_m - ground for s in stills if math.isfinite(s.altitude_m - ground) and s.altitude_m > ground]
    if above:
        return (float(np.median(above)), f'the stills\' GPS altitude above the ground height {ground:.1f} m ({source}; '
                f'median of {len(above)} of {len(stills)}) with their intrinsics: {why}', False)
    return nominal, f'georef.nominal_agl_m ({nominal:g} m), a guess: {why}, and no height above the ground is known', True


def _working_K(still: SurveyStill, r: int) -> np.ndarray:
    return np.linalg.inv(_full_from_reduced(r)) @ still.K


@dataclass
class RegisteredSurvey:
    """A survey's registrations and what the metadata says, ready for the solve: pairs (normalised
    coordinates) and priors; registrations: every pair tried (i, j) -> Registration; reduction:
    each still's working JPEG reduction; more: the pairs by footprint tried; the rest for the report."""

    pairs: list[PairConstraint]
    priors: SurveyPriors
    registrations: dict[tuple[int, int], Any]
    reduction: list[int]
    more: list[tuple[int, int]]
    second_opinions: list[list[int | bool]]
    described: int
    unreadable: dict[int, str]
    scale: float
    scale_source: str
    focal_known: bool
    has_gps: bool
    georef_note: str
    register_s: float
    scale_is_guess: bool = False


def register_survey(stills: list[SurveyStill], config: PipelineConfig, *, progress: bool = True,
                    control: GroundControl | None = None, reader: ImageFolderReader | None = None) -> RegisteredSurvey:
    """Register a survey's pairs (consecutive stills, then those whose footprints overlap) and set its
    priors from the metadata (module docstring, steps 2-3). control: ground control; without GPS it
    places the chained stills (every stretch of them that sees two targets) to predict the pairs."""
    scfg = config.survey
    n = len(stills)
    reduction = [reduction_for(s.size[0], s.size[1], scfg.working_megapixels) for s in stills]
    registrar = make_registrar(config.registration, config.device)
    cache = _FeatureCache(registrar, stills, reduction, scfg.feature_cache_frames,
                          config.registration.max_features, reader)
    pos = np.array([s.position_m for s in stills])
    registrations: dict[tuple[int, int], Any] = {}
    has_second_opinion = getattr(registrar, 'has_second_opinion', False)

    def register(i: int, j: int, *, second_opinion: bool = True) -> PairConstraint | None:
        fi, fj = cache.get(i), cache.get(j)
        if fi is None or fj is None:
            return None
        if (i, j) in registrations:  # tried without a second opinion: only that is left to do
            reg = registrar.second_opinion(fi, fj, registrations[(i, j)])
        elif has_second_opinion:
            reg = registrar.register(fi, fj, second_opinion=second_opinion)
        else:
            reg = registrar.register(fi, fj)
        registrations[(i, j)] = reg
        if not reg.ok:
            return None
        wi, wj = (math.ceil(stills[i].size[0] / reduction[i]), math.ceil(stills[i].size[1] / reduction[i])), \
            (math.ceil(stills[j].size[0] / reduction[j]), math.ceil(stills[j].size[1] / reduction[j]))
        return pair_constraint(i, j, reg.prev_H_cur, reg.covariance, _working_K(stills[i], reduction[i]),
                               _working_K(stills[j], reduction[j]), wi, wj, inliers=reg.inliers,
                               model_px=scfg.model_px)

    sigma_gps = float(config.georef.gps_sigma_h_m)
    has_gps = bool(np.isfinite(pos).all(axis=1).sum() >= 3)
    georef_note = '' if has_gps else 'fewer than three stills carry a GPS position'
    if has_gps:
        known = pos[np.isfinite(pos).all(axis=1)]
        extent = float(np.sqrt(np.mean(np.sum((known - known.mean(axis=0)) ** 2, axis=1))))
        if extent < GEOTAG_MIN_EXTENT_M:
            # a hover or a pan: GNSS noise, not the flight, would set the mosaic's scale and rotation
            georef_note = (f'the stills\' GPS positions span {extent:.1f} m RMS, less than {GEOTAG_MIN_EXTENT_M:g} m: '
                           'their GNSS noise, not the flight, would set the mosaic\'s scale and rotation (a hover, '
                           'a pan)')
            has_gps = False
            pos = np.full_like(pos, np.nan)
    t_reg = time.perf_counter()
    found: dict[tuple[int, int], PairConstraint] = {}
    second_opinions: list[list[int | bool]] = []  # [i, j, registered] of the pairs given the second opinion
    bar = tqdm(total=max(n - 1, 0), unit='pair', desc='survey: consecutive pairs', disable=not progress)
    with bar:
        # With GPS, a consecutive pair the torch registrar fails (mostly a line turn, no overlap) gets
        # the OpenCV second opinion later, if its footprints overlap; without, the chain needs it now.
        for i in range(n - 1):
            c = register(i, i + 1, second_opinion=not has_gps)
            if c is not None:
                found[(i, i + 1)] = c
            bar.update(1)
    pairs = list(found.values())
    scale = estimate_scale(pairs, pos, min_baseline_m=3.0 * sigma_gps) if has_gps else math.nan
    focal_known = all(s.focal_known for s in stills)
    scale_source = 'GPS baselines over the registered displacements of consecutive stills'
    scale_is_guess = False
    if not math.isfinite(scale):
        why = ('no consecutive pair with a GPS baseline registered' if has_gps
               else 'the stills carry no usable GPS positions')
        scale, scale_source, scale_is_guess = metadata_scale(stills, config, reader, why=why)
    if scale_is_guess:
        # a warning where the GPS puts the survey on the ground at that guess; without GPS the survey is
        # not georeferenced, or ground control sets its scale
        _LOG.log(logging.WARNING if has_gps and control is None else logging.INFO,
                 'survey: the ground scale is a guess, %s; the mosaic\'s size on the ground may be wrong by the '
                 'ratio of the true height to it (set georef.nominal_agl_m, or georef.ground_altitude_m with GPS '
                 'altitudes).', scale_source)
    else:
        _LOG.info('survey: ground scale %.1f m from %s', scale, scale_source)
    # footprint on the ground at the survey's scale: width / fx x scale
    wh = np.array([[s.size[0] / s.K[0, 0] * scale, s.size[1] / s.K[1, 1] * scale] for s in stills])
    centres = pos
    if not has_gps:
        # No positions: the chain of consecutive pairs predicts the footprints (on the first
        # still's plane, in its height's units; with ground control, on the ground, each stretch of
        # the chain that sees two targets), so a line that comes back over old ground finds it.
        chain = solve_survey(n, pairs, SurveyPriors(np.full((n, 2), np.nan), np.full(n, np.nan), 1.0),
                             control=control)
        G = chain.ground_H_frame
        centres = np.array([G[k][:2, 2] / G[k][2, 2] if chain.placed_by[k] else [np.nan, np.nan] for k in range(n)])
        wh = np.array([[s.size[0] / s.K[0, 0], s.size[1] / s.K[1, 1]] for s in stills]) * np.array(
            [[math.sqrt(abs(np.linalg.det(G[k][:2, :2] / G[k][2, 2]))) if chain.placed_by[k] else np.nan]
             for k in range(n)])
    candidates = predicted_pairs(centres, wh, min_overlap=scfg.min_overlap, max_per_frame=scfg.max_pairs_per_frame)
    more = [(i, j) for i, j, _ in candidates if j != i + 1]
    bar = tqdm(total=len(more), unit='pair', desc='survey: pairs by footprint', disable=not progress)
    with bar:
        # Last stills first: the consecutive pass left their features in the cache. Without the
        # OpenCV second opinion (SIFT on both stills, then matching): a pair between lines that the
        # torch registrar fails is mostly one that SIFT fails too (caliterra: 6 of 117).
        for i, j in reversed(more):
            c = register(i, j, second_opinion=False)
            if c is not None:
                found[(i, j)] = c
            bar.update(1)
        if has_second_opinion:
            # ... except for a still that is short of pairs: its failed pairs that the footprints
            # say overlap get the second opinion
            count = collections.Counter(k for i, j in found for k in (i, j))
            for i, j, _ in candidates:
                reg = registrations.get((i, j))
                if reg is not None and not reg.ok and 'fallback_opencv' not in reg.extras \
                        and min(count[i], count[j]) < SECOND_OPINION_BELOW_PAIRS:
                    c = register(i, j)
                    second_opinions.append([i, j, c is not None])
                    if c is not None:
                        found[(i, j)] = c
                        count.update((i, j))
    # the solve sees the consecutive pairs first, then the others in (j, i) order
    pairs = [found[(i, i + 1)] for i in range(n - 1) if (i, i + 1) in found] + [found[p] for p in more if p in found]
    t_reg = time.perf_counter() - t_reg
    if n == 1:  # a still in no pair is judged (decoded) before it is placed
        cache.get(0)
    cache.cache.clear()  # the features are spent: the canvas gets the memory
    trim_heap()

    # Where each still's principal ray meets the ground: below the camera within the tilt allowance,
    # or, with gimbal angles, offset along the optical axis by the height (to within their 1 deg).
    target = pos.copy()
    sigma = np.full(n, float(np.hypot(sigma_gps, scale * math.tan(math.radians(scfg.tilt_allowance_deg)))))
    shape = {}
    att_sd = math.radians(RECORDED_ATTITUDE_SIGMA_DEG)
    for k, st in enumerate(stills):
        if st.R_enu_from_cam is None:
            continue
        axis = st.R_enu_from_cam[:, 2]
        if axis[2] >= -0.2:
            target[k] = np.nan  # looking at the horizon: its GPS position says little about its view
            continue
        height = st.height_m if math.isfinite(st.height_m) else scale
        target[k] = pos[k] - axis[:2] / axis[2] * height
        sigma[k] = float(np.hypot(sigma_gps, height * math.tan(att_sd)))
        if np.isfinite(target[k]).all() and st.focal_known:
            # the footprint's turn, scale and tilt from the attitude and the height: corner offsets of
            # about half the height, known to the attitude's sd (and the height's, 5 % when estimated)
            rel_height_sd = 0.01 if math.isfinite(st.height_m) else 0.05
            sd = 0.6 * height * float(np.hypot(att_sd * 1.5, rel_height_sd))
            shape[k] = (attitude_ground_H(st.R_enu_from_cam, target[k], height), max(sd, 0.05))
    track = np.full(n, np.nan)
    for k in range(n):
        a, b = pos[max(k - 1, 0)], pos[min(k + 1, n - 1)]
        if np.isfinite(a).all() and np.isfinite(b).all() and np.hypot(*(b - a)) >= 1.0:
            track[k] = math.atan2(b[1] - a[1], b[0] - a[0])
    priors = SurveyPriors(target, sigma, scale, track, shape)
    return RegisteredSurvey(pairs, priors, registrations, reduction, more, second_opinions, cache.described,
                            dict(cache.unreadable), scale, scale_source, focal_known, has_gps, georef_note, t_reg,
                            scale_is_guess)


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
    report, rows = _paint_and_write(out, config, stills, sol, epsg, origin, progress=progress,
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


def _paint_and_write(out: Path, config: PipelineConfig, stills: list[SurveyStill], sol: Any, epsg: int,
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
                                [_footprint_px(corners[k], raster_H_local) for k in placed], tile_bytes)
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
                    canvas.paint(image, H @ _full_from_reduced(r), scale=gains[i],
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
