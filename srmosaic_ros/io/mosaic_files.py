"""The file contracts of `srmosaic process` (see DESIGN.md): mosaic.png, frames.csv, report.json.

Every file is written to a temporary name in the same directory and renamed into place, so an
interrupted run never leaves a half-written file under the final name.
"""
from __future__ import annotations

import csv
import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import cv2
import numpy as np

from ..errors import InputError

__all__ = [
    'FRAMES_CSV_HEADER',
    'FRAMES_CSV_META',
    'FRAMES_CSV_PLACED_BY',
    'atomic_path',
    'read_frames_csv',
    'write_counts_png',
    'write_frames_csv',
    'write_json',
    'write_png',
]

FRAMES_CSV_HEADER = ['stamp_ns', 'ok', 'inliers', 'rms_px'] + [f'h{r}{c}' for r in range(3) for c in range(3)]
#: Trailing columns: where the input's own metadata puts the frame centre on the ground (WGS84 deg;
#: the GPS position of a nadir still, the KLV frame centre of a video frame), NaN when it does not say.
FRAMES_CSV_META = ['meta_latitude', 'meta_longitude']
#: The last column: how the frame was placed in mosaic.png: 'registration' (by its registrations:
#: the chain, or a survey's global solve), 'pose' (a survey's still in no registered pair, placed by
#: its GPS position and heading alone) or empty (not in mosaic.png).
FRAMES_CSV_PLACED_BY = 'placed_by'


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it onto `path` when the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.stem}.', suffix=path.suffix, dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; the final file gets the usual mode
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


@contextmanager
def _atomic_text(path: str | os.PathLike[str]) -> Iterator[IO[str]]:
    with atomic_path(path) as tmp, open(tmp, 'w', newline='') as handle:
        yield handle


def write_png(path: str | os.PathLike[str], image: np.ndarray, coverage: np.ndarray | None = None) -> None:
    """Write a float image in [0, 1] ((H, W), (H, W, 1) or (H, W, 3) RGB) as 8-bit PNG.

    With `coverage` (H, W) bool, the PNG gets an alpha channel: uncovered mosaic pixels are
    transparent (RGBA for colour, grey+alpha written as RGBA too, which every reader accepts).
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    u8 = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if coverage is not None:
        rgb = np.repeat(u8[:, :, None], 3, axis=2) if u8.ndim == 2 else u8
        alpha = np.where(coverage, 255, 0).astype(np.uint8)
        out = cv2.cvtColor(np.dstack([rgb, alpha]), cv2.COLOR_RGBA2BGRA)
    else:
        out = u8 if u8.ndim == 2 else cv2.cvtColor(u8, cv2.COLOR_RGB2BGR)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), out):
            msg = f'could not write {path}'
            raise OSError(msg)


def write_counts_png(path: str | os.PathLike[str], counts: np.ndarray) -> None:
    """Write uint8 counts (H, W) as an 8-bit grey PNG, values as they are (atomically)."""
    u8 = np.asarray(counts)
    if u8.dtype != np.uint8 or u8.ndim != 2:
        msg = f'counts must be uint8 (H, W), got {u8.dtype} {u8.shape}.'
        raise ValueError(msg)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), u8):
            msg = f'could not write {path}'
            raise OSError(msg)


def write_frames_csv(path: str | os.PathLike[str], rows: Iterable[dict[str, Any]]) -> None:
    """frames.csv: one row per input frame; h = mosaic_H_frame (NaN when the frame is not in mosaic.png);
    ``meta_latlon`` (lat, lon) of a row fills the FRAMES_CSV_META columns (NaN when absent);
    ``placed_by`` the last column (default: 'registration' for a row in mosaic.png, else empty)."""
    with _atomic_text(path) as handle:
        writer = csv.writer(handle)
        writer.writerow([*FRAMES_CSV_HEADER, *FRAMES_CSV_META, FRAMES_CSV_PLACED_BY])
        for row in rows:
            H = row.get('mosaic_H_frame')
            h = [float('nan')] * 9 if H is None else [float(v) for v in np.asarray(H, dtype=np.float64).ravel()]
            rms = row.get('rms_px', float('nan'))
            meta = row.get('meta_latlon') or (float('nan'), float('nan'))
            placed = row.get('placed_by', 'registration' if H is not None and row['ok'] else '')
            writer.writerow([int(row['stamp_ns']), int(bool(row['ok'])), int(row.get('inliers', 0)),
                             f'{rms:.6g}', *[repr(v) for v in h], *[f'{float(v):.9f}' for v in meta], placed])


def read_frames_csv(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Rows of frames.csv with stamp_ns int, ok bool, inliers int, rms_px float, mosaic_H_frame (3, 3)."""
    rows = []
    with open(path, newline='') as handle:
        reader = csv.DictReader(handle)
        missing = set(FRAMES_CSV_HEADER) - set(reader.fieldnames or [])
        if missing:
            msg = f'{path} is not a frames.csv: missing columns {sorted(missing)}'
            raise InputError(msg)
        for rec in reader:
            try:  # a row cut short has None (missing fields) or a cut number
                H = np.array([float(rec[f'h{r}{c}']) for r in range(3) for c in range(3)]).reshape(3, 3)
                rows.append({'stamp_ns': int(rec['stamp_ns']), 'ok': rec['ok'] == '1', 'inliers': int(rec['inliers']),
                             'rms_px': float(rec['rms_px']), 'mosaic_H_frame': H,
                             'placed_by': rec.get(FRAMES_CSV_PLACED_BY) or ('registration' if rec['ok'] == '1'
                                                                            else '')})
            except (TypeError, ValueError):
                msg = (f'{path} line {reader.line_num} is cut short or damaged; the folder is not a complete run: '
                       'run `srmosaic process` into it again.')
                raise InputError(msg) from None
    return rows


def write_json(path: str | os.PathLike[str], data: Any) -> None:
    with _atomic_text(path) as handle:
        json.dump(data, handle, indent=2, sort_keys=False, default=_jsonable)
        handle.write('\n')


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    msg = f'{type(value).__name__} is not JSON serialisable'
    raise TypeError(msg)
