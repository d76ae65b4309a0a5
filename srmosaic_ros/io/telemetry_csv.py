"""Flight-log sidecar for video: CSV rows of time and pose -> GeoFix and ImuSample.

Header (one row per log sample, any rate): ``time_s,latitude,longitude,altitude,roll,pitch,yaw``
with time_s in seconds from the video's first frame (the same clock as frames.csv's stamp_ns for
video), WGS84 degrees and metres, and roll/pitch/yaw in degrees of the body (x forward, y left,
z up) in ENU (REP 103; yaw counter-clockwise from east).
"""
from __future__ import annotations

import csv
import logging
import math
from pathlib import Path

import numpy as np

from ..core.georef.frames import R_enu_from_body, quat_xyzw_from_matrix
from ..core.types import GeoFix, ImuSample
from ..errors import InputError

__all__ = ['TELEMETRY_HEADER', 'read_telemetry_csv', 'write_telemetry_csv']

_LOG = logging.getLogger(__name__)

TELEMETRY_HEADER = ['time_s', 'latitude', 'longitude', 'altitude', 'roll', 'pitch', 'yaw']


def read_telemetry_csv(path: str | Path, counts: dict[str, int] | None = None) -> list[GeoFix | ImuSample]:
    """Fixes and IMU orientations of a sidecar, in time order (InputError naming the row when bad).

    Rows earlier than the row before them (a log out of time order) are sorted into place, said in the
    log with the file's name, and counted in ``counts['telemetry_out_of_order']``; rows with a value
    missing (NaN) in ``counts['telemetry_gaps']``.
    """
    path = Path(path)
    counts = {} if counts is None else counts
    counts.setdefault('telemetry_out_of_order', 0)
    counts.setdefault('telemetry_gaps', 0)
    rows = 0
    last_s = -math.inf
    first_line = 0
    try:
        handle = open(path, newline='')
    except FileNotFoundError:
        msg = f'--telemetry {path} does not exist.'
        raise InputError(msg) from None
    out: list[GeoFix | ImuSample] = []
    with handle:
        reader = csv.DictReader(handle)
        missing = set(TELEMETRY_HEADER) - set(reader.fieldnames or [])
        if missing:
            msg = f'--telemetry {path} lacks columns {sorted(missing)}; the header must be {",".join(TELEMETRY_HEADER)}.'
            raise InputError(msg)
        for line, row in enumerate(reader, start=2):
            try:
                vals = {k: float(row[k]) for k in TELEMETRY_HEADER}
            except (TypeError, ValueError):
                msg = f'--telemetry {path} line {line}: a value is not a number: {row}'
                raise InputError(msg) from None
            if not all(math.isfinite(v) for v in vals.values()):
                counts['telemetry_gaps'] += 1
                continue  # a gap in the log: no sample, not a crash
            rows += 1
            if vals['time_s'] < last_s:
                if not counts['telemetry_out_of_order']:
                    first_line = line
                counts['telemetry_out_of_order'] += 1
            last_s = max(last_s, vals['time_s'])
            stamp = round(vals['time_s'] * 1e9)
            out.append(GeoFix(stamp, vals['latitude'], vals['longitude'], vals['altitude'], status=0))
            R = R_enu_from_body(*np.radians([vals['roll'], vals['pitch'], vals['yaw']]))
            # a flight log has no rates: NaN (not provided), never zeros (a gyro saying "no rotation")
            out.append(ImuSample(stamp, quat_xyzw_from_matrix(R), np.full(3, np.nan), np.full(3, np.nan)))
    if counts['telemetry_out_of_order']:
        _LOG.warning('--telemetry %s: %d of its %d rows are earlier than a row before them (the first at line %d): '
                     'the log is out of time order; its rows are used sorted by time_s (report.json '
                     'metadata.problems telemetry_out_of_order).', path.name, counts['telemetry_out_of_order'], rows,
                     first_line)
    out.sort(key=lambda item: item.stamp_ns)
    return out


def write_telemetry_csv(path: str | Path, rows: list[tuple[float, float, float, float, float, float, float]]) -> None:
    """Write (time_s, lat, lon, alt, roll_deg, pitch_deg, yaw_deg) rows with the sidecar header."""
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(TELEMETRY_HEADER)
        for r in rows:
            writer.writerow([f'{r[0]:.6f}', f'{r[1]:.9f}', f'{r[2]:.9f}', f'{r[3]:.3f}',
                             f'{r[4]:.4f}', f'{r[5]:.4f}', f'{r[6]:.4f}'])
