"""`srmosaic frames INPUT DIR`: a video's or a bag's frames as image files named by their stamps
(app/frame_names.py), to pick ground control targets in (OpenDroneMap's GCP Editor Pro, or any tool
that writes gcp_list.txt) for `process INPUT --gcp gcp_list.txt`."""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..core.types import Frame
from ..errors import InputError, OutputError
from .frame_names import frame_file_name
from .input_source import open_source

__all__ = ['export_frames']

_LOG = logging.getLogger(__name__)


def export_frames(path: Path, out: Path, *, select: str = 'all', every: int = 1, topics=None,
                  deinterlace: str = 'auto', suffix: str = '.png') -> list[Path]:
    """Write every ``every``-th frame of ``path`` (as ``process --select`` selects them, as decoded:
    before any undistortion) into ``out`` as 8-bit PNG or JPEG files; returns their paths.

    Raises:
        InputError: a folder of stills (its files are its frames already), or ``every`` < 1.
        OutputError: ``out`` cannot be written.
    """
    import cv2

    if every < 1:
        msg = f'--every {every}: give 1 or more (1: every frame).'
        raise InputError(msg)
    if suffix not in ('.png', '.jpg'):
        msg = f'--format {suffix.lstrip(".")}: give png or jpg.'
        raise InputError(msg)
    items, _, kind = open_source(path, topics=topics, select=select, deinterlace=deinterlace)
    if kind == 'images':
        msg = f'{path} is a folder of stills: pick the ground control in its files as they are (their names are their frames).'
        raise InputError(msg)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        msg = f'{out}: cannot create the folder ({exc.strerror}); give another DIR.'
        raise OutputError(msg) from None
    written: list[Path] = []
    index = 0
    for item in items:
        if not isinstance(item, Frame):
            continue
        if index % every == 0:
            image = item.image
            if image.dtype != np.uint8:  # 16-bit (thermal): the full range, as the mosaic shows it
                lo, hi = float(image.min()), float(image.max())
                image = np.clip((image.astype(np.float64) - lo) * (255.0 / max(hi - lo, 1.0)), 0, 255).astype(np.uint8)
            if image.ndim == 3:
                image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            target = out / frame_file_name(index, item.stamp_ns, suffix)
            if not cv2.imwrite(str(target), image):
                msg = f'{target}: the frame could not be written; check the space and permissions of {out}.'
                raise OutputError(msg)
            written.append(target)
        index += 1
    _LOG.info('%d of %d frames written into %s', len(written), index, out)
    return written
