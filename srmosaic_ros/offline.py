"""`srmosaic process`: run the pipeline over a recorded flight and write the file contracts."""
from __future__ import annotations

import collections
import errno
import json
import logging
import math
import os
import shutil
import time
from pathlib import Path
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from .checkpoint import Checkpoint, checkpoint_path, fingerprint, load_checkpoint, save_checkpoint
from .config import PipelineConfig
from .io.bags import TopicConfig, read_flight
from .io.metadata import merge_by_time
from .io.prefetch import prefetched
from .io.mosaic_files import write_frames_csv, write_json, write_png
from .io.outputs import StripPreview, peak_rss_mb, write_canvas
from .errors import InputError, OutputError, SrMosaicError
from .io.mosaic_video import MosaicVideoRecorder
from .pipeline import Pipeline, PipelineResult
from .core.georef.geotag_fit import GEOTAG_MIN_EXTENT_M
from .core.device import cores_left_for_torch
from .core.image_ops import to_float01
from .core.stage_clock import StageClock
from .core.types import Frame

if TYPE_CHECKING:
    from .core.georef import GeoRaster

_LOG = logging.getLogger(__name__)

#: Offline re-anchoring fits frame corners unless the height above ground is known worse than this
#: (relative standard deviation, median over the frames): then the frame centres only.
ANCHOR_CORNERS_MAX_REL_AGL_SD = 0.02
#: The fit of a mosaic to its geotags needs them to span GEOTAG_MIN_EXTENT_M (geotag_fit.py) ...
#: ... and fits only the offset when the similarity's rotation is known worse than the poses' heading,
#: and than this (deg).
ANCHOR_MIN_ROTATION_SD_DEG = 0.5

__all__ = ['open_source', 'process_input', 'write_outputs']


def _translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


#: Input items read ahead by a background thread while the pipeline works (io/prefetch.py).
READ_AHEAD = 8

def write_outputs(result: PipelineResult, out: Path, config: PipelineConfig, extra: dict[str, Any], *,
                  meta_centres: dict[int, tuple[float, float]] | None = None) -> dict[str, Any]:
    """Write mosaic.png (main canvas), preview.png, segments/, frames.csv, and with georeferencing
    mosaic.tif, mosaic.kml and poses.csv. Returns the report (the caller adds timings and writes it).
    ``meta_centres``: stamp_ns -> (lat, lon) where the input's metadata puts each frame's centre
    (frames.csv's meta_latitude, meta_longitude).

    The mosaics are rendered and written strip by strip (see _write_canvas): memory does not grow
    with the mosaic's area.
    """
    out.mkdir(parents=True, exist_ok=True)
    main = result.main_segment
    main_canvas = main.canvas if main is not None else None
    mosaic_H_seg = np.eye(3)
    segments_report = []
    written: dict[int, str] = {}  # id(canvas) -> file
    geo: dict[str, Any] = {}
    for seg in result.segments:
        x0, y0, x1, y1 = seg.canvas.bounds()
        if id(seg.canvas) not in written:
            if seg.canvas is main_canvas:
                mosaic_H_seg = _translation(-x0, -y0)
                geo = _write_main_mosaic(out, result, config, (x0, y0, x1, y1))
                written[id(seg.canvas)] = 'mosaic.png'
            elif len(seg.frames) >= 2:
                written[id(seg.canvas)] = f'segments/segment_{seg.index:03d}.png'
                write_canvas(seg.canvas, None, out / written[id(seg.canvas)])
        segments_report.append({'index': seg.index, 'frames': len(seg.frames), 'file': written.get(id(seg.canvas), ''),
                                'georeferenced': seg.georeferenced,
                                'size_px': [int(x1 - x0), int(y1 - y0)], 'origin_px': [int(x0), int(y0)]})
    main_segments = {seg.index for seg in result.segments if seg.canvas is main_canvas}
    rows = []
    for rec in result.records:
        in_main = rec.segment in main_segments
        reg = rec.registration
        rows.append({
            'stamp_ns': rec.stamp_ns,
            'ok': in_main,
            'inliers': reg.inliers if reg is not None else 0,
            'rms_px': reg.rms_px if reg is not None else float('nan'),
            'mosaic_H_frame': mosaic_H_seg @ rec.seg_H_frame if in_main else None,
            'meta_latlon': (meta_centres or {}).get(rec.stamp_ns),
        })
    write_frames_csv(out / 'frames.csv', rows)
    failures = collections.Counter(rec.reason.split(' (')[0] for rec in result.records if not rec.painted)
    regs = [rec.registration for rec in result.records if rec.registration is not None and rec.registration.ok]
    report = {
        'frames_in': len(result.records),
        'frames_registered': int(sum(r['ok'] for r in rows)),
        'frames_painted_any_segment': int(sum(rec.painted for rec in result.records)),
        'segments': segments_report,
        'failure_reasons': dict(failures),
        'registration': {
            'median_inliers': float(np.median([r.inliers for r in regs])) if regs else None,
            'median_rms_px': float(np.median([r.rms_px for r in regs])) if regs else None,
            'median_ms': float(np.median([r.time_s for r in regs]) * 1e3) if regs else None,
        },
        'telemetry': {'fixes': len(result.fixes), 'imu': len(result.imus)},
        'georeferenced': geo or None,
        'config': {'device': config.device, 'registration': vars(config.registration), 'mosaic': vars(config.mosaic)},
    }
    report.update(extra)
    return report


def open_source(path: Path, *, topics: TopicConfig | None = None, select: str = 'all',
                camera_yaml: Path | None = None, hfov_deg: float | None = None,
                telemetry_csv: Path | None = None, stamp_tolerance_s: float = 10.0) -> tuple[Iterable[Any], Any, str]:
    """(items in time order, the reader (frame_count, skipped, summary), 'bag', 'video' or 'images')
    for a bag, a video file or a folder of stills.

    The metadata the input carries is read and merged (io/metadata.py): a folder's EXIF/XMP; a
    video's MISB KLV stream, a DJI .SRT beside it or a GoPro GPMF track, in that order, unless
    ``telemetry_csv`` is given (it overrides them). ``reader.summary`` says what was found. A bag's
    messages stamped more than ``stamp_tolerance_s`` off their topic's clock are skipped and counted.
    """
    from .io.image_folder import ImageFolderReader, is_image_folder
    from .io.metadata import MetadataSummary
    from .io.video import VideoReader, is_video, load_camera_yaml, parse_selection

    if is_image_folder(path):
        if select != 'all' or camera_yaml or hfov_deg or telemetry_csv:
            msg = ('--select, --camera, --hfov and --telemetry apply to video input; a folder of stills takes its '
                   'stamps, geotags and camera from each image\'s EXIF/XMP (or a telemetry_from_exif.csv beside the '
                   'images).')
            raise InputError(msg)
        reader = ImageFolderReader(path)
        return reader, reader, 'images'
    if is_video(path):
        camera = load_camera_yaml(camera_yaml) if camera_yaml else None
        reader = VideoReader(path, selection=parse_selection(select), camera=camera, hfov_deg=hfov_deg)
        items: Iterable[Any] = reader
        if telemetry_csv is not None:
            from .io.telemetry_csv import read_telemetry_csv

            items = merge_by_time(reader, read_telemetry_csv(telemetry_csv))
            reader.summary = MetadataSummary(source='telemetry CSV', fields=['gps position', 'attitude'])
            return items, reader, 'video'
        return _video_with_metadata(path, reader)
    if select != 'all' or camera_yaml or hfov_deg or telemetry_csv:
        msg = ('--select, --camera, --hfov and --telemetry apply to video input; a bag carries its own camera '
               'info and telemetry topics.')
        raise InputError(msg)
    reader = read_flight(path, topics=topics or TopicConfig(), stamp_tolerance_s=stamp_tolerance_s)
    reader.summary = MetadataSummary(source='bag topics')
    return reader, reader, 'bag'


def _video_with_metadata(path: Path, reader: Any) -> tuple[Iterable[Any], Any, str]:
    """A video's own metadata, found in order: MISB KLV stream, DJI SRT beside it, GoPro GPMF track."""
    from .io.dji_srt import find_srt, read_srt
    from .io.gpmf import read_gpmf
    from .io.klv import read_klv
    from .io.metadata import KlvVideoSource, MetadataSummary, gpmf_items, srt_items
    from .errors import MetadataError

    track = read_klv(path)
    if track.records:
        source = KlvVideoSource(reader, track)
        return source, source, 'video'
    summary = MetadataSummary(frames=reader.frame_count or 0)
    srt = find_srt(path)
    if srt is not None:
        try:
            items = srt_items(read_srt(srt), summary)
        except MetadataError as exc:
            _LOG.warning('%s; the video is processed without its telemetry.', exc)
            summary.problems['srt_unusable'] += 1
        else:
            reader.summary = summary
            return merge_by_time(reader, items), reader, 'video'
    gpmf = read_gpmf(path)
    if gpmf.gps:
        items = gpmf_items(gpmf, summary)
        reader.summary = summary
        return merge_by_time(reader, items), reader, 'video'
    if track.packets:
        summary.note(f'{track.packets} KLV packets, none usable')
    reader.summary = summary
    return reader, reader, 'video'


def _write_main_mosaic(out: Path, result: PipelineResult, config: PipelineConfig,
                       bounds: tuple[int, int, int, int]) -> dict[str, Any]:
    """mosaic.png and preview.png of the main segment's canvas, and with georeferencing mosaic.tif
    (same pixel grid as mosaic.png), mosaic.kml and poses.csv. Returns the report's 'georeferenced'
    entry ({} without georeferencing)."""
    main = result.main_segment
    canvas = main.canvas
    x0, y0, x1, y1 = bounds
    preview = StripPreview(y1 - y0, x1 - x0, canvas.channels, config.mosaic.preview_max_side_px)
    georef = result.georef
    from .io.kml import write_kml_for_raster

    if not (main.georeferenced and georef is not None and georef.raster is not None):
        fit = _geotag_fit(result, (x0, y0), config) if config.georef_enabled else None
        write_canvas(canvas, out / 'mosaic.tif' if fit else None, out / 'mosaic.png', fit.raster if fit else None,
                      preview)
        write_png(out / 'preview.png', preview.image())
        if fit is None:
            return {}
        write_kml_for_raster(out / 'mosaic.kml', 'mosaic.png', fit.raster, x1 - x0, y1 - y0)
        return {'epsg': fit.raster.epsg, 'gsd_m_per_px': fit.raster.gsd_m_per_px,
                'geotransform': list(fit.raster.geotransform), **fit.figures()}
    from .io.poses_csv import write_poses_csv

    poses = georef.smoothed_poses()
    raster, anchoring = _mosaic_raster(result, poses, (x0, y0))
    write_canvas(canvas, out / 'mosaic.tif', out / 'mosaic.png', raster, preview)
    write_png(out / 'preview.png', preview.image())
    write_kml_for_raster(out / 'mosaic.kml', 'mosaic.png', raster, x1 - x0, y1 - y0)
    write_poses_csv(out / 'poses.csv', poses)
    return {'method': 'filter', 'epsg': raster.epsg, 'gsd_m_per_px': raster.gsd_m_per_px,
            'geotransform': list(raster.geotransform), **anchoring, 'poses': len(poses),
            'skipped_telemetry': dict(georef.skipped)}


def _mosaic_raster(result: PipelineResult, poses: list[Any], origin: tuple[int, int]) -> tuple[GeoRaster, dict[str, Any]]:
    """(GeoRaster of mosaic.png's pixel (0, 0), the anchoring figures) from the smoothed poses.

    The mosaic plane was anchored by the first frame's (early, filtered) pose. With the smoothed
    poses of every frame, re-anchor it (core/georef/anchoring.py): the least-squares similarity
    between each frame's chained corners and its pose-predicted corners (offset, rotation and
    scale, estimated from the whole flight) goes into the geotransform. The mosaic's pixels do
    not move: mosaic.png and mosaic.tif stay one grid.
    """
    from .core.georef.anchoring import fit_similarity
    from .core.metrics import apply_homography

    georef = result.georef
    chained, by_poses = [], []
    main_canvas = result.main_segment.canvas
    seg_of = {seg.index: seg for seg in result.segments}
    # A pose-predicted footprint is as large as its height above the ground says. Where the filter
    # never learnt the ground (registrations not fused: stills further apart than georef.max_step_s,
    # the nominal AGL prior left at +-30 m), the corners would carry that error into the scale
    # (stills 2 s apart: 2.7 m RMS); the frame centres do not depend on it (1.5 m).
    rel_sd = [math.sqrt(max(float(p.ground_covariance[-1]), 0.0)) / max(p.camera.center_enu_m[2] - p.ground_z_m, 1.0)
              for p in poses if p.valid and p.ground_covariance is not None and p.camera is not None]
    centres_only = bool(rel_sd) and float(np.median(rel_sd)) > ANCHOR_CORNERS_MAX_REL_AGL_SD
    by_stamp = {p.stamp_ns: p for p in poses}  # records and poses need not align one to one
    for rec in result.records:
        seg, pose = seg_of.get(rec.segment), by_stamp.get(rec.stamp_ns)
        if seg is None or seg.canvas is not main_canvas or pose is None or not pose.valid or rec.seg_H_frame is None:
            continue
        w_f, h_f = rec.size
        corners = np.array([[0, 0], [w_f - 1, 0], [w_f - 1, h_f - 1], [0, h_f - 1]], dtype=float)
        if centres_only:
            corners = np.array([[(w_f - 1) / 2.0, (h_f - 1) / 2.0]])
        by_poses.append(apply_homography(georef.raster_H_frame(pose), corners))
        chained.append(apply_homography(rec.seg_H_frame, corners))
    translation_only = False
    if chained:
        src, dst = np.concatenate(chained), np.concatenate(by_poses)
        # raster pixel by the poses ~ fix @ chained raster pixel
        fix = fit_similarity(src, dst)
        # Points that stay within their own noise of each other (a stare at a site from kilometres)
        # cannot tell a rotation or a scale: the fit's angle is uncertain by about residual /
        # (spread sqrt(n)) rad; when that is worse than the poses' own heading (their yaw std, median),
        # the fit would add error, and only the offset is re-anchored.
        residual = float(np.sqrt(np.mean(np.sum((apply_homography(fix, src) - dst) ** 2, axis=1))))
        spread = float(np.sqrt(np.mean(np.sum((src - src.mean(axis=0)) ** 2, axis=1))))
        rotation_sd = residual / max(spread * math.sqrt(len(src)), 1e-9)
        yaw_sd = [float(p.std_rpy_rad[2]) for p in poses if p.valid]
        translation_only = bool(yaw_sd) and rotation_sd > max(float(np.median(yaw_sd)),
                                                              math.radians(ANCHOR_MIN_ROTATION_SD_DEG))
        if translation_only:
            fix = np.eye(3)
            fix[:2, 2] = (dst - src).mean(axis=0)
    else:
        fix = np.eye(3)
    # mosaic pixel m is chained raster pixel m + origin, truly at raster pixel fix @ (m + origin).
    raster = georef.raster.transformed(fix).shifted(origin[0], origin[1])
    figures = {'anchor_shift_px': [float(fix[0, 2]), float(fix[1, 2])],
               'anchor_scale': float(np.hypot(fix[0, 0], fix[1, 0])),
               'anchor_rotation_deg': float(np.degrees(np.arctan2(fix[1, 0], fix[0, 0]))),
               'anchor_frames': len(chained), 'anchor_points': 'centres' if centres_only else 'corners',
               'anchor_model': 'translation' if translation_only else 'similarity'}
    return raster, figures


def _ground_offsets(result: PipelineResult, stamps_ns: np.ndarray, config: PipelineConfig,
                    max_gap_s: float = 0.5) -> np.ndarray:
    """(M, 2) east, north offset per metre of height of where each frame's optical axis meets the
    ground (-r_xy / r_z), from the Imu orientation nearest its stamp (within max_gap_s) and the
    camera mount (georef.gimbal_*); NaN without an orientation or for an axis near the horizon."""
    from .core.georef.frames import R_body_from_cam, matrix_from_quat_xyzw

    imus = [i for i in result.imus if i.orientation_xyzw is not None]
    out = np.full((len(stamps_ns), 2), np.nan)
    if not imus:
        return out
    t = np.array([i.stamp_ns for i in imus], dtype=np.int64)
    order = np.argsort(t)
    t = t[order]
    mount = config.georef.mount
    R_bc = R_body_from_cam(mount.gimbal_azimuth_rad, mount.gimbal_elevation_rad)
    for k, stamp in enumerate(stamps_ns):
        j = int(np.clip(np.searchsorted(t, stamp), 1, len(t) - 1)) if len(t) > 1 else 0
        j = j - 1 if len(t) > 1 and abs(t[j - 1] - stamp) < abs(t[j] - stamp) else j
        if abs(int(t[j]) - int(stamp)) > max_gap_s * 1e9:
            continue
        axis = matrix_from_quat_xyzw(np.asarray(imus[order[j]].orientation_xyzw)) @ R_bc @ np.array([0.0, 0.0, 1.0])
        if axis[2] < -0.2:  # looking down, not near the horizon
            out[k] = -axis[:2] / axis[2]
    return out


def _geotag_fit(result: PipelineResult, origin: tuple[int, int], config: PipelineConfig) -> Any:
    """GeotagFit of mosaic.png's grid (pixel (0, 0) = canvas pixel ``origin``) from the frames of the
    main canvas and the fixes at their stamps (core/georef/geotag_fit.py), or None (with the reason
    logged) when there are no fixes or they cannot place the mosaic."""
    from .core.georef.geotag_fit import fit_mosaic_to_geotags, geotags_at
    from .core.metrics import apply_homography

    fixes = [f for f in result.fixes if f.status >= 0]
    if not fixes:
        return None
    main_canvas = result.main_segment.canvas
    on_main = {seg.index for seg in result.segments if seg.canvas is main_canvas}
    recs = [r for r in result.records if r.segment in on_main and r.painted and r.seg_H_frame is not None]
    centres = np.array([apply_homography(r.seg_H_frame, np.array([[(r.size[0] - 1) / 2.0, (r.size[1] - 1) / 2.0]]))[0]
                        for r in recs]).reshape(-1, 2) - np.asarray(origin, dtype=np.float64)
    fixes.sort(key=lambda f: f.stamp_ns)
    tags = geotags_at(np.array([f.stamp_ns for f in fixes]), np.array([[f.longitude_deg, f.latitude_deg] for f in fixes]),
                      np.array([r.stamp_ns for r in recs], dtype=np.int64))
    offsets = _ground_offsets(result, np.array([r.stamp_ns for r in recs], dtype=np.int64), config) \
        if result.imus else None
    try:
        fit = fit_mosaic_to_geotags(centres, tags, offsets)
        if fit.extent_m < GEOTAG_MIN_EXTENT_M:
            msg = (f'the geotags of the main mosaic span {fit.extent_m:.1f} m RMS, less than {GEOTAG_MIN_EXTENT_M:g} m: '
                   'their GNSS noise, not the flight, would set its scale and rotation (a hover, a pan)')
            raise ValueError(msg)
    except ValueError as exc:
        _LOG.warning('the mosaic is not georeferenced: the filter did not place it (no camera intrinsics, or no fix '
                     'before its first frame) and its geotags cannot: %s', exc)
        result.georef_note = f'its geotags cannot place it: {exc}'
        return None
    _LOG.info('mosaic not placed by the filter: georeferenced by its %d geotagged frames (residual RMS %.2f m, '
              '%d left out, tilt %s)', int(fit.used.sum()), fit.rms_m, int((~fit.used).sum()),
              'corrected' if fit.height_m is not None else 'not corrected')
    return fit


#: What `process` writes into --out (and report.json); an earlier run's copy that this run did not write is removed.
RUN_OUTPUTS = ('mosaic.png', 'preview.png', 'mosaic.tif', 'mosaic.kml', 'poses.csv', 'frames.csv', 'mosaic.mp4',
               'segments', 'sr')


class OutputTransaction:
    """A run's outputs written into ``out``/.staging-PID and moved into ``out`` when the run ends.

    Entering takes ``out``/.srmosaic.lock (fcntl.flock): a second writer is refused with the other's
    pid. On a normal exit each of RUN_OUTPUTS and report.json is moved in (os.replace, report.json
    last); those that this run did not write are removed from ``out`` (``removed``). When the run
    raises with outputs in the staging folder (a damaged input: what was processed so far), they are
    moved in the same way unless ``out`` holds an earlier complete run (a report.json without an
    error): then they go to ``out``/failed_run/ and the earlier run stays. Files of other programs in
    ``out`` are never touched.
    """

    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        self.stage = self.out / f'.staging-{os.getpid()}'
        self.removed: list[str] = []
        self._lock: Any = None

    def __enter__(self) -> OutputTransaction:
        import fcntl

        self._lock = open(self.out / '.srmosaic.lock', 'a+')  # held for the run
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lock.seek(0)
            other = self._lock.read().strip() or 'unknown'
            self._lock.close()
            msg = (f'another srmosaic process (pid {other}) is writing {self.out}; wait for it to end or give '
                   'another --out.')
            raise OutputError(msg) from None
        self._lock.seek(0)
        self._lock.truncate()
        self._lock.write(str(os.getpid()))
        self._lock.flush()
        for left in self.out.glob('.staging-*'):  # of a run killed (kill -9): the lock says none is writing
            shutil.rmtree(left, ignore_errors=True)
        self.stage.mkdir()
        return self

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: Any) -> None:
        try:
            if exc_type is None:
                self.removed = self._publish(self.out)
            elif isinstance(exc, SrMosaicError) and (self.stage / 'report.json').is_file():
                if self._earlier_complete_run():
                    failed = self.out / 'failed_run'
                    shutil.rmtree(failed, ignore_errors=True)
                    failed.mkdir()
                    self._publish(failed)
                    _LOG.warning('the earlier complete run in %s is kept; this run\'s partial outputs are in %s',
                                 self.out, failed)
                else:
                    self.removed = self._publish(self.out)
        finally:
            shutil.rmtree(self.stage, ignore_errors=True)
            (self.out / '.srmosaic.lock').unlink(missing_ok=True)  # still held: no other writer is inside
            self._lock.close()

    def _earlier_complete_run(self) -> bool:
        try:
            return 'error' not in json.loads((self.out / 'report.json').read_text())
        except (OSError, ValueError):
            return False

    def _publish(self, dst: Path) -> list[str]:
        """Move the staged outputs into ``dst``; remove there what this run did not write."""
        removed = []
        for name in (*RUN_OUTPUTS, 'report.json'):
            src, target = self.stage / name, dst / name
            if src.exists():
                if target.is_dir() and not target.is_symlink():
                    old = self.stage / f'.old-{name}'
                    os.replace(target, old)
                os.replace(src, target)
            elif target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
                removed.append(name)
            elif target.exists():
                target.unlink()
                removed.append(name)
        if removed:
            _LOG.info('removed the outputs of an earlier run that this one did not write: %s', ', '.join(removed))
        return removed


def skipped_kinds(skipped: dict[str, int]) -> dict[str, int]:
    """The readers' skipped counts per kind: keys 'topic: reason' stay, a folder's 'file: reason'
    become 'reason' (one line per kind, not one per still)."""
    out: dict[str, int] = {}
    for key, count in skipped.items():
        head, _, reason = key.partition(': ')
        what = key if head.startswith('/') or not reason else reason
        out[what] = out.get(what, 0) + count
    return out


def check_output_dir(out: Path, what: str = '--out') -> None:
    """Make sure ``out`` can take a run's files before any work is done: it is (or is created as) a
    directory one can write into. Raises OutputError naming the problem and the way out."""
    import tempfile

    out = Path(out)
    too_long = [part for part in out.parts if len(os.fsencode(part)) > 255]
    if too_long:
        msg = f'{what} {out}: the name {too_long[0][:40]}... is longer than 255 bytes; give a shorter directory name.'
        raise OutputError(msg)
    if out.exists() and not out.is_dir():
        msg = f'{what} {out} is a file, not a directory; give a directory (it is created if missing).'
        raise OutputError(msg)
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        msg = f'{what} {out} lies under {parent}, which is a file; give a directory elsewhere.'
        raise OutputError(msg)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix='.write-test.', dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        msg = f'{what} {out} cannot be written ({exc.strerror or exc}); give a directory you may write to.'
        raise OutputError(msg) from None


def process_input(path: Path, out: Path, config: PipelineConfig, *, topics: TopicConfig | None = None,
                  select: str = 'all', camera_yaml: Path | None = None, hfov_deg: float | None = None,
                  telemetry_csv: Path | None = None, mosaic_video: bool = False,
                  checkpoint_every: int = 0, resume: bool = False, sr_factor: int | None = None,
                  progress: bool = True, overlap: bool = True) -> dict[str, Any]:
    """Run the pipeline over a bag, a video or a folder of stills and write the outputs into ``out``;
    returns the report (also in report.json).

    The run is written into a staging folder inside ``out`` and moved in when it ends
    (OutputTransaction): ``out`` holds one run's outputs, never a mix, and a second process writing
    the same ``out`` is refused. If the input breaks mid-way (a damaged bag or video, a frame size
    change), everything processed so far is written, the report records the error, and the error is
    raised again so the command exits non-zero; over an earlier complete run, those partial outputs go
    to ``out``/failed_run/ instead, the earlier run staying in place. With checkpoint_every > 0 the
    state is checkpointed every that many frames (see checkpoint.py); resume=True continues from the
    last checkpoint in ``out``. overlap: read the input ahead and paint on a background thread while
    the next frames are registered (the outputs are those of the sequential run, overlap=False).
    """
    t0 = time.perf_counter()
    if checkpoint_every < 0:
        msg = f'--checkpoint-every must be >= 0, got {checkpoint_every}.'
        raise InputError(msg)
    items, reader, kind = open_source(path, topics=topics, select=select, camera_yaml=camera_yaml,
                                      hfov_deg=hfov_deg, telemetry_csv=telemetry_csv,
                                      stamp_tolerance_s=config.stamp_tolerance_s)
    check_output_dir(out)  # before the work, not after it
    with OutputTransaction(out) as transaction:
        try:
            report = _process(path, out, transaction.stage, config, items, reader, kind, t0, topics=topics,
                              select=select, camera_yaml=camera_yaml, hfov_deg=hfov_deg, telemetry_csv=telemetry_csv,
                              mosaic_video=mosaic_video, checkpoint_every=checkpoint_every, resume=resume,
                              sr_factor=sr_factor, progress=progress, overlap=overlap)
        except OSError as exc:
            if exc.errno not in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
                raise
            msg = (f'{out}: an output could not be written ({exc.strerror}); free space, or give --out elsewhere '
                   '(the earlier run there is untouched).')
            raise OutputError(msg) from None
    report['stale_outputs_removed'] = transaction.removed
    return report


def _process(path: Path, out: Path, stage: Path, config: PipelineConfig, items: Iterable[Any], reader: Any,
             kind: str, t0: float, *, topics: TopicConfig | None, select: str, camera_yaml: Path | None,
             hfov_deg: float | None, telemetry_csv: Path | None, mosaic_video: bool, checkpoint_every: int,
             resume: bool, sr_factor: int | None, progress: bool, overlap: bool) -> dict[str, Any]:
    """process_input's work: outputs into ``stage``, checkpoints into ``out``."""
    summary = getattr(reader, 'summary', None)
    if kind == 'images':
        from .survey import use_global_alignment

        if use_global_alignment(reader, config):
            if resume or mosaic_video:
                msg = ('--resume and --mosaic-video apply to the chained pipeline; a survey aligned globally runs in '
                       'one pass (no checkpoints). Drop them, or set survey.mode: chain.')
                raise InputError(msg)
            return _process_survey(path, stage, config, reader, t0, sr_factor=sr_factor, progress=progress)
    config = _with_ground_hint(config, summary)
    settings = {'select': select, 'topics': repr(topics), 'config': repr(config), 'mosaic_video': mosaic_video,
                'camera': str(camera_yaml), 'hfov': hfov_deg, 'telemetry': str(telemetry_csv)}
    run_id = fingerprint(path, settings)
    pipeline = Pipeline(config, paint_thread=overlap)
    recorder = MosaicVideoRecorder() if mosaic_video else None
    recent: dict[int, np.ndarray] = {}
    skip_items = frames_done = 0
    if resume:
        state = load_checkpoint(out, run_id)
        pipeline, recorder = state.pipeline, state.recorder
        if overlap:
            pipeline.start_paint_thread()
        recent = state.recent or {}
        skip_items, frames_done = state.items_consumed, state.frames_consumed
    bar = tqdm(total=reader.frame_count, initial=frames_done, unit='frame', desc='process', disable=not progress)
    error: SrMosaicError | None = None
    consumed = 0
    clock = pipeline.clock
    with bar, cores_left_for_torch(1 if overlap else 0):  # one core is the painter's (Pipeline paint_thread)
        try:
            for item in _timed(prefetched(items, READ_AHEAD if overlap else 0), clock):
                consumed += 1
                if consumed <= skip_items:  # already in the checkpointed state
                    continue
                records = pipeline.feed(item)
                if isinstance(item, Frame):
                    clock.end_frame()
                    frames_done += 1
                    bar.update(1)
                    bar.set_postfix(segments=len(pipeline.segments), refresh=False)
                    if recorder is not None:
                        recent[item.stamp_ns] = item.image
                        while len(recent) > pipeline.max_decision_lag_frames:  # frames are decided at most this late
                            recent.pop(next(iter(recent)))
                if recorder is not None:
                    for rec in records:
                        if rec.painted and rec.stamp_ns in recent:
                            recorder.add(rec.segment, to_float01(recent[rec.stamp_ns]), rec.seg_H_frame)
                if checkpoint_every and isinstance(item, Frame) and frames_done % checkpoint_every == 0:
                    with clock.stage('outputs'):
                        save_checkpoint(out, Checkpoint(run_id, consumed, frames_done, pipeline, recorder, recent))
        except SrMosaicError as exc:
            error = exc
    if recorder is not None and error is None:
        for rec in pipeline.flush():  # the last frames, held for telemetry that never came
            if rec.painted and rec.stamp_ns in recent:
                recorder.add(rec.segment, to_float01(recent[rec.stamp_ns]), rec.seg_H_frame)
    result = pipeline.finish()
    kinds = skipped_kinds(dict(getattr(reader, 'skipped', {})))
    for what, count in kinds.items():
        _LOG.warning('%d message(s) left out: %s', count, what)
    if error is None and not result.records:
        said = '; '.join(f'{count} x {what}' for what, count in kinds.items()) or 'no image messages or files at all'
        msg = (f'no usable image in {path} ({said}); nothing was written. Check the image topic or files '
               '(srmosaic inspect INPUT says what the input holds).')
        raise InputError(msg)
    report_extra: dict[str, Any] = {'input': str(path), 'input_kind': kind,
                                    'skipped_messages': dict(getattr(reader, 'skipped', {}))}
    if getattr(reader, 'adjusted', None):  # CameraInfo scaled to images of another size (io/bags.py)
        report_extra['adjusted_messages'] = dict(reader.adjusted)
    if summary is not None:
        report_extra['metadata'] = _metadata_report(summary, result)
    if kind == 'video':
        report_extra['video'] = {'codec': reader.codec, 'fps': reader.fps, 'frames_decoded': reader.decoded,
                                 'frames_selected': reader.selected, 'select': select}
        if getattr(reader, 'ended_early', ''):
            report_extra['video']['ended_early'] = reader.ended_early
    if error is not None:
        report_extra['error'] = str(error)
    with clock.stage('outputs'):
        report = write_outputs(result, stage, config, report_extra,
                               meta_centres=summary.centres if summary is not None else None)
    if report.get('georeferenced') is None:
        report['not_georeferenced_reason'] = not_georeferenced_reason(result, config,
                                                                      dict(getattr(reader, 'skipped', {})))
        _LOG.warning('the mosaic is not georeferenced: %s', report['not_georeferenced_reason'])
    if recorder is not None and result.main_segment is not None:
        main = result.main_segment
        report['mosaic_video_frames'] = recorder.write(stage / 'mosaic.mp4', main.index, main.canvas.bounds())
    wall = time.perf_counter() - t0
    report['wall_s'] = round(wall, 3)
    report['frames_per_s'] = round(len(result.records) / wall, 2) if wall > 0 else None
    report['stage_times'] = clock.summary()
    report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    if resume:
        report['resumed_after_frames'] = skip_frames_note(skip_items, frames_done)
    if sr_factor is not None and error is None and result.main_segment is not None:
        from .sr_offline import super_resolve_mosaic

        t_sr = time.perf_counter()
        again, _, _ = open_source(path, topics=topics, select=select, camera_yaml=camera_yaml, hfov_deg=hfov_deg,
                                  telemetry_csv=telemetry_csv, stamp_tolerance_s=config.stamp_tolerance_s)
        report['sr'] = super_resolve_mosaic(stage, again, config, factor=sr_factor, progress=progress)
        report['sr']['wall_s'] = round(time.perf_counter() - t_sr, 3)
        report['wall_s'] = round(time.perf_counter() - t0, 3)
        report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    write_json(stage / 'report.json', report)
    if error is not None:
        raise error
    shutil.rmtree(checkpoint_path(out).parent, ignore_errors=True)  # complete: the checkpoint is spent
    return report


def _timed(items: Iterable[Any], clock: StageClock) -> Iterator[Any]:
    """The items, the time spent reading and decoding each counted to the clock's 'decode' stage."""
    it = iter(items)
    while True:
        t0 = time.perf_counter()
        try:
            item = next(it)
        except StopIteration:
            return
        finally:
            clock.add('decode', time.perf_counter() - t0)
        yield item


def _process_survey(path: Path, out: Path, config: PipelineConfig, reader: Any, t0: float, *,
                    sr_factor: int | None, progress: bool) -> dict[str, Any]:
    """A folder of stills aligned globally (survey.py), with the report and SR as process_input's."""
    from .survey import process_survey

    report = process_survey(path, out, config, reader, progress=progress)
    report = {'input': str(path), 'input_kind': 'images', 'skipped_messages': dict(reader.skipped), **report}
    report['metadata'] = reader.summary.to_dict()
    if report.get('georeferenced') is None:
        report.setdefault('not_georeferenced_reason', 'the stills carry no GPS positions (EXIF GPS or '
                          'telemetry_from_exif.csv): the survey is aligned on the first still\'s plane only.')
        _LOG.warning('the mosaic is not georeferenced: %s', report['not_georeferenced_reason'])
    report['config'] = {'device': config.device, 'registration': vars(config.registration),
                        'mosaic': vars(config.mosaic),
                        'survey': {k: (None if isinstance(v, float) and math.isnan(v) else v)
                                   for k, v in vars(config.survey).items()}}
    wall = time.perf_counter() - t0
    report['wall_s'] = round(wall, 3)
    report['frames_per_s'] = round(report['frames_in'] / wall, 2) if wall > 0 else None
    report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    if sr_factor is not None:
        from .sr_offline import super_resolve_mosaic

        t_sr = time.perf_counter()
        again, _, _ = open_source(path)
        report['sr'] = super_resolve_mosaic(out, again, config, factor=sr_factor, progress=progress)
        report['sr']['wall_s'] = round(time.perf_counter() - t_sr, 3)
        report['wall_s'] = round(time.perf_counter() - t0, 3)
        report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    write_json(out / 'report.json', report)
    return report


def _with_ground_hint(config: PipelineConfig, summary: Any) -> PipelineConfig:
    """The ground height the metadata implies (KLV frame centre elevation, a DJI take-off altitude)
    as the filter's prior, unless georef.ground_altitude_m is set."""
    import dataclasses

    if summary is None or not math.isfinite(summary.ground_altitude_m) or math.isfinite(config.georef.ground_altitude_m):
        return config
    _LOG.info('ground altitude %.1f m (+- %.0f m) from %s', summary.ground_altitude_m, summary.ground_altitude_sigma_m,
              summary.ground_altitude_source)
    georef = dataclasses.replace(config.georef, ground_altitude_m=summary.ground_altitude_m,
                                 ground_altitude_sigma_m=summary.ground_altitude_sigma_m)
    return dataclasses.replace(config, georef=georef)


def _covered(stamps: np.ndarray, frames_ns: np.ndarray, within_ns: int = 1_000_000_000) -> int:
    """How many frame stamps have a telemetry stamp within ``within_ns``."""
    if not len(stamps) or not len(frames_ns):
        return 0
    stamps = np.sort(stamps)
    i = np.clip(np.searchsorted(stamps, frames_ns), 1, len(stamps) - 1) if len(stamps) > 1 else np.zeros(len(frames_ns), int)
    d = np.minimum(np.abs(stamps[i] - frames_ns), np.abs(stamps[np.maximum(i - 1, 0)] - frames_ns))
    return int(np.sum(d <= within_ns))


def _metadata_report(summary: Any, result: PipelineResult) -> dict[str, Any]:
    """report.json ``metadata``: the carrier, the fields used and how many frames each covers."""
    out = summary.to_dict()
    frames_ns = np.array([r.stamp_ns for r in result.records], dtype=np.int64)
    attitudes = [a.stamp_ns for a in result.attitudes] + [i.stamp_ns for i in result.imus if i.orientation_xyzw is not None]
    out['frames'] = len(frames_ns)
    out['frames_with_position'] = _covered(np.array([f.stamp_ns for f in result.fixes], dtype=np.int64), frames_ns)
    out['frames_with_attitude'] = _covered(np.array(attitudes, dtype=np.int64), frames_ns)
    out['frames_with_centre'] = int(sum(1 for r in result.records if r.stamp_ns in summary.centres))
    return out


def not_georeferenced_reason(result: PipelineResult, config: PipelineConfig,
                             skipped: dict[str, int] | None = None) -> str:
    """One sentence: why the mosaic has no place on the map (``skipped``: the reader's messages
    left out, per kind, which say when every fix was unusable)."""
    if not config.georef_enabled:
        return 'georeferencing is off (georef.enabled: false).'
    bad_fixes = {k: n for k, n in (skipped or {}).items() if 'NavSatFix' in k}
    if not result.fixes and bad_fixes:
        worst = max(bad_fixes, key=bad_fixes.__getitem__)
        return (f'every GNSS fix was unusable ({sum(bad_fixes.values())} left out, most as "{worst}"); record '
                'valid fixes, or give a flight log with --telemetry.')
    if not result.fixes:
        return ('the input carries no GPS positions (no NavSatFix topic, EXIF GPS, KLV, SRT or GPMF track); give a '
                'flight log with --telemetry (video) or a telemetry_from_exif.csv beside the stills.')
    if getattr(result, 'georef_note', ''):
        return f'the filter could not place the mosaic (no camera intrinsics or attitude) and {result.georef_note}.'
    if result.georef is None or result.georef.raster is None:
        return ('the input has GPS positions but no camera intrinsics, and its geotags could not place the mosaic '
                '(too few distinct positions under the main mosaic); give --camera or --hfov.')
    return 'the frames placed on the map are not in the main mosaic (see segments).'


def skip_frames_note(items: int, frames: int) -> dict[str, int]:
    return {'input_items_skipped': items, 'frames_total': frames}
