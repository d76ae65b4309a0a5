"""report.json of a `srmosaic process` run, read and checked for what evaluate and the SR protocol use."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..io.mosaic_files import read_frames_csv

__all__ = ['REPORT_SHAPE', 'load_report']


#: What evaluate reads of report.json: dotted key -> (accepted types, what it should hold). A key may be
#: absent or null; present, it must have one of its types.
REPORT_SHAPE: dict[str, tuple[tuple[type, ...], str]] = {
    'input': ((str,), 'the input path, a string'),
    'input_kind': ((str,), "'bag', 'video' or 'images'"),
    'segments': ((list,), 'a list of segments'),
    'not_georeferenced_reason': ((str,), 'a sentence'),
    'video': ((dict,), 'an object'),
    'video.select': ((str,), "a frame selection such as 'all'"),
    'video.camera': ((str,), 'a camera YAML path'),
    'video.deinterlace': ((str,), "'auto', 'on' or 'off'"),
    'config': ((dict,), 'an object'),
    'config.undistort': ((bool,), 'true or false'),
    'config.mosaic': ((dict,), 'an object'),
    'config.mosaic.max_stretch': ((int, float), 'a number'),
    'config.mosaic.max_width': ((int,), 'an integer'),
    'sr': ((dict,), 'an object'),
    'sr.psf_sigma_px': ((int, float), 'a number'),
}


def load_report(path: Path) -> dict[str, Any]:
    """report.json of a run, checked against REPORT_SHAPE; InputError saying what is wrong with it
    (unreadable, not an object, a key of the wrong type) and to re-run process."""
    from ..bounded_yaml import preview

    again = 're-run `srmosaic process` to write it again'
    try:
        report = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        msg = f'{path} is not readable JSON ({" ".join(str(exc).split())[:120]}); {again}.'
        raise InputError(msg) from None
    def said(value: Any) -> str:  # as JSON names it
        kind = {dict: 'an object', list: 'an array', str: 'a string', bool: 'a boolean', int: 'a number',
                float: 'a number'}.get(type(value), type(value).__name__)
        return 'null' if value is None else f'{kind}, {preview(value)}'

    if not isinstance(report, dict):
        msg = f'{path} holds {said(report)}, not the object `srmosaic process` writes; {again}.'
        raise InputError(msg)
    for key, (types, what) in REPORT_SHAPE.items():
        *parents, leaf = key.split('.')
        node: Any = report
        for part in parents:
            node = node.get(part) if isinstance(node, dict) else None
        value = node.get(leaf) if isinstance(node, dict) else None
        if value is not None and (not isinstance(value, types) or (bool not in types and isinstance(value, bool))):
            msg = f'{path}: "{key}" is {said(value)}, but it should be {what}; the file was edited or damaged: {again}.'
            raise InputError(msg)
    return report


def _load_run(out_dir: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(report.json, frames.csv rows), InputError naming what is missing."""
    for name in ('frames.csv', 'report.json', 'mosaic.png'):
        if not (out_dir / name).is_file():
            msg = f'{out_dir / name} not found; run `srmosaic process INPUT --out {out_dir}` first.'
            raise InputError(msg)
    report = load_report(out_dir / 'report.json')
    try:
        rows = read_frames_csv(out_dir / 'frames.csv')
    except (ValueError, KeyError) as exc:
        msg = f'{out_dir / "frames.csv"} is not a frames.csv of `srmosaic process` ({exc}); re-run process.'
        raise InputError(msg) from None
    return report, rows


