"""`srmosaic evaluate`: figures of a process output against a simulated flight's ground truth."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .core.metrics import corner_error_px, mosaic_corner_errors
from .errors import InputError
from .io.mosaic_files import read_frames_csv
from .sim import load_truth

__all__ = ['evaluate_dir']


def evaluate_dir(out_dir: Path, truth_path: Path) -> dict[str, Any]:
    """Corner errors of frames.csv's mosaic_H_frame against the truth, and the fraction registered.

    Frames are matched by stamp_ns. The mosaic plane is related to the ground by a fitted
    homography (see mosaic_corner_errors); consecutive-frame errors compare
    inv(mosaic_H_prev) @ mosaic_H_cur with the true prev_H_cur.
    """
    frames_csv = Path(out_dir) / 'frames.csv'
    if not frames_csv.is_file():
        msg = f'{frames_csv} not found; run `srmosaic process INPUT --out {out_dir}` first.'
        raise InputError(msg)
    rows = read_frames_csv(frames_csv)
    truth = load_truth(truth_path)
    by_stamp = {f.stamp_ns: f for f in truth.frames}
    unknown = [r['stamp_ns'] for r in rows if r['stamp_ns'] not in by_stamp]
    if unknown:
        msg = (f'{len(unknown)} frame stamps of {frames_csv} are not in {truth_path} (first: {unknown[0]}); '
               'is this the ground truth of the same flight?')
        raise InputError(msg)
    w, h = truth.camera.width, truth.camera.height
    ok = [r for r in rows if r['ok']]
    figures: dict[str, Any] = {
        'frames_in': len(rows),
        'frames_truth': len(truth.frames),
        'frames_registered': len(ok),
        'fraction_registered': len(ok) / len(truth.frames) if truth.frames else 0.0,
        'corner_error_mean_px': float('nan'),
        'corner_error_max_px': float('nan'),
        'pair_corner_error_mean_px': None,
        'pair_corner_error_p90_px': None,
    }
    if len(ok) >= 2:
        err, _ = mosaic_corner_errors([r['mosaic_H_frame'] for r in ok],
                                      [by_stamp[r['stamp_ns']].world_px_H_frame for r in ok], w, h)
        figures['corner_error_mean_px'] = float(err.mean())
        figures['corner_error_max_px'] = float(err.max())
        figures['corner_error_last_px'] = float(err[-1])
    index = {f.stamp_ns: i for i, f in enumerate(truth.frames)}
    pair_err = []
    for prev, cur in zip(rows, rows[1:]):
        if not (prev['ok'] and cur['ok']) or index[cur['stamp_ns']] != index[prev['stamp_ns']] + 1:
            continue
        true_H = by_stamp[cur['stamp_ns']].prev_H_cur  # noqa: N806
        if true_H is None:
            continue
        est = np.linalg.inv(prev['mosaic_H_frame']) @ cur['mosaic_H_frame']
        pair_err.append(corner_error_px(est, true_H, w, h))
    if pair_err:
        figures['pair_corner_error_mean_px'] = float(np.mean(pair_err))
        figures['pair_corner_error_p90_px'] = float(np.percentile(pair_err, 90))
    return figures
