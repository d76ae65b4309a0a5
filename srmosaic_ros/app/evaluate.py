"""`srmosaic evaluate`: figures of a process output against a simulated flight's ground truth.

Geometry (frames.csv against the true homographies), georeferencing (mosaic.tif, poses.csv) and,
when the run has sr/tiles.json, the quality of the SR tiles against the true ground image
(:func:`sr_figures`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..core.metrics import corner_error_px, mosaic_corner_errors
from ..errors import InputError
from ..io.mosaic_files import read_frames_csv
from ..sim import load_truth

__all__ = ['evaluate_dir', 'sr_figures', 'tile_grid_H']


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
        true_H = np.linalg.inv(f_prev.world_px_H_frame) @ f_cur.world_px_H_frame
        est = np.linalg.inv(prev['mosaic_H_frame']) @ cur['mosaic_H_frame']
        pair_err.append(corner_error_px(est, true_H, w, h))
    if pair_err:
        figures['pair_corner_error_mean_px'] = float(np.mean(pair_err))
        figures['pair_corner_error_p90_px'] = float(np.percentile(pair_err, 90))
    if (Path(out_dir) / 'mosaic.tif').is_file() and ok:
        figures.update(_georef_errors(Path(out_dir), truth, ok, by_stamp, w, h))
    if (Path(out_dir) / 'sr' / 'tiles.json').is_file() and len(ok) >= 2:
        figures['sr'] = sr_figures(Path(out_dir), truth, ok, by_stamp)
        figures['sr'].update(_psf_figures(Path(out_dir), truth.config))
    return figures


def _psf_figures(out_dir: Path, sim_config: dict[str, Any]) -> dict[str, float]:
    """The PSF the SR run modelled (report.json sr.psf_sigma_px) and the simulated camera's true
    blur in frame pixels (``psf_sigma_true_px``), when both are known."""
    from ..sim.render import frame_blur_px
    from .evaluate_real import load_report

    out: dict[str, float] = {}
    report = Path(out_dir) / 'report.json'
    if report.is_file():
        used = (load_report(report).get('sr') or {}).get('psf_sigma_px')
        if used is not None:
            out['psf_sigma_px'] = float(used)
    if 'psf_sigma_px' in sim_config:
        out['psf_sigma_true_px'] = frame_blur_px(float(sim_config['psf_sigma_px']), int(sim_config.get('decimate', 1)))
    return out


def _georef_errors(out_dir: Path, truth: Any, ok: list[dict[str, Any]], by_stamp: dict[int, Any],
                   w: int, h: int) -> dict[str, Any]:
    """Georeferencing error (m) of mosaic points, and position error of poses.csv, against the truth."""
    import rasterio
    from pyproj import Transformer

    from ..core.georef.geodetic import LocalTangentPlane
    from ..core.metrics import apply_homography
    from ..io.poses_csv import read_poses_csv

    with rasterio.open(out_dir / 'mosaic.tif') as ds:
        affine, epsg = ds.transform, ds.crs.to_epsg()
    to_utm = Transformer.from_crs(4326, epsg, always_xy=True)
    ltp = LocalTangentPlane(*truth.origin)
    pts = np.array([[w / 2 - 0.5, h / 2 - 0.5], [0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], dtype=float)
    errors = []
    for r in ok:
        mos = apply_homography(r['mosaic_H_frame'], pts)
        # rasterio's affine maps pixel corners: the centre of pixel (x, y) is at (x + 0.5, y + 0.5).
        e_est = np.array([affine @ (x + 0.5, y + 0.5) for x, y in mos])
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


def tile_grid_H(entry: dict[str, Any]) -> np.ndarray:
    """(3, 3) SR tile pixel (u, v) -> mosaic.png point (x0 + (u + 0.5) / s - 0.5, y0 + (v + 0.5) / s - 0.5)."""
    s = float(entry['factor'])
    return np.array([[1.0 / s, 0.0, entry['x0'] + 0.5 / s - 0.5], [0.0, 1.0 / s, entry['y0'] + 0.5 / s - 0.5],
                     [0.0, 0.0, 1.0]])


def _world_H_mosaic_local(entry: dict[str, Any], ok: list[dict[str, Any]], by_stamp: dict[int, Any],
                          w: int, h: int) -> tuple[np.ndarray, int]:
    """world_px_H_mosaic fitted on the tile: where the covering frames' true geometry puts its points.

    A 5 x 5 grid of points over the tile (mosaic pixels) is mapped into every registered frame that
    contains the whole tile (inv(mosaic_H_frame)) and from there to the world (true
    world_px_H_frame); one homography is fitted by least squares to all of them. The mosaic is only
    defined up to a homography of the ground and drifts slowly along a flight, so a local fit is
    what places the truth under the tile (a global one would leave sub-pixel offsets that count
    against any sharp estimate). Returns (world_px_H_mosaic, frames used).
    """
    import cv2

    from ..core.metrics import apply_homography

    x0, y0, tw, th = entry['x0'], entry['y0'], entry['width'], entry['height']
    gx, gy = np.meshgrid(np.linspace(x0 - 0.5, x0 + tw - 0.5, 5), np.linspace(y0 - 0.5, y0 + th - 0.5, 5))
    pts = np.c_[gx.ravel(), gy.ravel()]
    src, dst = [], []
    for r in ok:
        in_frame = apply_homography(np.linalg.inv(r['mosaic_H_frame']), pts)
        if np.all((in_frame >= -0.5) & (in_frame <= np.array([w - 0.5, h - 0.5]))):
            src.append(pts)
            dst.append(apply_homography(by_stamp[r['stamp_ns']].world_px_H_frame, in_frame))
    if not src:   # no frame holds the whole tile: use every frame that sees its centre
        centre = pts[12:13]
        for r in ok:
            c = apply_homography(np.linalg.inv(r['mosaic_H_frame']), centre)[0]
            if 0 <= c[0] <= w - 1 and 0 <= c[1] <= h - 1:
                in_frame = apply_homography(np.linalg.inv(r['mosaic_H_frame']), pts)
                src.append(pts)
                dst.append(apply_homography(by_stamp[r['stamp_ns']].world_px_H_frame, in_frame))
    if not src:
        msg = f'no registered frame sees SR tile {entry["file"]}; is this the ground truth of the same flight?'
        raise InputError(msg)
    H, _ = cv2.findHomography(np.concatenate(src), np.concatenate(dst), 0)
    return H, len(src)


def _same_channels(img: np.ndarray, channels: int) -> np.ndarray:
    """(H, W[, C]) float -> (H, W) for channels == 1 (luminance of RGB), else (H, W, 3)."""
    if channels == 1:
        if img.ndim == 3:
            img = img[:, :, 0] if img.shape[2] == 1 else img[:, :, :3] @ np.array([0.299, 0.587, 0.114])
        return img
    return np.repeat(img[:, :, None], 3, axis=2) if img.ndim == 2 else img[:, :, :3]


def sr_figures(out_dir: Path, truth: Any, ok: list[dict[str, Any]], by_stamp: dict[int, Any], *,
               compare: bool = True) -> dict[str, Any]:
    """PSNR / SSIM of every SR tile and of the bicubic upsampling of mosaic.png against the truth.

    For each entry of sr/tiles.json, the true ground image is resampled onto the tile's pixel grid
    (tile pixel -> mosaic point by the tiles.json contract -> world pixel by a homography fitted on
    the tile, see :func:`_world_H_mosaic_local`), with the simulator's anti-alias prefilter
    0.5 sqrt(d^2 - 1) world pixels where the tile samples the world d > 1 pixels apart. The
    baseline is mosaic.png sampled bicubically at the same points (what a viewer zooming into the
    LR mosaic sees). Figures over all pixels and channels (the truth's: mono for IR flights),
    intensities in [0, 1]. ``psnr_*`` of all tiles together come from the pooled MSE; ``gain_db``
    is SR minus bicubic. With ``compare``, sr/compare.png shows bicubic | SR | truth of the tile
    with the median gain.
    """
    import json

    import cv2

    from ..core.sr.quality import mse, psnr, side_by_side, ssim
    from ..io.mosaic_files import write_png
    from ..sim.render import local_scales, reference_render
    from ..sim.world import load_world

    sr_dir = out_dir / 'sr'
    entries = json.loads((sr_dir / 'tiles.json').read_text())
    mode = str(truth.config.get('mode', 'eo'))
    world = load_world(truth.world_path, truth.world_gsd_m, mode=mode,
                       origin_lat_deg=truth.origin[0], origin_lon_deg=truth.origin[1]).image
    channels = 1 if world.ndim == 2 else 3
    mosaic = cv2.imread(str(out_dir / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    if mosaic is None:
        msg = f'cannot read {out_dir / "mosaic.png"}; run `srmosaic process` again.'
        raise InputError(msg)
    if mosaic.ndim == 3:
        mosaic = cv2.cvtColor(mosaic[:, :, :3], cv2.COLOR_BGR2RGB)
    mosaic = _same_channels(mosaic.astype(np.float32) / 255.0, channels).astype(np.float32)
    w, h = truth.camera.width, truth.camera.height
    tiles, panels = [], []
    sums = {'sr': 0.0, 'bicubic': 0.0, 'n': 0}
    for entry in entries:
        sr = cv2.imread(str(sr_dir / entry['file']), cv2.IMREAD_UNCHANGED)
        if sr is None:
            msg = f'cannot read SR tile {sr_dir / entry["file"]} listed in tiles.json.'
            raise InputError(msg)
        if sr.ndim == 3:
            sr = cv2.cvtColor(sr[:, :, :3], cv2.COLOR_BGR2RGB)
        sr = _same_channels(sr.astype(np.float64) / 255.0, channels)
        th, tw = sr.shape[:2]
        world_H_mosaic, n_frames = _world_H_mosaic_local(entry, ok, by_stamp, w, h)
        grid_H = tile_grid_H(entry)
        world_H_tile = world_H_mosaic @ grid_H
        centre = np.array([[(tw - 1) / 2.0, (th - 1) / 2.0]])
        d = float(np.sqrt(np.prod(local_scales(world_H_tile, centre)[0])))  # world px per tile px
        sigma = 0.5 * np.sqrt(d * d - 1.0) if d > 1.0 else 0.0
        true_img = np.clip(reference_render(world, world_H_tile, (tw, th), sigma) / 255.0, 0.0, 1.0)
        uu, vv = np.meshgrid(np.arange(tw, dtype=np.float64), np.arange(th, dtype=np.float64))
        mx = (grid_H[0, 0] * uu + grid_H[0, 2]).astype(np.float32)
        my = (grid_H[1, 1] * vv + grid_H[1, 2]).astype(np.float32)
        bicubic = np.clip(cv2.remap(mosaic, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE), 0.0, 1.0)
        bicubic = bicubic.astype(np.float64)
        m_sr, m_bic = mse(sr, true_img), mse(bicubic, true_img)
        n = true_img.size
        sums['sr'] += m_sr * n
        sums['bicubic'] += m_bic * n
        sums['n'] += n
        tile = {'file': entry['file'], 'frames_fit': n_frames, 'world_px_per_tile_px': round(d, 3),
                'psnr_sr': psnr(sr, true_img), 'psnr_bicubic': psnr(bicubic, true_img),
                'ssim_sr': ssim(sr, true_img), 'ssim_bicubic': ssim(bicubic, true_img)}
        tile['gain_db'] = tile['psnr_sr'] - tile['psnr_bicubic']
        tile['ssim_gain'] = tile['ssim_sr'] - tile['ssim_bicubic']
        tiles.append(tile)
        panels.append((bicubic, sr, true_img))
    out: dict[str, Any] = {'tiles': len(tiles), 'per_tile': tiles}
    if tiles:
        p_sr = 10.0 * np.log10(1.0 / max(sums['sr'] / sums['n'], 1e-20))
        p_bic = 10.0 * np.log10(1.0 / max(sums['bicubic'] / sums['n'], 1e-20))
        gains = np.array([t['gain_db'] for t in tiles])
        out.update({
            'factor': entries[0]['factor'],
            'psnr_sr': float(p_sr), 'psnr_bicubic': float(p_bic), 'gain_db': float(p_sr - p_bic),
            'gain_db_median': float(np.median(gains)), 'gain_db_min': float(gains.min()),
            'ssim_sr': float(np.mean([t['ssim_sr'] for t in tiles])),
            'ssim_bicubic': float(np.mean([t['ssim_bicubic'] for t in tiles])),
        })
        if compare:
            i = int(np.argsort(gains)[len(gains) // 2])   # the median tile, not the best one
            t = tiles[i]
            labels = [f'bicubic {t["psnr_bicubic"]:.2f} dB', f'SR x{entries[i]["factor"]} {t["psnr_sr"]:.2f} dB',
                      'truth']
            zoom = max(1, round(384 / panels[i][0].shape[1]))   # panels about 384 px wide
            write_png(sr_dir / 'compare.png', side_by_side(panels[i], labels, zoom=zoom).astype(np.float32) / 255.0)
            out['compare'] = {'file': 'sr/compare.png', 'tile': t['file']}
    return out
