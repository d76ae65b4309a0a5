"""Names of a video's or a bag's frames as files: how `srmosaic frames` writes them and how a
gcp_list.txt's ``image_name`` is read back to the frame it was picked in.

A frame is named by its stamp, the ``stamp_ns`` column of frames.csv: ``frame_000123_33333333ns.png``
is the 124th frame written, stamped 33 333 333 ns. A ground control pick names the frame by that file
name, or by the stamp alone (``33333333``, with or without an image extension): the index is for
people sorting files, the stamp is what identifies the frame.
"""
from __future__ import annotations

import re
from pathlib import PurePath

__all__ = ['frame_file_name', 'stamp_of_name']

_STAMPED = re.compile(r'^(?:.*_)?(\d+)ns$|^(\d+)$')
_IMAGE_SUFFIXES = {'.png', '.jpg', '.jpeg', '.tif', '.tiff', '.bmp', '.webp'}


def frame_file_name(index: int, stamp_ns: int, suffix: str = '.png') -> str:
    """The file name of frame ``index`` (0-based, in the order written) stamped ``stamp_ns``."""
    return f'frame_{index:06d}_{stamp_ns}ns{suffix}'


def stamp_of_name(name: str) -> int | None:
    """The stamp (ns) a frame's file name or a GCP ``image_name`` gives, or None when it gives none."""
    path = PurePath(name.strip())
    stem = path.stem if path.suffix.lower() in _IMAGE_SUFFIXES else path.name
    match = _STAMPED.match(stem)
    if match is None:
        return None
    return int(match.group(1) or match.group(2))
