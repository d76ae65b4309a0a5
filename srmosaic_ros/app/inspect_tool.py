"""`srmosaic inspect INPUT`: what a file carries, and what `srmosaic process` will do with it.

Reads headers and metadata only (no frame is decoded, except a video's first, to tell whether it
is interlaced, and its others to count them when the container does not say): streams, frame
count and rate, MISB KLV packets and their standard, a DJI SRT beside a video or a GoPro GPMF track
inside it, the EXIF camera of stills and the intrinsics derived, the fields that are missing.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ..errors import InputError

__all__ = ['inspect_input', 'format_inspection']


def inspect_input(path: Path) -> dict[str, Any]:
    """A description of ``path`` (video, folder of stills or bag) as a JSON-able dict."""
    from ..io.image_folder import is_image_folder
    from ..io.video import is_video

    path = Path(path)
    if not path.exists():
        msg = f'{path} does not exist; give a video file, a folder of stills or a bag.'
        raise InputError(msg)
    if is_image_folder(path):
        return _inspect_stills(path)
    if is_video(path):
        return _inspect_video(path)
    return _inspect_bag(path)


def _plan(positions: bool, intrinsics: bool, attitude: bool, attitude_what: str = '',
          why_fit: str = 'no camera intrinsics; give --camera or --hfov (video) for the filter') -> str:
    if positions and intrinsics:
        att = f'camera attitude from {attitude_what}' if attitude else \
            ('no attitude: it is learnt from the registrations and the course over ground, the camera taken as the '
             'mount georef.gimbal_* says (nadir); footage that disagrees is chained and fitted to its geotags instead, '
             'unless its frames look obliquely')
        return f'georeferenced through the filter (GPS + homographies; {att}); mosaic.tif, mosaic.kml, poses.csv'
    if positions:
        return (f'georeferenced by its geotags (a similarity fitted to the GPS positions, for a camera looking '
                f'straight down: a chain whose frames look obliquely is left unreferenced): {why_fit}')
    return ('mosaicked, not georeferenced: no GPS positions; give --telemetry (video) or a telemetry_from_exif.csv '
            '(stills)')


def _stills_plan(path: Path, reader: Any) -> str:
    """What `process` does with a folder of stills under the default parameters (survey.mode)."""
    from ..config import pipeline_config
    from .survey import use_global_alignment

    s = reader.summary
    if use_global_alignment(reader, pipeline_config()):
        att = ('their gimbal angles (XMP) as priors of each footprint\'s turn, scale and tilt'
               if s.frames_with_attitude else 'no gimbal angles: the camera is taken as vertical within '
               'survey.tilt_allowance_deg, the height from GPS baselines over registered displacements')
        return ('aligned globally (survey.mode auto): pairs by predicted footprint, one robust solve with the GPS '
                f'positions and {att}; georeferenced: mosaic.tif, mosaic.kml (no poses.csv)')
    return _plan(s.frames_with_position > 0 or bool(reader.telemetry),
                 s.frames_with_intrinsics > 0 and s.frames_with_attitude > 0,
                 s.frames_with_attitude > 0, 'the gimbal angles in the XMP',
                 why_fit='no gimbal angles in the XMP, so no camera attitude for the filter'
                 if s.frames_with_intrinsics else 'no camera intrinsics in the EXIF')


def _inspect_stills(path: Path) -> dict[str, Any]:
    from ..io.exif import intrinsics_from_metadata
    from ..io.image_folder import ImageFolderReader

    reader = ImageFolderReader(path)
    s = reader.summary
    first = next((m for m in reader.meta if m is not None), None)
    out: dict[str, Any] = {'input': str(path), 'kind': 'images', 'frames': len(reader.files),
                           'metadata': s.to_dict()}
    if first is not None:
        camera, why = intrinsics_from_metadata(first)
        out['camera'] = {'make': first.make, 'model': first.model, 'size_px': [first.width_px, first.height_px],
                         'focal_length_mm': first.focal_length_mm, 'intrinsics': why,
                         'fx_px': round(camera.fx, 2) if camera is not None else None}
    stamps = sorted(m.stamp_ns for m in reader.meta if m is not None and m.stamp_ns is not None)
    if len(stamps) >= 2:
        gaps = [(b - a) * 1e-9 for a, b in zip(stamps, stamps[1:])]
        out['interval_s'] = {'median': sorted(gaps)[len(gaps) // 2], 'max': max(gaps)}
    alts = [m.altitude_m for m in reader.meta if m is not None and math.isfinite(m.altitude_m)]
    if alts:
        out['gps_altitude_m'] = {'min': min(alts), 'max': max(alts)}
    out['missing'] = _missing(s.frames, s.frames_with_position, s.frames_with_intrinsics, s.frames_with_attitude,
                              stamps=len(stamps))
    out['plan'] = _stills_plan(path, reader)
    return out


def _missing(frames: int, positions: int, intrinsics: int, attitude: int, *, stamps: int | None = None) -> list[str]:
    out = []
    for what, n in (('GPS position', positions), ('camera intrinsics', intrinsics), ('camera attitude', attitude),
                    ('time', stamps)):
        if n is not None and n < frames:
            out.append(f'{what}: {frames - n} of {frames} frames lack it')
    return out


def _inspect_video(path: Path) -> dict[str, Any]:
    import av

    from ..io.dji_srt import find_srt, read_srt, time_mismatch
    from ..io.gpmf import read_gpmf
    from ..io.klv import read_klv
    from ..io.metadata import MetadataSummary, gpmf_items, srt_items
    from ..errors import MetadataError
    from ..io.video import VideoReader

    reader = VideoReader(path)
    out: dict[str, Any] = {'input': str(path), 'kind': 'video', 'codec': reader.codec,
                           'size_px': [reader.width, reader.height], 'fps': reader.fps,
                           'frames': reader.frame_count}
    with av.open(str(path)) as container:
        out['streams'] = [f'#{s.index} {s.type} {_codec_name(s)}' for s in container.streams]
        first_frame = next(container.decode(container.streams.video[0]), None)
        if first_frame is not None and first_frame.interlaced_frame:
            out['interlaced'] = 'yes: process keeps the top field of each frame (--deinterlace)'
        if not out['frames']:  # the container does not say: count the decoded frames (packets may be fields)
            container.seek(0)
            out['frames'] = sum(1 for _ in container.decode(container.streams.video[0]))
    klv = read_klv(path)
    out['klv'] = {'packets': klv.packets, 'records': len(klv.records), 'standards': dict(klv.standards),
                  'bad_checksum': klv.bad_checksum, 'stream': klv.stream}
    positions = intrinsics = attitude = 0
    what = ''
    if klv.records:
        first = klv.records[0].fields
        out['klv']['first'] = {k: first[k] for k in ('sensor_latitude_deg', 'sensor_longitude_deg', 'sensor_altitude_m',
                                                     'sensor_hfov_deg', 'sensor_vfov_deg', 'slant_range_m',
                                                     'frame_center_latitude_deg', 'frame_center_longitude_deg')
                               if k in first}
        positions = sum(1 for r in klv.records if 'sensor_latitude_deg' in r.fields)
        intrinsics = sum(1 for r in klv.records if 'sensor_hfov_deg' in r.fields)
        attitude = sum(1 for r in klv.records if 'sensor_rel_elevation_deg' in r.fields)
        what = 'the KLV platform attitude and sensor angles'
        out['metadata_source'] = 'MISB KLV'
    srt = find_srt(path)
    if srt is not None:
        try:
            track = read_srt(srt)
            summary = MetadataSummary()
            srt_items(track, summary, say=False)
            out['srt'] = {'file': str(srt), 'format': track.format, 'blocks': track.blocks,
                          'samples': len(track.samples), 'skipped': dict(track.skipped)}
            useless, said = time_mismatch(track, reader.duration_s)
            if said:
                out['srt']['refused' if useless else 'note'] = said
            if not klv.records and not useless:
                positions, attitude = summary.frames_with_position, summary.frames_with_attitude
                what = 'the SRT gimbal angles'
                out['metadata_source'] = 'DJI SRT'
        except MetadataError as exc:
            out['srt'] = {'file': str(srt), 'refused': str(exc)}
    gpmf = read_gpmf(path)
    if gpmf.payloads:
        summary = MetadataSummary()
        gpmf_items(gpmf, summary)
        out['gpmf'] = {'device': gpmf.device, 'payloads': gpmf.payloads, 'gps_samples': len(gpmf.gps),
                       'usable_fixes': summary.frames_with_position, 'orientation_samples': len(gpmf.orientation),
                       'camera_attitudes': summary.frames_with_attitude, 'notes': summary.notes}
        if not klv.records and 'metadata_source' not in out:
            positions, attitude = summary.frames_with_position, summary.frames_with_attitude
            what = "the Karma drone's attitude and gimbal tilt"
            out['metadata_source'] = 'GoPro GPMF'
    out['missing'] = [m for m in (
        None if positions else 'GPS positions (no KLV, SRT or GPMF)',
        None if (intrinsics or reader.camera) else 'camera intrinsics (give --camera or --hfov)',
        None if attitude else 'camera attitude',
    ) if m]
    out['plan'] = _plan(positions > 0, intrinsics > 0, attitude > 0, what)
    return out


def _codec_name(stream: Any) -> str:
    ctx = getattr(stream, 'codec_context', None)
    name = getattr(ctx, 'name', None) if ctx is not None else None
    return name or getattr(stream, 'codec_tag', None) or stream.metadata.get('handler_name', '') or 'data'


def _inspect_bag(path: Path) -> dict[str, Any]:
    from ..io.bags import bag_summary

    b = bag_summary(path)
    roles = dict(b.flight_topics)
    out: dict[str, Any] = {'input': str(path), 'kind': 'bag', 'storage': b.storage,
                           'metadata_version': b.metadata_version, 'files': list(b.files),
                           'compression': b.compression or None, 'duration_s': round(b.duration_ns * 1e-9, 3),
                           'messages': f'{b.messages_read} read of {b.message_count} in the metadata'}
    out['topics'] = [f'{name} ({t.msgtype}, {t.count_read} of {t.count_metadata}{", " + t.note if t.note else ""})'
                     for name, t in b.topics.items()]
    if b.warnings:
        out['warnings'] = list(b.warnings)
    if b.missing:
        out['missing_messages'] = dict(b.missing)
    out['used'] = roles
    out['missing'] = [f'{role} topic' for role in ('camera_info', 'fix', 'imu') if role not in roles and not b.refusal]
    if b.refusal:
        out['plan'] = f'refused: {b.refusal}'
    else:
        out['plan'] = _plan('fix' in roles, 'camera_info' in roles, 'imu' in roles, 'the Imu orientation')
    return out


def format_inspection(info: dict[str, Any]) -> list[str]:
    """The lines `srmosaic inspect` prints."""
    lines = [f'{info["input"]}: {info["kind"]}']
    for key, value in info.items():
        if key in ('input', 'kind', 'plan', 'missing'):
            continue
        if isinstance(value, dict):
            inner = ', '.join(f'{k} {v}' for k, v in value.items() if v not in (None, {}, [], ''))
            lines.append(f'  {key}: {inner}')
        elif isinstance(value, list):
            lines.append(f'  {key}: ' + '; '.join(str(v) for v in value))
        else:
            lines.append(f'  {key}: {value}')
    for m in info.get('missing', []):
        lines.append(f'  missing: {m}')
    lines.append(f'  process will: {info.get("plan", "")}' if info.get('plan') else '')
    return [line for line in lines if line]
