"""Whole surveys: the caliterra stills (../shared/data/real/surveys/caliterra) aligned globally,
against the chained pipeline on the same stills and beside OpenDroneMap's orthomosaic.

Prints, for `survey.mode: global` (the default for stills with GPS) and `survey.mode: chain`: the
truth-free figures of `srmosaic evaluate` (frames in the main mosaic, consistency, sharpness,
frame centres against the stills' own GPS), wall time, frames/s and peak memory; and the
agreement of the global mosaic with ODM's (a homography fitted to SIFT matches between the two,
its inlier residual in metres). Writes to --out:
- caliterra_vs_odm.jpg: the global mosaic and ODM's side by side at ODM's ground sampling distance;
- caliterra_pairs.jpg: the mosaic with each still's centre (blue), its GPS position (red, joined to
  its centre) and the registered pairs the solve used (green) or dropped (red).

And, with --sim, the accuracy cost of the working resolution on simulated truth: a lawnmower of
2000x1500 stills (EXIF/XMP, GNSS sigma 2.5 m) registered at survey.working_megapixels 0.25, 1 and
3 (full size), each: georeferencing error on the ground and mosaic corner error against the truth,
and the time to register; and the same survey with every fifth still textureless (even grey):
the registered stills' corner errors, and each textureless still's centre on the ground against
the truth beside its GPS tag's own error.

    .venv/bin/python bench/survey.py [--out bench/out/survey] [--skip-chain] [--sim]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SURVEY = ROOT.parent / 'shared' / 'data' / 'real' / 'surveys' / 'caliterra'
SRMOSAIC = ROOT / '.venv' / 'bin' / 'srmosaic'


def run(mode: str, out: Path) -> dict:
    params = out.parent / f'{mode}.yaml'
    params.write_text(f'srmosaic:\n  ros__parameters:\n    survey:\n      mode: {mode}\n')
    t0 = time.perf_counter()
    subprocess.run([str(SRMOSAIC), 'process', str(SURVEY / 'images'), '--out', str(out), '--params', str(params),
                    '--no-progress'], check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    ev = subprocess.run([str(SRMOSAIC), 'evaluate', str(out), '--no-progress'], check=True, capture_output=True,
                        text=True)
    report = json.loads((out / 'report.json').read_text())
    return {'mode': mode, 'wall_s': round(wall, 1), 'frames_per_s': report.get('frames_per_s'),
            'peak_rss_mb': report.get('peak_rss_mb'), 'evaluate': ev.stdout.strip().splitlines(),
            'survey': {k: v for k, v in report.get('survey', {}).items() if k != 'registration_failures'}}


def odm_agreement(out: Path, dst: Path) -> dict:
    """Homography from ODM's orthomosaic to ours (SIFT, RANSAC); side-by-side picture at ODM's GSD."""
    import rasterio

    ours = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    odm = cv2.imread(str(SURVEY / 'odm_orthomosaic.png'), cv2.IMREAD_UNCHANGED)
    with rasterio.open(out / 'mosaic.tif') as ds:
        gsd = abs(ds.transform.a)
    s = 2000 / max(ours.shape[:2])
    small = cv2.resize(ours, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    sift = cv2.SIFT_create(8000)
    ka, da = sift.detectAndCompute(cv2.cvtColor(small[..., :3], cv2.COLOR_BGR2GRAY), (small[..., 3] > 0).astype(np.uint8))
    kb, db = sift.detectAndCompute(cv2.cvtColor(odm[..., :3], cv2.COLOR_BGR2GRAY), (odm[..., 3] > 0).astype(np.uint8))
    good = [m for m, n in cv2.BFMatcher().knnMatch(db, da, k=2) if m.distance < 0.75 * n.distance]
    pb = np.float32([kb[m.queryIdx].pt for m in good])
    pa = np.float32([ka[m.trainIdx].pt for m in good])
    H, inl = cv2.findHomography(pb, pa, cv2.RANSAC, 3.0)  # ODM px -> our small px
    inl = inl.ravel() > 0
    res = cv2.perspectiveTransform(pb[inl][None], H)[0] - pa[inl]
    m_per_small_px = gsd / s
    odm_gsd = float(np.sqrt(abs(np.linalg.det(H[:2, :2])))) * m_per_small_px
    # side by side at ODM's GSD
    f = gsd / odm_gsd
    ours_at = cv2.resize(ours, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
    h = max(ours_at.shape[0], odm.shape[0])

    def pad(img: np.ndarray) -> np.ndarray:
        base = np.full((h, img.shape[1], 3), 255, np.uint8)
        a = img[..., 3:4] / 255.0
        base[:img.shape[0]] = (img[..., :3] * a + 255 * (1 - a)).astype(np.uint8)
        return base

    side = np.hstack([pad(ours_at), np.full((h, 12, 3), 255, np.uint8), pad(odm)])
    cv2.putText(side, 'srmosaic (global alignment)', (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 2)
    cv2.putText(side, 'OpenDroneMap', (ours_at.shape[1] + 22, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 2)
    cv2.imwrite(str(dst / 'caliterra_vs_odm.jpg'), side, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return {'matches': len(good), 'inliers': int(inl.sum()),
            'residual_rms_m': float(np.sqrt((res**2).sum(axis=1).mean())) * m_per_small_px,
            'odm_gsd_m': odm_gsd, 'rotation_deg': float(np.degrees(np.arctan2(H[1, 0], H[0, 0])))}


def pairs_picture(out: Path, dst: Path, max_side: int = 1600) -> None:
    """The mosaic with the stills' centres, their GPS positions and the pairs of the solve."""
    import rasterio
    from pyproj import Transformer

    from srmosaic_ros.app.evaluate_real import read_meta_positions
    from srmosaic_ros.io.mosaic_files import read_frames_csv
    from srmosaic_ros.app.process import open_source
    from srmosaic_ros.app.survey import survey_stills

    rgba = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    scale = min(1.0, max_side / max(rgba.shape[:2]))
    img = rgba[..., :3].copy()
    img[rgba[..., 3] == 0] = 40
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    rows = read_frames_csv(out / 'frames.csv')
    meta = read_meta_positions(out / 'frames.csv')
    with rasterio.open(out / 'mosaic.tif') as ds:
        inv, epsg = ~ds.transform, ds.crs.to_epsg()
    to_map = Transformer.from_crs(4326, epsg, always_xy=True)
    _, reader, _ = open_source(SURVEY / 'images')
    stills, _, _ = survey_stills(reader)
    centres = []
    for r, st in zip(rows, stills):
        c = r['mosaic_H_frame'] @ [st.K[0, 2], st.K[1, 2], 1.0]
        centres.append(c[:2] / c[2] * scale)
    report = json.loads((out / 'report.json').read_text())
    for (i, j), used in report['survey'].get('pairs_graph', []):
        a, b = centres[i], centres[j]
        cv2.line(img, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), (0, 200, 0) if used else (0, 0, 255), 1,
                 cv2.LINE_AA)
    for r, c in zip(rows, centres):
        if r['stamp_ns'] in meta:
            lat, lon = meta[r['stamp_ns']]
            e, n = to_map.transform(lon, lat)
            g = (np.array(inv * (e, n)) - 0.5) * scale
            cv2.line(img, (int(c[0]), int(c[1])), (int(g[0]), int(g[1])), (0, 0, 255), 1, cv2.LINE_AA)
            cv2.circle(img, (int(g[0]), int(g[1])), 4, (0, 0, 255), -1)
        cv2.circle(img, (int(c[0]), int(c[1])), 4, (255, 80, 0), -1)
    cv2.imwrite(str(dst / 'caliterra_pairs.jpg'), img, [cv2.IMWRITE_JPEG_QUALITY, 88])


def sim_working_resolution(dst: Path) -> list[dict]:
    from srmosaic_ros.config import pipeline_config
    from srmosaic_ros.app.evaluate import evaluate_dir
    from srmosaic_ros.app.process import process_input
    from srmosaic_ros.sim import SimConfig, save_truth, simulate
    from srmosaic_ros.sim.record import write_drone_stills

    root = dst / 'sim'
    if not (root / 'truth.json').is_file():
        flight = simulate(SimConfig(width=2000, height=1500, trajectory='lawnmower', legs=3, leg_length_m=120.0,
                                    leg_spacing_m=60.0, speed_m_s=10.0, rate_hz=0.5, fix_rate_hz=0.5, gust_deg=1.0,
                                    max_supersample=1, seed=5))
        write_drone_stills(flight, root / 'survey')
        save_truth(flight.truth, root / 'truth.json')
    rows = []
    for mp in (0.25, 1.0, 3.0):
        out = root / f'out_{mp:g}mp'
        report = process_input(root / 'survey', out, pipeline_config({'survey.working_megapixels': mp}), progress=False)
        fig = evaluate_dir(out, root / 'truth.json')
        rows.append({'working_megapixels': mp, 'reduction': report['survey']['working_reduction'],
                     'frames': report['frames_in'], 'placed': report['frames_registered'],
                     'georef_error_rms_m': round(fig['georef_error_rms_m'], 3),
                     'corner_error_mean_px': round(fig['corner_error_mean_px'], 3),
                     'corner_error_max_px': round(fig['corner_error_max_px'], 3),
                     'gsd_m': report['georeferenced']['gsd_m_per_px'],
                     'register_s': report['survey']['time_s']['register'], 'wall_s': report['wall_s'],
                     'peak_rss_mb': report['peak_rss_mb']})
    return rows


def sim_textureless(dst: Path, every: int = 5) -> dict:
    """The simulated survey with every ``every``-th still made textureless (even grey, EXIF/XMP
    kept): the others' corner errors against the truth, and each textureless still's centre on
    the ground against the truth beside its own GPS tag's error."""
    import shutil

    import rasterio
    from PIL import Image
    from pyproj import Transformer

    from srmosaic_ros.app.evaluate_real import read_meta_positions
    from srmosaic_ros.app.process import process_input
    from srmosaic_ros.config import pipeline_config
    from srmosaic_ros.core.georef.geodetic import LocalTangentPlane
    from srmosaic_ros.core.metrics import apply_homography, mosaic_corner_errors
    from srmosaic_ros.io.mosaic_files import read_frames_csv
    from srmosaic_ros.sim import load_truth

    root = dst / 'sim'
    folder = root / f'survey_textureless_{every}'
    if not folder.is_dir():
        shutil.copytree(root / 'survey', folder)
        for still in sorted((folder / 'images').iterdir())[every - 1::every]:
            with Image.open(still) as im:
                xmp, exif, size = im.info.get('xmp'), im.getexif(), im.size
            Image.new('RGB', size, (120, 110, 90)).save(still, quality=95, exif=exif, xmp=xmp)
    out = root / f'out_textureless_{every}'
    report = process_input(folder, out, pipeline_config(), progress=False)
    truth = load_truth(root / 'truth.json')
    by_stamp = {f.stamp_ns: f for f in truth.frames}
    rows = read_frames_csv(out / 'frames.csv')
    placed_by = [r['placed_by'] for r in rows]
    meta = read_meta_positions(out / 'frames.csv')
    w, h = truth.camera.width, truth.camera.height
    reg = [k for k, r in enumerate(rows) if r['ok'] and placed_by[k] == 'registration']
    err, _ = mosaic_corner_errors([rows[k]['mosaic_H_frame'] for k in reg],
                                  [by_stamp[rows[k]['stamp_ns']].world_px_H_frame for k in reg], w, h)
    with rasterio.open(out / 'mosaic.tif') as ds:
        affine, epsg = ds.transform, ds.crs.to_epsg()
    to_utm = Transformer.from_crs(4326, epsg, always_xy=True)
    ltp = LocalTangentPlane(*truth.origin)
    centre = np.array([[w / 2 - 0.5, h / 2 - 0.5]])
    flat = []
    for k, r in enumerate(rows):
        if placed_by[k] == 'registration':
            continue
        f = by_stamp[r['stamp_ns']]
        est = np.array(affine @ tuple(apply_homography(r['mosaic_H_frame'], centre)[0] + 0.5)) if r['ok'] else None
        enu = apply_homography(truth.enu_H_world_px, apply_homography(f.world_px_H_frame, centre))
        lat, lon, _ = ltp.geodetic_from_enu(np.c_[enu, np.zeros(1)])
        true_xy = np.array(to_utm.transform(lon, lat)).ravel()
        cam = np.array(to_utm.transform(f.longitude_deg, f.latitude_deg))
        lat_tag, lon_tag = meta[r['stamp_ns']]
        gps = np.array(to_utm.transform(lon_tag, lat_tag))
        flat.append({'index': k, 'placed_by': placed_by[k],
                     'centre_error_m': None if est is None else round(float(np.linalg.norm(est - true_xy)), 2),
                     'gps_error_m': round(float(np.linalg.norm(gps - cam)), 2)})
    return {'stills': len(rows), 'textureless': len(flat), 'placed_by': report['placed_by'],
            'registered_corner_error_rms_px': round(float(np.sqrt(np.mean(err ** 2))), 3),
            'registered_corner_error_max_px': round(float(err.max()), 3),
            'gsd_m': report['georeferenced']['gsd_m_per_px'], 'textureless_stills': flat}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, default=ROOT / 'bench' / 'out' / 'survey')
    ap.add_argument('--skip-chain', action='store_true', help='only the global alignment')
    ap.add_argument('--sim', action='store_true', help='also the working-resolution cost on a simulated survey')
    ap.add_argument('--sim-only', action='store_true', help='only that')
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.sim_only:
        caliterra(args)
    if args.sim or args.sim_only:  # in this process, after the runs (a child inherits its parent's peak RSS)
        sim = sim_working_resolution(args.out)
        for r in sim:
            print(f"simulated 2000x1500 survey at {r['working_megapixels']:g} MP (reduction {r['reduction']}): "
                  f"{r['placed']}/{r['frames']} placed, georef {r['georef_error_rms_m']} m RMS, corners "
                  f"{r['corner_error_mean_px']} px mean / {r['corner_error_max_px']} max (mosaic px of "
                  f"{r['gsd_m']:.3f} m), register {r['register_s']} s, wall {r['wall_s']} s, peak {r['peak_rss_mb']} MB")
        flat = sim_textureless(args.out)
        print(f"simulated survey with {flat['textureless']} of {flat['stills']} stills textureless: placed by "
              f"{flat['placed_by']}; registered stills' corners {flat['registered_corner_error_rms_px']} px RMS / "
              f"{flat['registered_corner_error_max_px']} max (mosaic px of {flat['gsd_m']:.3f} m)")
        for t in flat['textureless_stills']:
            print(f"  textureless still {t['index']}: placed by {t['placed_by'] or 'nothing'}, centre "
                  f"{t['centre_error_m']} m from the truth; its GPS tag {t['gps_error_m']} m off")
        (args.out / 'sim_figures.json').write_text(json.dumps({'working_resolution': sim, 'textureless': flat},
                                                              indent=2))
    return 0


def caliterra(args: argparse.Namespace) -> None:
    results = [run('global', args.out / 'global')]
    if not args.skip_chain:
        results.append(run('chain', args.out / 'chain'))
    odm = odm_agreement(args.out / 'global', args.out)
    pairs_picture(args.out / 'global', args.out)
    for r in results:
        print(f"survey.mode {r['mode']}: {r['wall_s']} s, {r['frames_per_s']} frames/s, peak {r['peak_rss_mb']} MB")
        for line in r['evaluate']:
            print('  ' + line)
        if r['survey']:
            s = r['survey']
            print(f"  pairs: {s['pairs_tried']} tried ({s['pairs_consecutive_tried']} consecutive), "
                  f"{s['pairs_registered']} registered, {s['pairs_used']} used, {s['pairs_against_gps']} against "
                  f"the GPS, {s['pairs_dropped']} dropped by the solve; height {s['scale_m']:.1f} m; "
                  f"times {s['time_s']}")
    print(f"against OpenDroneMap's orthomosaic: {odm['inliers']} of {odm['matches']} SIFT matches agree, "
          f"residual {odm['residual_rms_m']:.2f} m RMS (ODM's PNG at {odm['odm_gsd_m']:.3f} m/px, turned "
          f"{odm['rotation_deg']:.2f} deg from ours)")
    (args.out / 'figures.json').write_text(json.dumps({'runs': results, 'odm': odm}, indent=2))


if __name__ == '__main__':
    sys.exit(main())
