"""A survey's stills and what their metadata says, at the working resolution (`process FOLDER`, steps 1-2).

Each still's GPS position, intrinsics and attitude (io/image_folder.py), its decoding reduced by JPEG
DCT scaling to the working resolution (:func:`read_reduced`), and the survey's scale from the
metadata where no GPS baseline gives it (:func:`metadata_scale`).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from ..config import PipelineConfig
from ..core.georef.frames import R_enu_from_cam_aviation
from ..core.georef.georeferencer import utm_epsg
from ..core.georef.geotag_fit import geotags_at
from ..core.image_decode import decode_file
from ..io.image_folder import ImageFolderReader
from .survey_still import SurveyStill

__all__ = ['full_from_reduced', 'metadata_scale', 'NOMINAL_FOCAL_PER_SIDE', 'read_reduced', 'reduction_for', 'survey_stills', 'working_K']

_REDUCED = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4,
            8: cv2.IMREAD_REDUCED_COLOR_8}
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


def full_from_reduced(r: int) -> np.ndarray:
    """(3, 3) pixel of an image reduced by r -> pixel of the full image (pixel centres at integers)."""
    return np.array([[r, 0.0, (r - 1) / 2.0], [0.0, r, (r - 1) / 2.0], [0.0, 0.0, 1.0]])


def working_K(still: SurveyStill, r: int) -> np.ndarray:
    return np.linalg.inv(full_from_reduced(r)) @ still.K


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
