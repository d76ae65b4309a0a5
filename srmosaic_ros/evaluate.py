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
    if (Path(out_dir) / 'mosaic.tif').is_file() and ok:
        figures.update(_georef_errors(Path(out_dir), truth, ok, by_stamp, w, h))
    return figures


def _georef_errors(out_dir: Path, truth: Any, ok: list[dict[str, Any]], by_stamp: dict[int, Any],
                   w: int, h: int) -> dict[str, Any]:
    """Georeferencing error (m) of mosaic points, and position error of poses.csv, against the truth."""
    import rasterio
    from pyproj import Transformer

    from .core.georef.geodetic import LocalTangentPlane
    from .core.metrics import apply_homography
    from .io.poses_csv import read_poses_csv

    with rasterio.open(out_dir / 'mosaic.tif') as ds:
        affine, epsg = ds.transform, ds.crs.to_epsg()
    to_utm = Transformer.from_crs(4326, epsg, always_xy=True)
    ltp = LocalTangentPlane(*truth.origin)
    pts = np.array([[w / 2 - 0.5, h / 2 - 0.5], [0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], dtype=float)
    errors = []
    for r in ok:
        mos = apply_homography(r['mosaic_H_frame'], pts)
        # rasterio's affine maps pixel corners: the centre of pixel (x, y) is at (x + 0.5, y + 0.5).
        e_est = np.array([affine * (x + 0.5, y + 0.5) for x, y in mos])
        world = apply_homography(by_stamp[r['stamp_ns']].world_px_H_frame, pts)
        enu = apply_homography(truth.enu_H_world_px, world)
        lat, lon, _ = ltp.geodetic_from_enu(np.c_[enu, np.zeros(len(enu))])
        e_true = np.c_[to_utm.transform(lon, lat)]
        errors.append(np.linalg.norm(e_est - e_true, axis=1))
    err = np.concatenate(errors)
    out: dict[str, Any] = {'georef_error_rms_m': float(np.sqrt(np.mean(err ** 2))), 'georef_error_max_m': float(err.max()),
                           'epsg': epsg}
    poses_csv = out_dir / 'poses.csv'
    if poses_csv.is_file():
        rows = [p for p in read_poses_csv(poses_csv) if p['stamp_ns'] in by_stamp and np.isfinite(p['latitude'])]
        if rows:
            est = np.array([ltp.enu_from_geodetic(p['latitude'], p['longitude'], p['altitude']) for p in rows])
            tru = np.array([by_stamp[p['stamp_ns']].position_enu_m for p in rows])
            d = est - tru
            out['pose_rmse_horizontal_m'] = float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1))))
            out['pose_rmse_vertical_m'] = float(np.sqrt(np.mean(d[:, 2] ** 2)))
    return out
