"""Real footage in, georeferenced out: the figures of the metadata issue on ../shared/data/real.

For each input: `srmosaic process`, then the truth-free figures of `srmosaic evaluate` (frames in
the main mosaic, frame-to-mosaic consistency, sharpness, frame centres against the footage's own
GPS/KLV), and a picture: the mosaic with what the metadata says drawn over it (the KLV footprint
corners and frame centres for video, the GPS positions for stills), placed through mosaic.tif.

    .venv/bin/python bench/real_metadata.py [--out bench/out/real_metadata] [--only aphill]
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REAL = Path(__file__).resolve().parents[1].parent / 'shared' / 'data' / 'real'
INPUTS = {
    'aphill': REAL / 'klv' / 'aphill_short.ts',
    'karma': REAL / 'gopro' / 'karma.mp4',
    'caliterra': REAL / 'surveys' / 'caliterra' / 'images',
}


def overlay(out_dir: Path, picture: Path, *, klv: Path | None = None, max_side: int = 1600) -> None:
    """mosaic.png with the metadata's positions drawn over it: KLV corners (green) and centres
    (red crosses) or the stills' GPS positions (red), and the frame centres as placed (blue)."""
    import rasterio
    from pyproj import Transformer

    from srmosaic_ros.core.metrics import apply_homography
    from srmosaic_ros.app.evaluate_real import read_meta_positions
    from srmosaic_ros.io.mosaic_files import read_frames_csv

    rgba = cv2.imread(str(out_dir / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    with rasterio.open(out_dir / 'mosaic.tif') as ds:
        inv, crs = ~ds.transform, ds.crs.to_epsg()
    to_map = Transformer.from_crs(4326, crs, always_xy=True)

    def pix(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        e, n = to_map.transform(lon, lat)
        return np.array([inv * (x, y) for x, y in zip(np.atleast_1d(e), np.atleast_1d(n))]) - 0.5

    h, w = rgba.shape[:2]
    scale = min(1.0, max_side / max(h, w))
    base = rgba[..., :3].copy()
    base[rgba[..., 3] == 0] = 40
    img = cv2.resize(base, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)

    def pt(p: np.ndarray) -> tuple[int, int]:
        return round(float(p[0]) * scale), round(float(p[1]) * scale)

    if klv is not None:
        from srmosaic_ros.io.klv import read_klv

        for rec in read_klv(klv).records[::6]:
            f = rec.fields
            if 'corner_latitude_deg' in f:
                poly = pix(np.array(f['corner_latitude_deg']), np.array(f['corner_longitude_deg']))
                cv2.polylines(img, [np.array([pt(p) for p in poly], np.int32)], True, (0, 220, 0), 2)
    rows = read_frames_csv(out_dir / 'frames.csv')
    meta = read_meta_positions(out_dir / 'frames.csv')
    for r in rows:
        if not r['ok']:
            continue
        fw, fh = _frame_size(out_dir)
        c = apply_homography(r['mosaic_H_frame'], np.array([[(fw - 1) / 2.0, (fh - 1) / 2.0]]))[0]
        cv2.circle(img, pt(c), 4, (255, 80, 0), -1)
        if r['stamp_ns'] in meta:
            lat, lon = meta[r['stamp_ns']]
            m = pix(np.array([lat]), np.array([lon]))[0]
            cv2.drawMarker(img, pt(m), (0, 0, 255), cv2.MARKER_CROSS, 12, 2)
            cv2.line(img, pt(c), pt(m), (0, 0, 255), 1)
    cv2.imwrite(str(picture), img)


def _frame_size(out_dir: Path) -> tuple[int, int]:
    report = json.loads((out_dir / 'report.json').read_text())
    seg = report.get('frame_size_px')
    if seg:
        return int(seg[0]), int(seg[1])
    from srmosaic_ros.app.process import open_source
    from srmosaic_ros.core.types import Frame

    items, _, _ = open_source(Path(report['input']))
    frame = next(it for it in items if isinstance(it, Frame))
    report['frame_size_px'] = [frame.image.shape[1], frame.image.shape[0]]
    (out_dir / 'report.json').write_text(json.dumps(report, indent=2))
    return frame.image.shape[1], frame.image.shape[0]


def main() -> int:
    from srmosaic_ros.config import PipelineConfig
    from srmosaic_ros.app.evaluate_real import evaluate_real, format_real_figures
    from srmosaic_ros.app.process import process_input

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, default=Path(__file__).parent / 'out' / 'real_metadata')
    ap.add_argument('--only', nargs='*', default=list(INPUTS), choices=list(INPUTS))
    args = ap.parse_args()
    if not REAL.is_dir():
        print(f'{REAL} not found: this benchmark reads the shared real footage', file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.only:
        out = args.out / name
        shutil.rmtree(out, ignore_errors=True)  # outputs of an earlier run must not pass for this one's
        t0 = time.perf_counter()
        report = process_input(INPUTS[name], out, PipelineConfig(), progress=False)
        wall = time.perf_counter() - t0
        geo = report.get('georeferenced') or {}
        print(f'== {name}: {report["frames_registered"]}/{report["frames_in"]} frames in mosaic.png, '
              f'{len(report["segments"])} segment(s), {wall:.0f} s, peak {report["peak_rss_mb"]:.0f} MB; '
              f'georeferenced: {geo.get("method", "no: " + str(report.get("not_georeferenced_reason")))}; '
              f'metadata: {report["metadata"]["source"]} {report["metadata"]["fields"]}')
        for line in format_real_figures(evaluate_real(out, progress=False)):
            print('   ', line)
        if (out / 'mosaic.tif').is_file():
            picture = args.out / f'{name}_on_metadata.png'
            overlay(out, picture, klv=INPUTS[name] if INPUTS[name].suffix == '.ts' else None)
            print(f'    picture: {picture}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
