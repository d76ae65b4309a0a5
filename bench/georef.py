"""Benchmark: georeferencing, GPS-only vs homography chaining vs the UKF, and mosaic drift control.

Two synthetic flights (srmosaic_ros.sim) over the caliterra orthophoto stretched to 0.3 m per world
pixel (1200 m x 900 m), 320 x 240 frames at 4 frames/s, 100 m above the ground (0.36 m/px), GNSS at
5 Hz with sigma 2.5 m horizontal / 5 m vertical, IMU at 50 Hz with 0.5 deg attitude noise (and
0.002 rad/s gyro noise), 2 deg RMS gusts:

- line: 500 frames straight east at 8 m/s (1 km);
- lawnmower: 4 legs of 250 m, 60 m apart, at 10 m/s (513 frames, ~48 % side overlap between the
  legs, which fly in opposite directions, so the mosaic must close across them).

Registrations: the true inter-frame homographies perturbed by Gaussian noise of the four frame
corners (sigma per coordinate), refitted exactly through the noisy corners, with their covariance
(8 x 8, of h) passed to the filter; sigma is calibrated first by running the pipeline's default registrar
(srmosaic_ros.core.registration.make_registrar) on rendered frames of the line flight (its mean corner
error = sigma sqrt(pi / 2)). Rendering every frame is needed anyway for the mosaic products.

Estimators of the body position at each frame, against the simulator's truth:
- GPS-only: the fixes, linearly interpolated at the frame stamps;
- chaining: the first frame placed by the first fix and IMU sample (ground at the first fix minus
  the nominal 100 m AGL), then only the homographies (each frame's pose decomposed from its chained
  ground homography);
- UKF without video (GNSS + IMU orientation + gyro), the UKF with every registration (causal: the
  pose of each frame when it arrives), and the same run smoothed offline (Rauch-Tung-Striebel,
  Georeferencer.smoothed_poses).

Mosaics (frames -> north-up UTM raster at the frame GSD): chained only (no drift control), each
frame placed by its fused pose, the chain corrected by Georeferencer.correct (drift control, live:
a Kalman filter of the chain's corner error, the anchor's similarity error and the pose error, a
Gauss-Markov process whose time constants come from the filter's information rate and the frame
spacing, see core/georef/drift.py; the live canvas keeps the anchor's offset, rotation and scale
error, hence its larger "georef RMS" before re-anchoring), and the same with the smoothed poses
(offline).
Figures: geometric error (the project's metric: per-frame mean corner error after the best global
homography to the truth, RMS over frames and at the last frame), seam error between consecutive
frames (px), closure between legs (px: the same ground point placed by two frames of different
legs), georeferencing error of mosaic points (m: 5 x 5 pixels of every frame, UTM against truth).

Writes bench/out/georef_trajectories.png (the three trajectories and the truth), georef.json, and
for each flight bench/out/<flight>/{mosaic.tif, mosaic.png, mosaic.kml, poses.csv} (offline
products: smoothed poses, drift-controlled placement).

    python bench/georef.py [--quick] [--seed 0] [--sigma-px S] [--pose-time-constant S] [--altitude M]
                           [--ut-iterations N] [--out bench/out]
"""
from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.core.georef import (
    FramePose,
    GeorefConfig,
    Georeferencer,
    camera_pose_from_enu_H_image,
    homography_from_corners,
)
from srmosaic_ros.core.georef.anchoring import fit_similarity
from srmosaic_ros.core.georef.frames import matrix_from_quat_xyzw, rpy_from_R_enu_from_body
from srmosaic_ros.core.georef.geodetic import LocalTangentPlane
from srmosaic_ros.core.georef.ground_homography import apply_H, ground_H_image, normalize_H
from srmosaic_ros.core.georef.ukf import corner_jacobian
from srmosaic_ros.core.metrics import corner_error_px, mosaic_corner_errors
from srmosaic_ros.core.registration import RegistrationConfig, make_registrar
from srmosaic_ros.io.geotiff import write_geotiff
from srmosaic_ros.io.kml import write_kml_for_raster
from srmosaic_ros.io.mosaic_files import write_json, write_png
from srmosaic_ros.io.poses_csv import write_poses_csv
from srmosaic_ros.sim import SimConfig, SimulatedFlight, simulate

BASE = {'width': 320, 'height': 240, 'world_gsd_m': 0.3, 'altitude_m': 100.0, 'gps_sigma_h_m': 2.5,
        'gps_sigma_v_m': 5.0, 'imu_sigma_deg': 0.5}
FLIGHTS = {
    'line': {'trajectory': 'line', 'frames': 500, 'speed_m_s': 8.0},
    'lawnmower': {'trajectory': 'lawnmower', 'legs': 4, 'leg_length_m': 250.0, 'leg_spacing_m': 60.0,
                  'speed_m_s': 10.0},
}
GOALS = {'fused_over_gps': 0.5, 'georef_rms_m': 2.0, 'mosaic_px': 3.0}


# --- inputs ------------------------------------------------------------------------------------


def corners_of(cam) -> np.ndarray:
    return np.array([[0.0, 0.0], [cam.width - 1.0, 0.0], [cam.width - 1.0, cam.height - 1.0], [0.0, cam.height - 1.0]])


def calibrate_registrar(flight: SimulatedFlight, frames: int) -> dict[str, float]:
    """Corner errors of the pipeline's default registrar (make_registrar: registration.backend
    and its OpenCV fallback) on consecutive rendered frames.

    sigma (per corner coordinate) = mean corner error / sqrt(pi / 2) over the successful
    registrations within 2 px of the truth (the gross ones, counted apart, are what the UKF's gate
    refuses; the bench's Gaussian model has none)."""
    reg = make_registrar(RegistrationConfig(), 'cpu')
    feats = [reg.describe(f.image) for f in flight.frames[:frames]]
    errs, fails = [], 0
    for k in range(1, len(feats)):
        r = reg.register(feats[k - 1], feats[k])
        if not r.ok:
            fails += 1
            continue
        errs.append(corner_error_px(r.prev_H_cur, flight.truth.frames[k].prev_H_cur, flight.camera.width,
                                    flight.camera.height))
    errs_a = np.array(errs)
    core = errs_a[errs_a <= 2.0]
    return {'pairs': len(feats) - 1, 'failed': fails, 'gross_over_2px': int((errs_a > 2.0).sum()),
            'mean_corner_error_px': float(errs_a.mean()), 'median_corner_error_px': float(np.median(errs_a)),
            'p90_corner_error_px': float(np.percentile(errs_a, 90)),
            'sigma_px': float(core.mean()) / math.sqrt(math.pi / 2.0)}


def registrations(flight: SimulatedFlight, sigma_px: float, seed: int) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """Per frame (prev_H_cur with corner noise, its (8, 8) covariance of h); None for frame 0."""
    rng = np.random.default_rng(seed)
    c = corners_of(flight.camera)
    out: list[tuple[np.ndarray, np.ndarray] | None] = [None]
    for t in flight.truth.frames[1:]:
        H = homography_from_corners(c, apply_H(t.prev_H_cur, c) + rng.normal(0.0, sigma_px, (4, 2)))
        J_inv = np.linalg.inv(corner_jacobian(H, c))
        out.append((H, sigma_px**2 * J_inv @ J_inv.T))
    return out


def run_ukf(flight: SimulatedFlight, regs: list, *, video: bool,
            config: GeorefConfig) -> tuple[Georeferencer, list[FramePose], float]:
    """Feed the flight in stamp order; returns the georeferencer, the causal poses and s per frame."""
    georef = Georeferencer(config, flight.camera)
    events = [(f.stamp_ns, 0, f) for f in flight.fixes] + [(i.stamp_ns, 1, i) for i in flight.imus]
    events += [(fr.stamp_ns, 2, k) for k, fr in enumerate(flight.frames)]
    events.sort(key=lambda e: (e[0], e[1]))
    poses = []
    t0 = time.perf_counter()
    for stamp, kind, item in events:
        if kind == 0:
            georef.feed_fix(item)
        elif kind == 1:
            georef.feed_imu(item)
        else:
            reg = regs[item] if video else None
            poses.append(georef.feed_frame(stamp, *(reg if reg is not None else (None, None))))
    return georef, poses, (time.perf_counter() - t0) / len(flight.frames)


# --- truth and baselines -----------------------------------------------------------------------


def utm_affine(ltp: LocalTangentPlane, epsg: int, centre_en: np.ndarray) -> np.ndarray:
    """(3, 3) affine ENU ground plane (east, north, 1) of ``ltp`` -> UTM, fitted around ``centre_en``."""
    from pyproj import Transformer

    s = np.linspace(-1500.0, 1500.0, 7)
    e, n = np.meshgrid(s + centre_en[0], s + centre_en[1])
    lat, lon, _ = ltp.geodetic_from_enu(np.c_[e.ravel(), n.ravel(), np.zeros(e.size)])
    x, y = Transformer.from_crs(4326, epsg, always_xy=True).transform(lon, lat)
    coef, *_ = np.linalg.lstsq(np.c_[e.ravel(), n.ravel(), np.ones(e.size)], np.c_[x, y], rcond=None)
    A = np.eye(3)
    A[:2] = coef.T
    return A


def truth_positions(georef: Georeferencer, flight: SimulatedFlight) -> np.ndarray:
    return np.array([georef.origin.enu_from_geodetic(t.latitude_deg, t.longitude_deg, t.altitude_m)
                     for t in flight.truth.frames])


def true_raster_H_frames(georef: Georeferencer, flight: SimulatedFlight) -> list[np.ndarray]:
    world = flight.world
    A = utm_affine(world.origin, georef.raster.epsg, np.zeros(2))
    raster_H_world_px = georef.raster.raster_H_utm @ A @ world.enu_H_world_px
    return [normalize_H(raster_H_world_px @ t.world_px_H_frame) for t in flight.truth.frames]


def gps_only(georef: Georeferencer, flight: SimulatedFlight) -> np.ndarray:
    stamps = np.array([f.stamp_ns for f in flight.fixes], dtype=np.float64)
    enu = np.array([georef.origin.enu_from_geodetic(f.latitude_deg, f.longitude_deg, f.altitude_m)
                    for f in flight.fixes])
    at = np.array([fr.stamp_ns for fr in flight.frames], dtype=np.float64)
    return np.stack([np.interp(at, stamps, enu[:, i]) for i in range(3)], axis=1)


def chain_only(georef: Georeferencer, flight: SimulatedFlight, regs: list) -> tuple[list[np.ndarray], np.ndarray]:
    """(raster_H_frame per frame, body ENU positions) from the first fix and IMU sample, then homographies."""
    cam = flight.camera
    t0 = flight.frames[0].stamp_ns
    fix = max((f for f in flight.fixes if f.stamp_ns <= t0), key=lambda f: f.stamp_ns)
    imu = min(flight.imus, key=lambda i: abs(i.stamp_ns - t0))
    p0 = georef.origin.enu_from_geodetic(fix.latitude_deg, fix.longitude_deg, fix.altitude_m)
    rpy0 = rpy_from_R_enu_from_body(matrix_from_quat_xyzw(imu.orientation_xyzw))
    y0 = np.r_[p0, rpy0]
    cam0 = georef.mount.camera_pose(y0)
    raster_H_enu = georef.raster_H_enu()
    enu_H_raster = np.linalg.inv(raster_H_enu)
    H = normalize_H(raster_H_enu @ ground_H_image(cam.K, cam0.R_enu_from_cam, cam0.center_enu_m))
    placed, positions = [H], [p0]
    for reg in regs[1:]:
        H = normalize_H(H @ reg[0])
        placed.append(H)
        pose = camera_pose_from_enu_H_image(cam.K, enu_H_raster @ H)
        positions.append(georef.mount.body_pose(pose)[:3])
    return placed, np.array(positions)


def drift_controlled(georef: Georeferencer, poses: list[FramePose], regs: list) -> list[np.ndarray]:
    georef.reset_drift(new_canvas=True)
    placed = [georef.correct(georef.raster_H_frame(poses[0]), poses[0])]
    for pose, reg in zip(poses[1:], regs[1:]):
        placed.append(georef.correct(placed[-1] @ reg[0], pose, chain_sigma_px=georef.corner_sigma_px(*reg)))
    return placed


def reanchored(georef: Georeferencer, poses: list[FramePose], placed: list[np.ndarray]) -> list[np.ndarray]:
    """The placements as the product's outputs georeference them (app.georeference.anchored_raster): the
    least-squares similarity from the placed corners to the corners predicted by the smoothed
    poses, applied to the whole mosaic (core/georef/anchoring.py)."""
    c = corners_of(georef.camera)
    fix = fit_similarity(np.concatenate([apply_H(H, c) for H in placed]),
                         np.concatenate([apply_H(georef.raster_H_frame(p), c) for p in poses]))
    return [fix @ H for H in placed]


# --- figures -----------------------------------------------------------------------------------


def position_figures(est: np.ndarray, truth: np.ndarray, first: int) -> dict[str, float]:
    """Errors (m) of est (N, 3) against truth (N, 3); ``first``: the frames of the first 5 s (the
    filter still learning the ground height and the velocity)."""
    d = est - truth
    h = np.linalg.norm(d[:, :2], axis=1)
    return {'rmse_h_m': float(np.sqrt(np.mean(h**2))), 'rmse_v_m': float(np.sqrt(np.mean(d[:, 2] ** 2))),
            'max_h_m': float(h.max()), 'last_h_m': float(h[-1]),
            'rmse_h_first_5s_m': float(np.sqrt(np.mean(h[:first] ** 2)))}


def ground_nees(georef: Georeferencer, poses: list[FramePose]) -> float:
    """Mean normalised estimation error squared of the causal ground height over ``poses`` (the
    simulated ground is at ellipsoidal height 0)."""
    vals = [(georef.origin.alt0_m + p.ground_z_m) ** 2 / float(p.ground_covariance[-1]) for p in poses
            if p.valid and p.ground_covariance is not None and p.ground_covariance[-1] > 0]
    return float(np.mean(vals)) if vals else float('nan')


def closure_pairs(flight: SimulatedFlight, min_gap: int = 60, step: int = 5) -> list[tuple[int, int, np.ndarray]]:
    """(i, j, pixels of frame i) for frames of different legs that see the same ground (true geometry)."""
    cam = flight.camera
    grid = np.array([[x, y] for x in np.linspace(20, cam.width - 21, 5) for y in np.linspace(20, cam.height - 21, 4)])
    world = [t.world_px_H_frame for t in flight.truth.frames]
    out = []
    for i in range(0, len(world), step):
        for j in range(i + min_gap, len(world), step):
            q = apply_H(np.linalg.inv(world[j]) @ world[i], grid)
            inside = (q[:, 0] > 0) & (q[:, 0] < cam.width - 1) & (q[:, 1] > 0) & (q[:, 1] < cam.height - 1)
            if inside.sum() >= 4:
                out.append((i, j, grid[inside]))
    return out


def mosaic_figures(placed: list[np.ndarray], truth: list[np.ndarray], flight: SimulatedFlight, gsd: float,
                   pairs: list) -> dict[str, float]:
    cam = flight.camera
    w, h = cam.width, cam.height
    err, _ = mosaic_corner_errors(placed, truth, w, h)
    seams = [corner_error_px(np.linalg.inv(a) @ b, t.prev_H_cur, w, h)
             for a, b, t in zip(placed, placed[1:], flight.truth.frames[1:])]
    grid = np.array([[x, y] for x in np.linspace(0, w - 1, 5) for y in np.linspace(0, h - 1, 5)])
    geo = np.concatenate([np.linalg.norm(apply_H(a, grid) - apply_H(b, grid), axis=1) for a, b in zip(placed, truth)])
    world_from = [t.world_px_H_frame for t in flight.truth.frames]
    closure = []
    for i, j, pix in pairs:
        pj = apply_H(np.linalg.inv(world_from[j]) @ world_from[i], pix)
        closure.append(np.linalg.norm(apply_H(placed[i], pix) - apply_H(placed[j], pj), axis=1))
    out = {
        'geometric_rms_px': float(np.sqrt(np.mean(err**2))),
        'geometric_last_px': float(err[-1]),
        'seam_mean_px': float(np.mean(seams)),
        'georef_rms_m': float(np.sqrt(np.mean(geo**2)) * gsd),
        'georef_p95_m': float(np.percentile(geo, 95) * gsd),
    }
    if closure:
        out['closure_rms_px'] = float(np.sqrt(np.mean(np.concatenate(closure) ** 2)))
    return out


def paint(flight: SimulatedFlight, placed: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(image float32 (H, W, 3), coverage (H, W) bool, mosaic_H_raster) of the frames on the raster grid."""
    cam = flight.camera
    c = np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5], [cam.width - 0.5, cam.height - 0.5], [-0.5, cam.height - 0.5]])
    pts = np.concatenate([apply_H(H, c) for H in placed])
    x0, y0 = np.floor(pts.min(axis=0)).astype(int)
    x1, y1 = np.ceil(pts.max(axis=0)).astype(int)
    shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    size = (int(x1 - x0 + 1), int(y1 - y0 + 1))
    image = np.zeros((size[1], size[0], 3), np.float32)
    coverage = np.zeros((size[1], size[0]), np.uint8)
    ones = np.full((cam.height, cam.width), 255, np.uint8)
    ones[:2], ones[-2:], ones[:, :2], ones[:, -2:] = 0, 0, 0, 0
    for frame, H in zip(flight.frames, placed):
        warped = cv2.warpPerspective(frame.image.astype(np.float32) / 255.0, shift @ H, size, flags=cv2.INTER_LINEAR)
        m = cv2.warpPerspective(ones, shift @ H, size, flags=cv2.INTER_NEAREST) > 0
        image[m] = warped[m]
        coverage |= m
    return image, coverage.astype(bool), shift


def write_products(out: Path, flight: SimulatedFlight, georef: Georeferencer, poses: list[FramePose],
                   placed: list[np.ndarray]) -> None:
    image, coverage, shift = paint(flight, placed)
    raster = georef.raster.shifted(-shift[0, 2], -shift[1, 2])
    write_geotiff(out / 'mosaic.tif', image, raster, coverage=coverage)
    write_png(out / 'mosaic.png', image, coverage)
    write_kml_for_raster(out / 'mosaic.kml', 'mosaic.png', raster, image.shape[1], image.shape[0],
                         name=f'srmosaic bench: {flight.config.trajectory}')
    write_poses_csv(out / 'poses.csv', poses)


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), 2, figsize=(14, 5.2 * len(results)), squeeze=False,
                             gridspec_kw={'width_ratios': [1.6, 1]})
    for row, (name, r) in enumerate(results.items()):
        ax, ax2 = axes[row]
        tr, gps, chain, ukf = r['truth'], r['gps'], r['chain'], r['ukf']
        ax.plot(gps[:, 0], gps[:, 1], '.', color='0.6', ms=2.5, label='GPS-only (fixes)')
        ax.plot(chain[:, 0], chain[:, 1], '-', color='tab:red', lw=1.2, label='homography chaining from the first fix')
        ax.plot(ukf[:, 0], ukf[:, 1], '-', color='tab:blue', lw=1.2, label='UKF (GNSS + IMU + video)')
        ax.plot(tr[:, 0], tr[:, 1], '--', color='k', lw=1.0, label='truth')
        ax.set_aspect('equal', adjustable='datalim')
        ax.set_xlabel('east (m)')
        ax.set_ylabel('north (m)')
        ax.set_title(f'{name}: {len(tr)} frames at 100 m')
        ax.legend(loc='best', fontsize=8)
        k = np.arange(len(tr))
        for est, label, color in ((gps, 'GPS-only', '0.5'), (chain, 'chaining', 'tab:red'), (ukf, 'UKF', 'tab:blue'),
                                  (r['ukf_s'], 'UKF smoothed (offline)', 'tab:cyan')):
            ax2.plot(k, np.linalg.norm((est - tr)[:, :2], axis=1), color=color, lw=1.0, label=label)
        ax2.set_yscale('log')
        ax2.set_xlabel('frame')
        ax2.set_ylabel('horizontal position error (m)')
        ax2.grid(True, which='both', alpha=0.3)
        ax2.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --- main --------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--quick', action='store_true', help='120 frames per flight (smoke run)')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--sigma-px', type=float, default=None,
                    help="corner noise of the registrations (default: calibrated on the pipeline's registrar)")
    ap.add_argument('--pose-time-constant', type=float, default=None, metavar='S',
                    help='georef.drift_pose_time_constant_s (default: NaN, from the filter; 0: poses independent '
                         'from frame to frame)')
    ap.add_argument('--nominal-agl-sigma', type=float, default=None, metavar='M',
                    help='georef.nominal_agl_sigma_m (default: params/default.yaml\'s)')
    ap.add_argument('--altitude', type=float, default=None, metavar='M',
                    help='flight height above the ground (default 100 m, which is also georef.nominal_agl_m: '
                         'the ground prior is then exactly right; other heights test the filter while it learns '
                         'the ground)')
    ap.add_argument('--ut-iterations', type=int, default=None, metavar='N',
                    help="georef.ut_iterations (default: params/default.yaml's; 1: one UKF pass per homography)")
    ap.add_argument('--out', type=Path, default=ROOT / 'bench' / 'out')
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    t_start = time.perf_counter()
    overrides = {}
    if args.pose_time_constant is not None:
        overrides['drift_pose_time_constant_s'] = args.pose_time_constant
    if args.nominal_agl_sigma is not None:
        overrides['nominal_agl_sigma_m'] = args.nominal_agl_sigma
    if args.ut_iterations is not None:
        overrides['ut_iterations'] = args.ut_iterations
    config = GeorefConfig(**overrides)
    results, table = {}, {}
    calibration = None
    for name, opts in FLIGHTS.items():
        sim_opts = dict(BASE, **opts, seed=args.seed)
        if args.altitude is not None:
            sim_opts['altitude_m'] = args.altitude
        if args.quick:
            sim_opts['frames'] = 120
        t0 = time.perf_counter()
        flight = simulate(SimConfig(**sim_opts))
        t_sim = time.perf_counter() - t0
        if calibration is None:
            calibration = calibrate_registrar(flight, 120)
            sigma = args.sigma_px if args.sigma_px is not None else calibration['sigma_px']
            print(f'registrar calibration (pipeline registrar, {name} frames 0..{calibration["pairs"]}): corner error '
                  f'mean {calibration["mean_corner_error_px"]:.3f} px, '
                  f'median {calibration["median_corner_error_px"]:.3f}'
                  f', p90 {calibration["p90_corner_error_px"]:.3f}; {calibration["failed"]} failed, '
                  f'{calibration["gross_over_2px"]} over 2 px; the bench registrations get sigma {sigma:.3f} px per '
                  'corner coordinate')
        regs = registrations(flight, sigma, args.seed + 1)
        georef, poses, ms_ukf = run_ukf(flight, regs, video=True, config=config)
        georef_nv, poses_nv, _ = run_ukf(flight, regs, video=False, config=config)
        georef.make_raster(poses[0])
        truth = truth_positions(georef, flight)
        truth_placed = true_raster_H_frames(georef, flight)
        chain_placed, chain_pos = chain_only(georef, flight, regs)
        pose_placed = [georef.raster_H_frame(p) for p in poses]
        corrected = drift_controlled(georef, poses, regs)
        smoothed = georef.smoothed_poses()
        corrected_smoothed = drift_controlled(georef, smoothed, regs)
        corrected_outputs = reanchored(georef, smoothed, corrected)
        gps = gps_only(georef, flight)
        # the no-video filter has its own origin (the same first fix): express in the same plane
        nv = np.array([georef.origin.enu_from_geodetic(p.latitude_deg, p.longitude_deg, p.altitude_m)
                       for p in poses_nv])
        ukf = np.array([p.position_enu_m for p in poses])
        ukf_s = np.array([p.position_enu_m for p in smoothed])
        pairs = closure_pairs(flight)
        first = int(sum(fr.stamp_ns - flight.frames[0].stamp_ns < 5_000_000_000 for fr in flight.frames))
        gsd = georef.raster.gsd_m_per_px
        table[name] = {
            'frames': len(flight.frames),
            'position': {
                'gps_only': position_figures(gps, truth, first),
                'chaining': position_figures(chain_pos, truth, first),
                'ukf_no_video': position_figures(nv, truth, first),
                'ukf': position_figures(ukf, truth, first),
                'ukf_smoothed': position_figures(ukf_s, truth, first),
            },
            'mosaic': {
                'chained (no drift control)': mosaic_figures(chain_placed, truth_placed, flight, gsd, pairs),
                'pose only': mosaic_figures(pose_placed, truth_placed, flight, gsd, pairs),
                'drift control': mosaic_figures(corrected, truth_placed, flight, gsd, pairs),
                'drift control, re-anchored': mosaic_figures(corrected_outputs, truth_placed, flight, gsd, pairs),
                'smoothed + drift (offline)': mosaic_figures(corrected_smoothed, truth_placed, flight, gsd, pairs),
            },
            'gsd_m_per_px': gsd,
            'ground_altitude_estimate_m': georef.origin.alt0_m + georef.ground_z_m,
            # consistency of the causal ground estimate (truth: ellipsoidal height 0): ~1 when the
            # filter knows what it knows; the first 5 s are where the ground is learnt
            'ground_nees_first_5s': ground_nees(georef, poses[:first]),
            'ground_nees_all': ground_nees(georef, poses),
            'ukf_ms_per_frame': ms_ukf * 1e3,
            'skipped': dict(georef.skipped),
            'updates': dict(georef.updates),
            'simulate_s': t_sim,
        }
        results[name] = {'truth': truth, 'gps': gps, 'chain': chain_pos, 'ukf': ukf, 'ukf_s': ukf_s}
        write_products(args.out / name, flight, georef, smoothed, corrected_smoothed)
    plot(results, args.out / 'georef_trajectories.png')
    wall = time.perf_counter() - t_start
    write_json(args.out / 'georef.json', {'calibration': calibration, 'flights': table, 'wall_s': wall,
                                          'sigma_px': sigma, 'goals': GOALS})

    print(f'\nposition of the body at each frame against the truth (m); sigma_reg = {sigma:.3f} px')
    print(f'{"flight":10s} {"estimator":16s} {"RMSE h":>8s} {"RMSE v":>8s} {"max h":>8s} {"last h":>8s} '
          f'{"h 0-5 s":>8s}')
    for name, t in table.items():
        for est, f in t['position'].items():
            print(f'{name:10s} {est:16s} {f["rmse_h_m"]:8.2f} {f["rmse_v_m"]:8.2f} {f["max_h_m"]:8.2f} '
                  f'{f["last_h_m"]:8.2f} {f["rmse_h_first_5s_m"]:8.2f}')
    print('\nmosaic on the UTM raster (px at the raster gsd; m on the ground)')
    print(f'{"flight":10s} {"placement":27s} {"geom RMS":>9s} {"geom last":>9s} {"seam":>7s} {"closure":>8s} '
          f'{"georef RMS":>10s} {"p95":>6s}')
    for name, t in table.items():
        for how, f in t['mosaic'].items():
            closure = f'{f["closure_rms_px"]:8.2f}' if 'closure_rms_px' in f else f'{"-":>8s}'
            print(f'{name:10s} {how:27s} {f["geometric_rms_px"]:9.2f} {f["geometric_last_px"]:9.2f} '
                  f'{f["seam_mean_px"]:7.2f} {closure} {f["georef_rms_m"]:10.2f} {f["georef_p95_m"]:6.2f}')
    print('\ngoals')
    ok_all = True
    for name, t in table.items():
        p, m, out = t['position'], t['mosaic']['drift control'], t['mosaic']['drift control, re-anchored']
        checks = [
            (f'fused RMSE h <= {GOALS["fused_over_gps"]} x GPS-only', p['ukf']['rmse_h_m'],
             GOALS['fused_over_gps'] * p['gps_only']['rmse_h_m']),
            (f'georef error of mosaic points <= {GOALS["georef_rms_m"]} m RMS (outputs)', out['georef_rms_m'],
             GOALS['georef_rms_m']),
            (f'mosaic geometric error after {t["frames"]} frames <= {GOALS["mosaic_px"]} px', m['geometric_last_px'],
             GOALS['mosaic_px']),
            (f'  same, RMS over all {t["frames"]} frames <= {GOALS["mosaic_px"]} px', m['geometric_rms_px'],
             GOALS['mosaic_px']),
        ]
        for what, got, bound in checks:
            ok = got <= bound
            ok_all &= ok
            print(f'  {name:10s} {what:48s} {got:7.2f} vs {bound:5.2f}  {"ok" if ok else "MISSED"}')
        print(f'  {name:10s} UKF {t["ukf_ms_per_frame"]:.1f} ms/frame, ground altitude estimate '
              f'{t["ground_altitude_estimate_m"]:+.2f} m (truth 0), its NEES {t["ground_nees_first_5s"]:.2f} over '
              f'the first 5 s and {t["ground_nees_all"]:.2f} over the flight, skipped {t["skipped"] or "nothing"}')
    print(f'\nwrote {args.out / "georef_trajectories.png"}, {args.out / "georef.json"} and '
          f'{", ".join(str(args.out / n) for n in table)}/{{mosaic.tif,mosaic.png,mosaic.kml,poses.csv}}; '
          f'{wall:.0f} s')
    return 0 if ok_all else 1


if __name__ == '__main__':
    raise SystemExit(main())
