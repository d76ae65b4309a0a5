"""Frame centres of a real run against the footage's own metadata positions, in metres.

frames.csv's optional ``meta_latitude,meta_longitude`` (WGS84 degrees) against each main frame's
centre pixel through mosaic_H_frame and mosaic.tif's geotransform (evaluate_real.py's module
docstring, "Position error").
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..core.metrics import apply_homography

__all__ = ['META_COLUMNS', 'read_meta_positions']

#: Optional trailing columns of frames.csv: the frame centre on the ground by the footage's metadata.
META_COLUMNS = ('meta_latitude', 'meta_longitude')


def read_meta_positions(frames_csv: Path) -> dict[int, tuple[float, float]]:
    """stamp_ns -> (meta_latitude, meta_longitude) in WGS84 degrees, for the rows of ``frames_csv``
    whose metadata gives both as finite numbers; {} when the file has no such columns. A row with a
    value that is not a number is left out (as unknown), never an error."""
    out: dict[int, tuple[float, float]] = {}
    with open(frames_csv, newline='') as handle:
        reader = csv.DictReader(handle)
        if not set(META_COLUMNS) <= set(reader.fieldnames or []):
            return out
        for rec in reader:
            try:
                stamp = int(rec['stamp_ns'])
                lat, lon = float(rec['meta_latitude']), float(rec['meta_longitude'])
            except (TypeError, ValueError):
                continue
            if math.isfinite(lat) and math.isfinite(lon):
                out[stamp] = (lat, lon)
    return out



def _position_figures(out_dir: Path, main: list[dict[str, Any]], meta: dict[int, tuple[float, float]],
                      size: tuple[int, int], report: dict[str, Any]) -> tuple[dict[str, Any] | None, dict[int, float], str]:
    """(position summary or None, stamp_ns -> error_m, why None) of the main frames with metadata.

    ``size``: (w, h) of the frames (a flight's frames share one size: a size change ends a run);
    ``report``: the run's report.json (its not_georeferenced_reason says why there is no mosaic.tif).
    """
    tif = out_dir / 'mosaic.tif'
    if not tif.is_file():
        # its first clause (report.json keeps the whole reason, the way out included)
        why = re.split(r'\. |: |; ', str(report.get('not_georeferenced_reason') or ''))[0].rstrip('.')
        return None, {}, f'no mosaic.tif (the run is not georeferenced{": " + why if why else ""})'
    if not meta:
        with open(out_dir / 'frames.csv', newline='') as handle:
            has_columns = set(META_COLUMNS) <= set(next(csv.reader(handle), []))
        return None, {}, ('no frame has a metadata position: meta_latitude/meta_longitude all NaN' if has_columns
                          else 'frames.csv has no meta_latitude/meta_longitude')
    use = [r for r in main if r['stamp_ns'] in meta]
    if not use:
        return None, {}, 'no frame of the main mosaic has a metadata position'
    import rasterio
    from pyproj import Transformer

    with rasterio.open(tif) as ds:
        affine, crs = ds.transform, ds.crs
    if crs is None:
        return None, {}, f'{tif} has no CRS'
    w, h = size
    centre = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
    # rasterio's affine maps pixel corners: the centre of pixel (x, y) is at (x + 0.5, y + 0.5)
    est = np.array([affine @ tuple(apply_homography(r['mosaic_H_frame'], centre)[0] + 0.5) for r in use])
    to_map = Transformer.from_crs('EPSG:4326', crs, always_xy=True)
    lon_lat = np.array([(meta[r['stamp_ns']][1], meta[r['stamp_ns']][0]) for r in use])
    ref = np.c_[to_map.transform(lon_lat[:, 0], lon_lat[:, 1])]
    err = np.linalg.norm(est - ref, axis=1)
    epsg = crs.to_epsg()
    summary = {'frames': len(use), 'rms_m': float(np.sqrt(np.mean(err ** 2))), 'median_m': float(np.median(err)),
               'max_m': float(err.max()), 'crs': f'EPSG:{epsg}' if epsg is not None else crs.to_string()}
    return summary, {r['stamp_ns']: float(e) for r, e in zip(use, err)}, ''

