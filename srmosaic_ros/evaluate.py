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
    if truth.frames and not any(r['stamp_ns'] in by_stamp for r in rows):
        # Video input: stamps are presentation times from the first frame.
        t0 = truth.frames[0].stamp_ns
        by_stamp = {f.stamp_ns - t0: f for f in truth.frames}
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
        'fraction_registered': len(ok) / len(rows) if rows else 0.0,
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
    pair_err = []
    for prev, cur in zip(rows, rows[1:]):
        if not (prev['ok'] and cur['ok']):
            continue
        # True homography between the two rows' frames (consecutive or not, e.g. I-frames only).
        f_prev, f_cur = by_stamp[prev['stamp_ns']], by_stamp[cur['stamp_ns']]
        true_H = np.linalg.inv(f_prev.world_px_H_frame) @ f_cur.world_px_H_frame  # noqa: N806
        est = np.linalg.inv(prev['mosaic_H_frame']) @ cur['mosaic_H_frame']
        pair_err.append(corner_error_px(est, true_H, w, h))
    if pair_err:
        figures['pair_corner_error_mean_px'] = float(np.mean(pair_err))
        figures['pair_corner_error_p90_px'] = float(np.percentile(pair_err, 90))
    return figures
