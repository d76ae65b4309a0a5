"""`srmosaic process`: run the pipeline over a recorded flight and write the file contracts."""
from __future__ import annotations

import collections
import resource
import shutil
import time
from pathlib import Path
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
from tqdm import tqdm

from .checkpoint import Checkpoint, checkpoint_path, fingerprint, load_checkpoint, save_checkpoint
from .config import PipelineConfig
from .io.bags import TopicConfig, read_flight
from .io.mosaic_files import write_frames_csv, write_json, write_png
from .errors import InputError, SrMosaicError
from .io.mosaic_video import MosaicVideoRecorder
from .pipeline import SYNC_HOLD_FRAMES, Pipeline, PipelineResult
from .core.image_ops import to_float01
from .core.types import Frame

__all__ = ['open_source', 'peak_rss_mb', 'preview_image', 'process_input', 'write_outputs']


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


def _translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def preview_image(image: np.ndarray, coverage: np.ndarray, max_side: int) -> np.ndarray:
    """The mosaic downscaled so that its longer side is at most max_side, uncovered pixels black."""
    import cv2

    image = np.where(coverage[..., None] if image.ndim == 3 else coverage, image, 0.0).astype(np.float32)
    h, w = image.shape[:2]
    scale = min(1.0, max_side / max(h, w))
    if scale >= 1.0:
        return image
    return cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


def write_outputs(result: PipelineResult, out: Path, config: PipelineConfig, extra: dict[str, Any]) -> dict[str, Any]:
    """Write mosaic.png (main canvas), segments/, frames.csv, and with georeferencing mosaic.tif,
    mosaic.kml and poses.csv. Returns the report (the caller adds timings and writes it)."""
    out.mkdir(parents=True, exist_ok=True)
    main = result.main_segment
    main_canvas = main.canvas if main is not None else None
    mosaic_H_seg = np.eye(3)  # noqa: N806
    segments_report = []
    written: dict[int, str] = {}  # id(canvas) -> file
    geo: dict[str, Any] = {}
    for seg in result.segments:
        x0, y0, x1, y1 = seg.canvas.bounds()
        if id(seg.canvas) not in written:
            image, coverage = seg.canvas.render()
            if seg.canvas is main_canvas:
                mosaic_H_seg = _translation(-x0, -y0)  # noqa: N806
                write_png(out / 'mosaic.png', image, coverage)
                write_png(out / 'preview.png', preview_image(image, coverage, config.mosaic.preview_max_side_px))
                written[id(seg.canvas)] = 'mosaic.png'
                if main.georeferenced and result.georef is not None and result.georef.raster is not None:
                    geo = _write_georeferenced(out, result, image, coverage, (x0, y0))
            elif len(seg.frames) >= 2:
                written[id(seg.canvas)] = f'segments/segment_{seg.index:03d}.png'
                write_png(out / written[id(seg.canvas)], image, coverage)
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


def _merge_by_time(frames: Iterable[Frame], telemetry: list[Any]) -> Iterator[Any]:
    """Interleave telemetry (sorted by stamp) before the frames that follow it in time."""
    i = 0
    for frame in frames:
        while i < len(telemetry) and telemetry[i].stamp_ns <= frame.stamp_ns:
            yield telemetry[i]
            i += 1
        yield frame
    yield from telemetry[i:]


def open_source(path: Path, *, topics: TopicConfig | None = None, select: str = 'all',
                camera_yaml: Path | None = None, hfov_deg: float | None = None,
                telemetry_csv: Path | None = None) -> tuple[Iterable[Any], Any, str]:
    """(items in time order, the reader (frame_count, skipped), 'bag' or 'video') for a bag or a video file."""
    from .io.image_folder import ImageFolderReader, is_image_folder
    from .io.video import VideoReader, is_video, load_camera_yaml, parse_selection

    if is_image_folder(path):
        reader = ImageFolderReader(path)
        return reader, reader, 'images'
    if is_video(path):
        camera = load_camera_yaml(camera_yaml) if camera_yaml else None
        reader = VideoReader(path, selection=parse_selection(select), camera=camera, hfov_deg=hfov_deg)
        items: Iterable[Any] = reader
        if telemetry_csv is not None:
            from .io.telemetry_csv import read_telemetry_csv

            items = _merge_by_time(reader, read_telemetry_csv(telemetry_csv))
        return items, reader, 'video'
    if select != 'all' or camera_yaml or hfov_deg or telemetry_csv:
        msg = ('--select, --camera, --hfov and --telemetry apply to video input; a bag carries its own camera '
               'info and telemetry topics.')
        raise InputError(msg)
    reader = read_flight(path, topics=topics or TopicConfig())
    return reader, reader, 'bag'


def _write_georeferenced(out: Path, result: PipelineResult, image: np.ndarray, coverage: np.ndarray,
                         origin: tuple[int, int]) -> dict[str, Any]:
    """mosaic.tif (same pixel grid as mosaic.png), mosaic.kml and poses.csv (smoothed poses)."""
    from .io.geotiff import write_geotiff
    from .io.kml import write_kml_for_raster
    from .io.poses_csv import write_poses_csv

    from .core.metrics import apply_homography

    georef = result.georef
    poses = georef.smoothed_poses()
    # The mosaic plane was anchored by the first frame's (early, filtered) pose. With the smoothed
    # poses of every frame, re-anchor it: the mean offset between each frame's chained corners and
    # its pose-predicted corners is the anchor error (averaged over the flight), removed by shifting
    # the geotransform. The mosaic's pixels do not move: mosaic.png and mosaic.tif stay one grid.
    offsets = []
    main_canvas = result.main_segment.canvas
    seg_of = {seg.index: seg for seg in result.segments}
    for rec, pose in zip(result.records, poses):
        seg = seg_of.get(rec.segment)
        if seg is None or seg.canvas is not main_canvas or not pose.valid or rec.seg_H_frame is None:
            continue
        w_f, h_f = rec.size
        corners = np.array([[0, 0], [w_f - 1, 0], [w_f - 1, h_f - 1], [0, h_f - 1]], dtype=float)
        by_pose = apply_homography(georef.raster_H_frame(pose), corners)
        offsets.append(by_pose - apply_homography(rec.seg_H_frame, corners))
    shift = np.concatenate(offsets).mean(axis=0) if offsets else np.zeros(2)
    # mosaic pixel m is chained raster pixel m + origin, truly at raster pixel m + origin + shift.
    raster = georef.raster.shifted(origin[0] + shift[0], origin[1] + shift[1])  # pixel (0, 0) of mosaic.png
    write_geotiff(out / 'mosaic.tif', image, raster, coverage=coverage)
    h, w = coverage.shape
    write_kml_for_raster(out / 'mosaic.kml', 'mosaic.png', raster, w, h)
    write_poses_csv(out / 'poses.csv', poses)
    return {'epsg': raster.epsg, 'gsd_m_per_px': raster.gsd_m_per_px, 'geotransform': list(raster.geotransform),
            'anchor_shift_px': [float(v) for v in shift], 'poses': len(poses),
            'skipped_telemetry': dict(georef.skipped)}


def process_input(path: Path, out: Path, config: PipelineConfig, *, topics: TopicConfig | None = None,
                  select: str = 'all', camera_yaml: Path | None = None, hfov_deg: float | None = None,
                  telemetry_csv: Path | None = None, mosaic_video: bool = False,
                  checkpoint_every: int = 0, resume: bool = False, sr_factor: int | None = None,
                  progress: bool = True) -> dict[str, Any]:
    """Run the pipeline over a bag or video and write the outputs; returns the report (also in report.json).

    If the input breaks mid-way (a damaged bag or video, a frame size change), everything processed
    so far is written, the report records the error, and the error is raised again so the command
    exits non-zero. With checkpoint_every > 0 the state is checkpointed every that many frames
    (see checkpoint.py); resume=True continues from the last checkpoint in `out`.
    """
    t0 = time.perf_counter()
    if checkpoint_every < 0:
        msg = f'--checkpoint-every must be >= 0, got {checkpoint_every}.'
        raise InputError(msg)
    items, reader, kind = open_source(path, topics=topics, select=select, camera_yaml=camera_yaml,
                                      hfov_deg=hfov_deg, telemetry_csv=telemetry_csv)
    settings = {'select': select, 'topics': repr(topics), 'config': repr(config), 'mosaic_video': mosaic_video,
                'camera': str(camera_yaml), 'hfov': hfov_deg, 'telemetry': str(telemetry_csv)}
    run_id = fingerprint(path, settings)
    pipeline = Pipeline(config)
    recorder = MosaicVideoRecorder() if mosaic_video else None
    recent: dict[int, np.ndarray] = {}
    skip_items = frames_done = 0
    if resume:
        state = load_checkpoint(out, run_id)
        pipeline, recorder = state.pipeline, state.recorder
        recent = state.recent or {}
        skip_items, frames_done = state.items_consumed, state.frames_consumed
    bar = tqdm(total=reader.frame_count, initial=frames_done, unit='frame', desc='process', disable=not progress)
    error: SrMosaicError | None = None
    consumed = 0
    with bar:
        try:
            for item in items:
                consumed += 1
                if consumed <= skip_items:  # already in the checkpointed state
                    continue
                records = pipeline.feed(item)
                if isinstance(item, Frame):
                    frames_done += 1
                    bar.update(1)
                    bar.set_postfix(segments=len(pipeline.segments), refresh=False)
                    if recorder is not None:
                        recent[item.stamp_ns] = item.image
                        while len(recent) > SYNC_HOLD_FRAMES + 3:  # frames are decided at most this late
                            recent.pop(next(iter(recent)))
                if recorder is not None:
                    for rec in records:
                        if rec.painted and rec.stamp_ns in recent:
                            recorder.add(rec.segment, to_float01(recent[rec.stamp_ns]), rec.seg_H_frame)
                if checkpoint_every and isinstance(item, Frame) and frames_done % checkpoint_every == 0:
                    save_checkpoint(out, Checkpoint(run_id, consumed, frames_done, pipeline, recorder, recent))
        except SrMosaicError as exc:
            error = exc
    if recorder is not None and error is None:
        for rec in pipeline.flush():  # the last frames, held for telemetry that never came
            if rec.painted and rec.stamp_ns in recent:
                recorder.add(rec.segment, to_float01(recent[rec.stamp_ns]), rec.seg_H_frame)
    result = pipeline.finish()
    report_extra: dict[str, Any] = {'input': str(path), 'input_kind': kind,
                                    'skipped_messages': dict(getattr(reader, 'skipped', {}))}
    if kind == 'video':
        report_extra['video'] = {'codec': reader.codec, 'fps': reader.fps, 'frames_decoded': reader.decoded,
                                 'frames_selected': reader.selected, 'select': select}
    if error is not None:
        report_extra['error'] = str(error)
    report = write_outputs(result, out, config, report_extra)
    if recorder is not None and result.main_segment is not None:
        main = result.main_segment
        report['mosaic_video_frames'] = recorder.write(out / 'mosaic.mp4', main.index, main.canvas.bounds())
    wall = time.perf_counter() - t0
    report['wall_s'] = round(wall, 3)
    report['frames_per_s'] = round(len(result.records) / wall, 2) if wall > 0 else None
    report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    if resume:
        report['resumed_after_frames'] = skip_frames_note(skip_items, frames_done)
    if sr_factor is not None and error is None and result.main_segment is not None:
        from .sr_offline import super_resolve_mosaic

        t_sr = time.perf_counter()
        again, _, _ = open_source(path, topics=topics, select=select, camera_yaml=camera_yaml, hfov_deg=hfov_deg,
                                  telemetry_csv=telemetry_csv)
        report['sr'] = super_resolve_mosaic(out, again, config, factor=sr_factor, progress=progress)
        report['sr']['wall_s'] = round(time.perf_counter() - t_sr, 3)
        report['wall_s'] = round(time.perf_counter() - t0, 3)
        report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    write_json(out / 'report.json', report)
    if error is not None:
        raise error
    shutil.rmtree(checkpoint_path(out).parent, ignore_errors=True)  # complete: the checkpoint is spent
    return report


def skip_frames_note(items: int, frames: int) -> dict[str, int]:
    return {'input_items_skipped': items, 'frames_total': frames}
