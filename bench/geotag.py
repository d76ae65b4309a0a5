"""Benchmark: georeferencing by geotags (core/georef/geotag_fit.py) against the truth of simulated surveys.

Stills 2 s apart over a 2-leg lawnmower (160 m legs, 50 m apart, 100 m above the ground, 320x240,
no camera model given to the pipeline), with GNSS noise sigma_h and the camera off nadir by gusts of
RMS tilt. Prints, per case, the error of mosaic points (centre and two corners of every frame,
mosaic.tif's geotransform against the simulator's ground truth) and, for scale, what one geotag
alone is off (the GNSS noise plus the tilt's displacement of the frame centre), the fit's residual
RMS and the fitted scale against the true ground sampling distance.

    python bench/geotag.py [--seeds 3] [--out /tmp/bench_geotag]
"""
from __future__ import annotations

import argparse
import csv
import logging
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import rasterio
from pyproj import Transformer

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.georef.geodetic import LocalTangentPlane
from srmosaic_ros.core.georef.ground_homography import apply_H, ground_H_image
from srmosaic_ros.app.process import process_input
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.record import write_stills_folder

CASES = [(2.5, 0.1), (2.5, 0.5), (2.5, 2.0), (5.0, 0.5), (1.0, 0.1)]  # (GNSS sigma m, tilt deg RMS)


def run_case(sigma_h: float, tilt_deg: float, seed: int, work: Path) -> dict[str, float]:
    flight = simulate(SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='lawnmower', legs=2,
                                leg_length_m=160.0, leg_spacing_m=50.0, speed_m_s=10.0, rate_hz=0.5, fix_rate_hz=0.5,
                                gust_deg=tilt_deg, gps_sigma_h_m=sigma_h, seed=seed))
    folder = work / f'survey_{sigma_h}_{tilt_deg}_{seed}'
    write_stills_folder(flight, folder)
    report = process_input(folder, folder / 'out', pipeline_config(), progress=False)
    geo = report['georeferenced']
    with rasterio.open(folder / 'out' / 'mosaic.tif') as ds:
        transform = ds.transform
    rows = list(csv.DictReader(open(folder / 'out' / 'frames.csv')))
    ltp = LocalTangentPlane(*flight.truth.origin)
    to_utm = Transformer.from_crs(4326, geo['epsg'], always_xy=True)
    cam = flight.camera
    err, tag_err = [], []
    fix_at = {f.stamp_ns: f for f in flight.fixes}
    for row, t in zip(rows, flight.truth.frames):
        H = np.array([float(row[f'h{i}{j}']) for i in range(3) for j in range(3)]).reshape(3, 3)
        ground_H = ground_H_image(cam.K, t.R_enu_from_cam, t.camera_enu_m)
        for px in ([cam.cx, cam.cy], [0.0, 0.0], [cam.width - 1.0, cam.height - 1.0]):
            m = apply_H(H, np.array([px]))[0]
            e, n = transform @ (m[0] + 0.5, m[1] + 0.5)
            g = apply_H(ground_H, np.array([px]))[0]
            lat, lon, _ = ltp.geodetic_from_enu(np.array([g[0], g[1], 0.0]))
            err.append(math.dist((e, n), to_utm.transform(float(lon), float(lat))))
        g = apply_H(ground_H, np.array([[cam.cx, cam.cy]]))[0]
        lat, lon, _ = ltp.geodetic_from_enu(np.array([g[0], g[1], 0.0]))
        fix = fix_at[t.stamp_ns]
        tag_err.append(math.dist(to_utm.transform(fix.longitude_deg, fix.latitude_deg),
                                 to_utm.transform(float(lon), float(lat))))
    err_a = np.array(err)
    return {'rms_m': float(np.sqrt(np.mean(err_a**2))), 'max_m': float(err_a.max()),
            'tag_rms_m': float(np.sqrt(np.mean(np.square(tag_err)))), 'residual_rms_m': geo['geotag_residual_rms_m'],
            'scale_err': geo['gsd_m_per_px'] / (flight.config.altitude_m / cam.fx) - 1.0, 'frames': len(rows)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seeds', type=int, default=3)
    ap.add_argument('--out', type=Path, default=None, help='work folder (default: a temporary one)')
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)  # the per-run notes (no intrinsics, no attitude) are expected here
    work = args.out or Path(tempfile.mkdtemp(prefix='bench_geotag_'))
    print(f'{"GNSS sigma":>10s} {"tilt":>6s} {"frames":>6s} {"one tag":>8s} {"fit resid":>9s} {"mosaic RMS":>10s} '
          f'{"max":>6s} {"scale err":>9s}   (m; mean over {args.seeds} seeds)')
    for sigma_h, tilt in CASES:
        res = [run_case(sigma_h, tilt, seed, work) for seed in range(args.seeds)]
        mean = {k: float(np.mean([r[k] for r in res])) for k in res[0]}
        print(f'{sigma_h:10.1f} {tilt:6.1f} {mean["frames"]:6.0f} {mean["tag_rms_m"]:8.2f} {mean["residual_rms_m"]:9.2f} '
              f'{mean["rms_m"]:10.2f} {mean["max_m"]:6.2f} {100 * mean["scale_err"]:+8.2f}%')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
