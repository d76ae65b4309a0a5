"""`srmosaic process`: run the pipeline over a recorded flight and write the file contracts."""
from __future__ import annotations

import collections
import dataclasses
import logging
import math
import re
import shutil
import time
from pathlib import Path
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
from tqdm import tqdm

from ..core.homography import translation as _translation
from .georeference import MainPlacement, georeference_main
from ..io.output_dir import OutputTransaction, check_output_dir
from .checkpoint import Checkpoint, checkpoint_path, fingerprint, load_checkpoint, save_checkpoint
from ..config import PipelineConfig
from ..io.bags import TopicConfig
from ..io.mosaic_files import write_counts_png, write_frames_csv, write_json, write_png
from ..io.outputs import MOSAIC_TIF_ZLEVEL, StripPreview, output_threads, peak_rss_mb, process_age_s, write_canvas
from ..core.sr_factors import SR_FACTORS
from ..errors import FULL_DISK_ERRNOS, ConfigError, InputError, OutputError
from ..pipeline import Pipeline, PipelineResult
from ..core.device import cores_left_for_torch
from ..core.georef.georeferencer import MIN_AXIS_DEPRESSION_DEG
from ..core.registration import Registration
from .input_pass import InputPass, feed_input, second_pass_mount, with_mount
from .map_outputs import map_outputs
from .ground_control_file import ground_control_file
from .input_source import open_source  # re-exported: app/psf.py, app/evaluate_real.py and the tests open inputs here

_LOG = logging.getLogger(__name__)

__all__ = ['open_source', 'process_input', 'write_outputs']



def registration_report(regs: list[Registration]) -> dict[str, Any]:
    """report.json's `registration`: medians over the pairs registered by features (inliers, RMS in
    px), over all placed pairs (ms), the pairs tracked (photometric alone: no inliers, RMS NaN) and
    the pairs whose tracking was refused (then registered by features)."""
    feats = [r for r in regs if not r.extras.get('tracked')]
    return {
        'median_inliers': float(np.median([r.inliers for r in feats])) if feats else None,
        'median_rms_px': float(np.median([r.rms_px for r in feats])) if feats else None,
        'median_ms': float(np.median([r.time_s for r in regs]) * 1e3) if regs else None,
        'tracked': len(regs) - len(feats),
        'track_refused': sum(1 for r in regs if r.extras.get('track_refused')),
    }


def write_outputs(result: PipelineResult, out: Path, config: PipelineConfig, extra: dict[str, Any], *,
                  meta_centres: dict[int, tuple[float, float]] | None = None,
                  placement: MainPlacement | None = None,
                  on_tables: Callable[[dict[str, Any]], None] | None = None,
                  on_preview: Callable[[], None] | None = None) -> dict[str, Any]:
    """Write mosaic.png (main canvas), preview.png, segments/, frames.csv, and with georeferencing
    mosaic.tif, mosaic.kml and poses.csv. Returns the report (the caller adds timings and writes it).
    ``meta_centres``: stamp_ns -> (lat, lon) where the input's metadata puts each frame's centre
    (frames.csv's meta_latitude, meta_longitude). ``placement``: where the main mosaic lies, as
    georeference_main decided it (None: decided here). ``on_tables``: called with the report once
    frames.csv, poses.csv and mosaic.kml are written, before the mosaic images are rendered (what
    can be drawn from them is then drawn beside the rendering: process's report.html); ``on_preview``:
    called once preview.png is written (the main mosaic rendered; mosaic.tif may still be compressed).

    The mosaics are rendered and written strip by strip (see _write_canvas): memory does not grow
    with the mosaic's area.
    """
    out.mkdir(parents=True, exist_ok=True)
    main = result.main_segment
    main_canvas = main.canvas if main is not None else None
    mosaic_H_seg = np.eye(3)
    segments_report = []
    to_write: dict[int, tuple[str, Any, tuple[int, int, int, int]]] = {}  # id(canvas) -> (file, canvas, bounds)
    geo: dict[str, Any] = {}
    for seg in result.segments:
        x0, y0, x1, y1 = seg.canvas.bounds()
        if id(seg.canvas) not in to_write:
            if seg.canvas is main_canvas:
                mosaic_H_seg = _translation(-x0, -y0)
                placement = placement or georeference_main(result, config)
                geo = placement.report
                to_write[id(seg.canvas)] = ('mosaic.png', seg.canvas, (x0, y0, x1, y1))
            elif len(seg.frames) >= 2:
                to_write[id(seg.canvas)] = (f'segments/segment_{seg.index:03d}.png', seg.canvas, (x0, y0, x1, y1))
        segments_report.append({'index': seg.index, 'frames': len(seg.frames),
                                'file': to_write[id(seg.canvas)][0] if id(seg.canvas) in to_write else '',
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
    if main_canvas is not None and placement is not None:
        _write_main_tables(out, placement, to_write[id(main_canvas)][2])
    failures = collections.Counter(rec.reason.split(' (')[0] for rec in result.records if not rec.painted)
    regs = [rec.registration for rec in result.records if rec.registration is not None and rec.registration.ok]
    report = {
        'frames_in': len(result.records),
        'frames_registered': int(sum(r['ok'] for r in rows)),
        'frames_painted_any_segment': int(sum(rec.painted for rec in result.records)),
        # placed, their pixels left to their neighbours' (mosaic.paint_stride, core/mosaic/thinning.py)
        'frames_thinned': int(getattr(result, 'frames_thinned', 0)),
        'frames_painted_in_part': int(getattr(result, 'frames_painted_in_part', 0)),
        'segments': segments_report,
        'failure_reasons': dict(failures),
        'registration': registration_report(regs),
        'telemetry': {'fixes': len(result.fixes), 'imu': len(result.imus)},
        # (w, h) of the last frame in mosaic.png: with its frames.csv row, the footprint the map shows (web/run_source.py)
        'frame_size_px': next((list(rec.size) for rec in reversed(result.records) if rec.segment in main_segments), None),
        'keyframes': keyframe_report(result.records),
        'georeferenced': geo or None,
        **({'pose_placement': result.pose_check.as_dict()} if result.pose_check is not None else {}),
        **({'attitude_check': result.attitude_check} if getattr(result, 'attitude_check', None) else {}),
        'config': {'device': config.device, 'registration': vars(config.registration), 'mosaic': vars(config.mosaic),
                   'undistort': config.undistort},
    }
    report.update(extra)
    if on_tables is not None:
        on_tables(report)
    for name, canvas, bounds in to_write.values():
        if canvas is main_canvas:
            assert placement is not None
            _write_main_mosaic(out, canvas, config, bounds, placement, on_preview=on_preview)
            moving = _write_moving(out, canvas, bounds)
            if moving is not None:
                report['moving'] = moving
        else:
            write_canvas(canvas, None, out / name, threads=output_threads())
    return report


def _write_moving(out: Path, canvas: Any, bounds: tuple[int, int, int, int]) -> dict[str, Any] | None:
    """moving.png beside mosaic.png (same pixel grid) when the canvas votes on moving objects
    (mosaic.moving > 0): 8-bit grey, at each mosaic pixel the number of frames whose pixel there
    saw something move and was kept out (0: none; saturating at 255). Returns the report's
    'moving' entry, None without the vote."""
    if not canvas.tracks_moving:
        return None
    counts = canvas.moving_counts(bounds)
    write_counts_png(out / 'moving.png', counts)
    covered = max(int(np.count_nonzero(canvas.weights(bounds))), 1)
    return {'file': 'moving.png', 'pixels': int(np.count_nonzero(counts)),
            'fraction_of_mosaic': round(float(np.count_nonzero(counts)) / covered, 5)}


def _write_main_tables(out: Path, placement: MainPlacement, bounds: tuple[int, int, int, int]) -> None:
    """mosaic.kml and poses.csv of the main mosaic, where ``placement`` has a raster (and poses)."""
    x0, y0, x1, y1 = bounds
    if placement.raster is None:
        return
    from ..io.kml import write_kml_for_raster

    write_kml_for_raster(out / 'mosaic.kml', 'mosaic.png', placement.raster, x1 - x0, y1 - y0)
    if placement.poses is not None:
        from ..io.poses_csv import write_poses_csv

        write_poses_csv(out / 'poses.csv', placement.poses)


def _write_main_mosaic(out: Path, canvas: Any, config: PipelineConfig, bounds: tuple[int, int, int, int],
                       placement: MainPlacement, *, on_preview: Callable[[], None] | None = None) -> None:
    """mosaic.png and preview.png of the main segment's canvas, and where ``placement`` has a raster
    mosaic.tif (same pixel grid as mosaic.png); ``on_preview`` called once preview.png is written."""
    x0, y0, x1, y1 = bounds
    preview = StripPreview(y1 - y0, x1 - x0, canvas.channels, config.mosaic.preview_max_side_px)
    raster = placement.raster

    def rendered() -> None:  # every strip in the preview: written while GDAL finishes mosaic.tif
        write_png(out / 'preview.png', preview.image())
        if on_preview is not None:
            on_preview()

    write_canvas(canvas, out / 'mosaic.tif' if raster is not None else None, out / 'mosaic.png', raster, preview,
                 threads=output_threads(), zlevel=MOSAIC_TIF_ZLEVEL, on_rendered=rendered)


def keyframe_report(records: list[Any]) -> dict[str, Any]:
    """What the keyframe-to-mosaic registrations did (core/mosaic/keyframe.py): how many were tried
    and applied, the corner shifts (px) of the applied corrections, why the others changed nothing,
    and the frames given a share of a correction (Pipeline's revisit spreading)."""
    results = [rec.keyframe for rec in records if rec.keyframe is not None]
    shifts = [k.shift_px for k in results if not k.reason]
    moved = [rec.corrected_px for rec in records if rec.corrected_px > 0]
    return {
        'tried': len(results),
        'applied': len(shifts),
        'shift_px_median': round(float(np.median(shifts)), 3) if shifts else None,
        'shift_px_max': round(float(np.max(shifts)), 3) if shifts else None,
        'not_applied': dict(collections.Counter(re.sub(r'\d+(\.\d+)?', '#', k.reason) for k in results if k.reason)),
        'frames_moved_back': len(moved),  # mosaic.revisit_spread_frames: frames before a keyframe given a share of its correction
        'moved_back_px_max': round(float(np.max(moved)), 3) if moved else None,
    }


def skipped_kinds(skipped: dict[str, int]) -> dict[str, int]:
    """The readers' skipped counts per kind: keys 'topic: reason' stay, a folder's 'file: reason'
    become 'reason' (one line per kind, not one per still)."""
    out: dict[str, int] = {}
    for key, count in skipped.items():
        head, _, reason = key.partition(': ')
        what = key if head.startswith('/') or not reason else reason
        out[what] = out.get(what, 0) + count
    return out


def process_input(path: Path, out: Path, config: PipelineConfig, *, topics: TopicConfig | None = None,
                  select: str = 'all', camera_yaml: Path | None = None, hfov_deg: float | None = None,
                  telemetry_csv: Path | None = None, mosaic_video: bool = False,
                  checkpoint_every: int = 0, resume: bool = False, sr_factor: int | None = None,
                  progress: bool = True, overlap: bool = True, deinterlace: str = 'auto',
                  gcp_file: Path | None = None, check_points: str | None = None, tiles: str | None = None,
                  kmz: bool = False) -> dict[str, Any]:
    """Run the pipeline over a bag, a video or a folder of stills and write the outputs into ``out``;
    returns the report (also in report.json).

    tiles: also write the web map's XYZ tiles in this format ('png' or 'webp') with the offline page
    (web/offline.py); kmz: also write mosaic.kmz. Both need a georeferenced mosaic (mosaic.tif).

    gcp_file: ground control points (OpenDroneMap's gcp_list.txt; None: for a folder of stills the
    gcp_list.txt inside or beside it, if any): the survey's solve takes them (app/ground_control.py),
    a video's or a bag's mosaic is re-anchored on them (app/video_control.py); check_points: the
    targets held out of the control, a count or names separated by commas.

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
    if sr_factor is not None and sr_factor not in SR_FACTORS:  # before the mosaic, not after it
        msg = f'--sr-factor {sr_factor} is out of range: it must be one of {", ".join(map(str, SR_FACTORS))}.'
        raise ConfigError(msg)
    items, reader, kind = open_source(path, topics=topics, select=select, camera_yaml=camera_yaml,
                                      hfov_deg=hfov_deg, telemetry_csv=telemetry_csv,
                                      stamp_tolerance_s=config.stamp_tolerance_s, deinterlace=deinterlace)
    gcp_file = ground_control_file(path, kind, gcp_file, check_points)
    check_output_dir(out)  # before the work, not after it
    with OutputTransaction(out) as transaction:
        try:
            report = _process(path, out, transaction.stage, config, items, reader, kind, t0, topics=topics,
                              select=select, camera_yaml=camera_yaml, hfov_deg=hfov_deg, telemetry_csv=telemetry_csv,
                              mosaic_video=mosaic_video, checkpoint_every=checkpoint_every, resume=resume,
                              sr_factor=sr_factor, progress=progress, overlap=overlap, deinterlace=deinterlace,
                              gcp_file=gcp_file, check_points=check_points)
            if tiles or kmz:
                report = map_outputs(transaction.stage, report, t0, tiles=tiles, kmz=kmz)
        except OSError as exc:
            if exc.errno not in FULL_DISK_ERRNOS:
                raise
            msg = (f'{out}: an output could not be written ({exc.strerror}); free space, or give --out elsewhere '
                   '(the earlier run there is untouched).')
            raise OutputError(msg) from None
    report['stale_outputs_removed'] = transaction.removed
    return report


def _process(path: Path, out: Path, stage: Path, config: PipelineConfig, items: Iterable[Any], reader: Any,
             kind: str, t0: float, *, topics: TopicConfig | None, select: str, camera_yaml: Path | None,
             hfov_deg: float | None, telemetry_csv: Path | None, mosaic_video: bool, checkpoint_every: int,
             resume: bool, sr_factor: int | None, progress: bool, overlap: bool,
             deinterlace: str = 'auto', gcp_file: Path | None = None, check_points: str | None = None) -> dict[str, Any]:
    """process_input's work: outputs into ``stage``, checkpoints into ``out``."""
    summary = getattr(reader, 'summary', None)
    if kind == 'images':
        from .survey import use_global_alignment

        if use_global_alignment(reader, config, ground_control=gcp_file is not None):
            if resume or mosaic_video:
                msg = ('--resume and --mosaic-video apply to the chained pipeline; a survey aligned globally runs in '
                       'one pass (no checkpoints). Drop them, or set survey.mode: chain.')
                raise InputError(msg)
            return _process_survey(path, stage, config, reader, t0, sr_factor=sr_factor, progress=progress,
                                   gcp_file=gcp_file, check_points=check_points)
        if gcp_file is not None:
            _LOG.warning('%s: ground control is used by the global alignment of stills, and survey.mode is chain: '
                         'the points are not used (set survey.mode: auto or global to use them).', gcp_file)
    config = _with_ground_hint(config, summary)
    settings = {'select': select, 'topics': repr(topics), 'config': repr(config), 'mosaic_video': mosaic_video,
                'camera': str(camera_yaml), 'hfov': hfov_deg, 'telemetry': str(telemetry_csv)}
    run_id = fingerprint(path, settings)
    run, restart = InputPass.fresh(config, overlap=overlap, mosaic_video=mosaic_video), None
    if resume:
        run, restart = _resumed(out, run_id, overlap=overlap)
        config = run.pipeline.config  # the mount the run started again with, when it did
    bar = tqdm(total=reader.frame_count, initial=run.frames_done, unit='frame', desc='process', disable=not progress)

    def save(done: InputPass) -> None:
        save_checkpoint(out, Checkpoint(run_id, done.consumed, done.frames_done, done.pipeline.state(), done.recorder,
                                        done.recent, mount_restart=restart))

    def on_frame(done: InputPass) -> None:
        bar.update(1)
        bar.set_postfix(segments=len(done.pipeline.segments), refresh=False)

    passes = {'overlap': overlap, 'checkpoint_every': checkpoint_every, 'save': save, 'on_frame': on_frame}
    with bar, cores_left_for_torch(1 if overlap else 0):  # one core is the painter's (Pipeline paint_thread)
        feed_input(items, run, try_mount=restart is None and config.georef.mount_from_frames, **passes)
        if run.mount_to_try is not None:  # the second pass, with the mount the frames show (input_pass.py)
            restart = second_pass_mount(run)
            config = with_mount(config, restart)
            run = InputPass.fresh(config, overlap=overlap, mosaic_video=mosaic_video)
            items, reader, _ = open_source(path, topics=topics, select=select, camera_yaml=camera_yaml,
                                           hfov_deg=hfov_deg, telemetry_csv=telemetry_csv,
                                           stamp_tolerance_s=config.stamp_tolerance_s, deinterlace=deinterlace)
            bar.reset()
            feed_input(items, run, try_mount=False, **passes)
    pipeline, error, clock = run.pipeline, run.error, run.pipeline.clock
    from .run_report import start_sections, start_warm_up

    warm = start_warm_up()  # report.html's imports while the last frames are painted (a core waits for the painter)
    if run.recorder is not None and error is None:
        run.record(pipeline.flush())  # the last frames, held for telemetry that never came
    result = pipeline.finish()
    kinds = skipped_kinds(dict(getattr(reader, 'skipped', {})))
    for what, count in kinds.items():
        _LOG.warning('%d message(s) left out: %s', count, what)
    if error is None and not result.records:
        said = '; '.join(f'{count} x {what}' for what, count in kinds.items()) or 'no image messages or files at all'
        msg = (f'no usable image in {path} ({said}); nothing was written. Check the image topic or files '
               '(srmosaic inspect INPUT says what the input holds).')
        raise InputError(msg)
    report_extra = _input_report(path, kind, reader, summary, result, select=select, camera_yaml=camera_yaml,
                                 hfov_deg=hfov_deg)
    if error is not None:
        report_extra['error'] = str(error)
    if restart is not None:
        report_extra['mount_from_frames'] = restart
    frame_sizes = [rec.size for rec in result.records]
    gnss_latlon = np.array([(f.latitude_deg, f.longitude_deg) for f in result.fixes]).reshape(-1, 2)
    early: list[Any] = []

    def draw_early(tables: dict[str, Any]) -> None:  # report.html's figures of the tables, while the mosaic renders
        early.append(start_sections(stage, tables, frame_sizes=frame_sizes, gnss_latlon=gnss_latlon, warm=warm))

    with clock.stage('outputs'):  # decided, then written
        placement = georeference_main(result, config)
        if gcp_file is not None:  # the raster re-anchored on the ground control (app/video_control.py)
            from .video_control import control_main

            placement, report_extra['gcp'] = control_main(gcp_file, result, placement, check_points,
                                                          getattr(reader, 'camera', None))
        report = write_outputs(result, stage, config, report_extra, placement=placement,
                               meta_centres=summary.centres if summary is not None else None, on_tables=draw_early,
                               on_preview=lambda: early[0].add_mosaic_sections() if early else None)
    if report.get('georeferenced') is None:
        report['not_georeferenced_reason'] = not_georeferenced_reason(result, config,
                                                                      dict(getattr(reader, 'skipped', {})))
        _LOG.warning('the mosaic is not georeferenced: %s', report['not_georeferenced_reason'])
    if run.recorder is not None and result.main_segment is not None:
        main = result.main_segment
        report['mosaic_video_frames'] = run.recorder.write(stage / 'mosaic.mp4', main.index, main.canvas.bounds())
    wall = time.perf_counter() - t0
    report['wall_s'] = round(wall, 3)
    report['frames_per_s'] = round(len(result.records) / wall, 2) if wall > 0 else None
    report['stage_times'] = clock.summary()
    report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    if resume:
        report['resumed_after_frames'] = skip_frames_note(run.skip_items, run.frames_done)
    if sr_factor is not None and error is None and result.main_segment is not None:
        from .sr_process import super_resolve_mosaic

        t_sr = time.perf_counter()
        again, _, _ = open_source(path, topics=topics, select=select, camera_yaml=camera_yaml, hfov_deg=hfov_deg,
                                  telemetry_csv=telemetry_csv, stamp_tolerance_s=config.stamp_tolerance_s,
                                  deinterlace=deinterlace)
        report['sr'] = super_resolve_mosaic(stage, again, config, factor=sr_factor, progress=progress)
        report['sr']['wall_s'] = round(time.perf_counter() - t_sr, 3)
        report['wall_s'] = round(time.perf_counter() - t0, 3)
        report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    _write_reports(stage, report, t0, frame_sizes=frame_sizes, gnss_latlon=gnss_latlon, early=early[0] if early else None)
    if error is not None:
        raise error
    shutil.rmtree(checkpoint_path(out).parent, ignore_errors=True)  # complete: the checkpoint is spent
    return report


def _input_report(path: Path, kind: str, reader: Any, summary: Any, result: PipelineResult, *, select: str,
                  camera_yaml: Path | None, hfov_deg: float | None) -> dict[str, Any]:
    """report.json's entries on the input: what it was, what was left out or adjusted, its metadata and video."""
    report_extra: dict[str, Any] = {'input': str(path), 'input_kind': kind,
                                    'skipped_messages': dict(getattr(reader, 'skipped', {}))}
    if kind == 'images':
        report_extra['images_left_out'] = dict(reader.left_out)
    if getattr(reader, 'warned', None):  # images used although their decoder warned (io/bags.py)
        report_extra['image_decoder_warnings'] = dict(reader.warned)
    if getattr(reader, 'adjusted', None):  # CameraInfo scaled to images of another size (io/bags.py)
        report_extra['adjusted_messages'] = dict(reader.adjusted)
    if summary is not None:
        report_extra['metadata'] = _metadata_report(summary, result)
    if kind == 'video':
        report_extra['video'] = {'codec': reader.codec, 'fps': reader.fps, 'frames_decoded': reader.decoded,
                                 'frames_selected': reader.selected, 'select': select,
                                 'deinterlace': reader.deinterlace, 'frames_deinterlaced': reader.deinterlaced,
                                 'camera': str(Path(camera_yaml).resolve()) if camera_yaml else None,
                                 'hfov_deg': hfov_deg}
        if getattr(reader, 'ended_early', ''):
            report_extra['video']['ended_early'] = reader.ended_early
    return report_extra


def _resumed(out: Path, run_id: str, *, overlap: bool) -> tuple[InputPass, dict[str, Any] | None]:
    """The pass a checkpoint in ``out`` holds, and the mount its run switched to (None: it did not)."""
    state = load_checkpoint(out, run_id)
    try:
        pipeline = Pipeline.from_state(state.pipeline, paint_thread=overlap)
    except ValueError as exc:
        msg = f'--resume: the checkpoint in {out} holds a {exc} Run without --resume.'
        raise InputError(msg) from None
    run = InputPass(pipeline, state.recorder, state.recent or {}, skip_items=state.items_consumed,
                    frames_done=state.frames_consumed)
    return run, state.mount_restart


def _process_survey(path: Path, out: Path, config: PipelineConfig, reader: Any, t0: float, *,
                    sr_factor: int | None, progress: bool, gcp_file: Path | None = None,
                    check_points: str | None = None) -> dict[str, Any]:
    """A folder of stills aligned globally (survey.py), with the report and SR as process_input's."""
    from .survey import process_survey, survey_stills

    report = process_survey(path, out, config, reader, progress=progress, gcp_file=gcp_file,
                            check_points=check_points)
    report = {'input': str(path), 'input_kind': 'images', 'skipped_messages': dict(reader.skipped), **report}
    report['images_left_out'] = dict(reader.left_out)
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
        from .sr_process import super_resolve_mosaic

        t_sr = time.perf_counter()
        again, _, _ = open_source(path)
        report['sr'] = super_resolve_mosaic(out, again, config, factor=sr_factor, progress=progress)
        report['sr']['wall_s'] = round(time.perf_counter() - t_sr, 3)
        report['wall_s'] = round(time.perf_counter() - t0, 3)
        report['peak_rss_mb'] = round(peak_rss_mb(), 1)
    stills, _, _ = survey_stills(reader)
    _write_reports(out, report, t0, frame_sizes=[s.size for s in stills],
                   gnss_latlon=np.array([s.latlon for s in stills]).reshape(-1, 2))
    return report


def _write_reports(out: Path, report: dict[str, Any], t0: float, *, frame_sizes: list[tuple[int, int]],
                   gnss_latlon: np.ndarray, early: Any = None) -> None:
    """report.html (run_report.py), then report.json with the page's time counted in ``wall_s`` and
    in ``stage_times.outputs`` (where the run keeps stage times), the page's figures in
    ``report_html`` and ``startup_s``: the seconds from the process's start to ``t0`` (the input
    opened), which ``wall_s`` leaves out (Python's and the imports' start-up when `srmosaic process`
    runs as a program; in a longer-lived process, its age then)."""
    from .run_report import write_run_report

    page = write_run_report(out, report, frame_sizes=frame_sizes, gnss_latlon=gnss_latlon, early=early)
    report['report_html'] = page
    wall = time.perf_counter() - t0
    report['wall_s'] = round(wall, 3)
    age = process_age_s()  # wall_s leaves out the process's start-up: said beside it
    report['startup_s'] = round(max(age - wall, 0.0), 3) if age is not None else None
    if report.get('frames_per_s'):  # the frames over the time before SR (as before), the page's added
        report['frames_per_s'] = round(report['frames_in'] / (report['frames_in'] / report['frames_per_s']
                                                              + page['time_s']), 2)
    for name in ('outputs', 'total'):
        times = (report.get('stage_times') or {}).get(name)
        if times is not None:
            times['total_s'] = round(times['total_s'] + page['time_s'], 3)
            if name == 'outputs':  # once per run: its per-frame figures are its total spread over the frames
                per_frame = round(times['total_s'] / max(times.get('frames') or 1, 1) * 1e3, 3)
                times.update(median_ms=per_frame, p95_ms=per_frame, mean_ms=per_frame)
    write_json(out / 'report.json', report)


def _with_ground_hint(config: PipelineConfig, summary: Any) -> PipelineConfig:
    """The ground height the metadata implies (KLV frame centre elevation, a DJI take-off altitude)
    as the filter's prior, unless georef.ground_altitude_m is set."""

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
    left out, per kind, which say when every fix was unusable), after the measured attitudes the
    filter left out because they look at the horizon, when there were any."""
    why = _why_not_georeferenced(result, config, skipped)
    at_horizon = result.georef.skipped.get('camera_attitude_horizon', 0) if result.georef is not None else 0
    if at_horizon:
        return (f'{at_horizon} measured camera attitude(s) look less than {MIN_AXIS_DEPRESSION_DEG:g} deg below the '
                'horizon, where no ground '
                f'plane is in view, and were left out; {why}')
    return why


def _why_not_georeferenced(result: PipelineResult, config: PipelineConfig, skipped: dict[str, int] | None) -> str:
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
    check = getattr(result, 'pose_check', None)
    if getattr(result, 'georef_note', '') and check is not None and not check.used:
        return f'the filter\'s poses were not used ({check.reason}) and {result.georef_note.rstrip(".")}.'
    if getattr(result, 'georef_note', ''):
        return ('the filter could not place the mosaic (no camera intrinsics or attitude) and '
                f'{result.georef_note.rstrip(".")}.')
    if result.georef is None or result.georef.raster is None:
        return ('the input has GPS positions but no camera intrinsics, and its geotags could not place the mosaic '
                '(too few distinct positions under the main mosaic); give --camera or --hfov.')
    return 'the frames placed on the map are not in the main mosaic (see segments).'


def skip_frames_note(items: int, frames: int) -> dict[str, int]:
    return {'input_items_skipped': items, 'frames_total': frames}
