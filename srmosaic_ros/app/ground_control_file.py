"""Which ground control file a `process` run uses, decided before any work: ``--gcp``, else a folder
of stills' own gcp_list.txt (io/gcp.py); a video or a bag takes one only with ``--gcp``."""
from __future__ import annotations

import logging
from pathlib import Path

from ..errors import InputError

__all__ = ['ground_control_file']

_LOG = logging.getLogger(__name__)


def ground_control_file(path: Path, kind: str, gcp_file: Path | None, check_points: str | None) -> Path | None:
    """The GCP file a run uses: ``gcp_file``, else a folder of stills' own gcp_list.txt (io/gcp.py);
    refuses what cannot be used, before any work."""
    from ..io.gcp import find_gcp_file

    if kind != 'images':  # a video's or a bag's picks name frames by stamp (app/video_control.py)
        if check_points and gcp_file is None:
            msg = f'--check-points {check_points}: a video or a bag has no gcp_list.txt of its own; give it with --gcp FILE.'
            raise InputError(msg)
        if gcp_file is not None and not Path(gcp_file).is_file():
            msg = f'--gcp {gcp_file}: no such file; give the path of an OpenDroneMap gcp_list.txt.'
            raise InputError(msg)
        return Path(gcp_file) if gcp_file is not None else None
    if gcp_file is not None:
        if not Path(gcp_file).is_file():
            msg = f'--gcp {gcp_file}: no such file; give the path of an OpenDroneMap gcp_list.txt.'
            raise InputError(msg)
        return Path(gcp_file)
    found = find_gcp_file(path)
    if found is None and check_points:
        msg = (f'--check-points {check_points}: {path} has no gcp_list.txt inside or beside it; give the ground '
               'control points with --gcp FILE.')
        raise InputError(msg)
    if found is not None:
        _LOG.info('ground control points: %s', found)
    return found
