"""A run's input opened as one stream of items in time order: a bag, a video file (with the metadata it
carries: MISB KLV, a DJI SRT beside it, a GoPro GPMF track, or a telemetry CSV given) or a folder of stills."""
from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..io.bags import TopicConfig, read_flight
from ..io.metadata import merge_by_time

_LOG = logging.getLogger(__name__)

__all__ = ['open_source']


def open_source(path: Path, *, topics: TopicConfig | None = None, select: str = 'all',
                camera_yaml: Path | None = None, hfov_deg: float | None = None,
                telemetry_csv: Path | None = None, stamp_tolerance_s: float = 10.0,
                deinterlace: str = 'auto') -> tuple[Iterable[Any], Any, str]:
    """(items in time order, the reader (frame_count, skipped, summary), 'bag', 'video' or 'images')
    for a bag, a video file or a folder of stills.

    The metadata the input carries is read and merged (io/metadata.py): a folder's EXIF/XMP; a
    video's MISB KLV stream, a DJI .SRT beside it or a GoPro GPMF track, in that order, unless
    ``telemetry_csv`` is given (it overrides them). ``reader.summary`` says what was found. A bag's
    messages stamped more than ``stamp_tolerance_s`` off their topic's clock are skipped and counted.
    ``deinterlace``: a video's interlaced frames (io/video.py: auto, on, off).
    """
    from ..io.image_folder import ImageFolderReader, is_image_folder
    from ..io.metadata import MetadataSummary
    from ..io.video import VideoReader, is_video, load_camera_yaml, parse_selection

    if is_image_folder(path):
        if select != 'all' or camera_yaml or hfov_deg or telemetry_csv or deinterlace != 'auto':
            msg = ('--select, --camera, --hfov, --telemetry and --deinterlace apply to video input; a folder of stills takes its '
                   'stamps, geotags and camera from each image\'s EXIF/XMP (or a telemetry_from_exif.csv beside the '
                   'images).')
            raise InputError(msg)
        reader = ImageFolderReader(path)
        return reader, reader, 'images'
    if is_video(path):
        camera = load_camera_yaml(camera_yaml) if camera_yaml else None
        reader = VideoReader(path, selection=parse_selection(select), camera=camera, hfov_deg=hfov_deg,
                             deinterlace=deinterlace)
        items: Iterable[Any] = reader
        if telemetry_csv is not None:
            from ..io.telemetry_csv import read_telemetry_csv

            counts: dict[str, int] = {}
            items = merge_by_time(reader, read_telemetry_csv(telemetry_csv, counts))
            reader.summary = MetadataSummary(source='telemetry CSV', fields=['gps position', 'attitude'])
            reader.summary.problems.update({k: n for k, n in counts.items() if n})
            return items, reader, 'video'
        return _video_with_metadata(path, reader)
    if select != 'all' or camera_yaml or hfov_deg or telemetry_csv or deinterlace != 'auto':
        msg = ('--select, --camera, --hfov, --telemetry and --deinterlace apply to video input; a bag carries its own camera '
               'info and telemetry topics.')
        raise InputError(msg)
    reader = read_flight(path, topics=topics or TopicConfig(), stamp_tolerance_s=stamp_tolerance_s)
    reader.summary = MetadataSummary(source='bag topics')
    return reader, reader, 'bag'


def _video_with_metadata(path: Path, reader: Any) -> tuple[Iterable[Any], Any, str]:
    """A video's own metadata, found in order: MISB KLV stream, DJI SRT beside it, GoPro GPMF track."""
    from ..io.dji_srt import find_srt, read_srt, time_mismatch
    from ..io.gpmf import read_gpmf
    from ..io.klv import read_klv
    from ..io.metadata import KlvVideoSource, MetadataSummary, gpmf_items, srt_items
    from ..errors import MetadataError

    track = read_klv(path)
    if track.records:
        source = KlvVideoSource(reader, track)
        return source, source, 'video'
    summary = MetadataSummary(frames=reader.frame_count or 0)
    srt = find_srt(path)
    if srt is not None:
        try:
            srt_track = read_srt(srt)
        except MetadataError as exc:
            _LOG.warning('%s; the video is processed without its telemetry.', exc)
            summary.problems['srt_unusable'] += 1
        else:
            useless, said = time_mismatch(srt_track, reader.duration_s)
            if said:
                _LOG.warning('%s', said)
                summary.note(said)
            if useless:
                summary.problems['srt_outside_video'] += 1
            else:
                items = srt_items(srt_track, summary)
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
