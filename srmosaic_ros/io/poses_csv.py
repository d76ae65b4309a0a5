"""poses.csv: one fused pose per frame (the file contract of `srmosaic process`, see DESIGN.md).

Header ``stamp_ns,latitude,longitude,altitude,roll,pitch,yaw,std_east_m,std_north_m,std_up_m``:
WGS84 latitude and longitude in degrees, altitude in metres above the ellipsoid, roll, pitch, yaw
in degrees of the body (x forward, y left, z up) in ENU (REP 103), and the standard deviations of
the position in metres. A frame without a pose (no fix yet) has ``nan`` fields.
"""
from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from .mosaic_files import atomic_path

if TYPE_CHECKING:
    from ..core.georef.georeferencer import FramePose

__all__ = ['POSES_CSV_HEADER', 'write_poses_csv', 'read_poses_csv']

POSES_CSV_HEADER = ['stamp_ns', 'latitude', 'longitude', 'altitude', 'roll', 'pitch', 'yaw',
                    'std_east_m', 'std_north_m', 'std_up_m']


def _fmt(value: float, digits: int) -> str:
    return f'{value:.{digits}f}' if math.isfinite(value) else 'nan'


def write_poses_csv(path: str | os.PathLike[str], poses: Iterable[FramePose]) -> None:
    """Write one row per FramePose (atomically)."""
    with atomic_path(path) as tmp, open(tmp, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(POSES_CSV_HEADER)
        for pose in poses:
            rpy = [math.degrees(float(v)) for v in pose.rpy_rad]
            std = [float(v) for v in pose.std_enu_m]
            writer.writerow([int(pose.stamp_ns), _fmt(pose.latitude_deg, 9), _fmt(pose.longitude_deg, 9),
                             _fmt(pose.altitude_m, 4)] + [_fmt(v, 6) for v in rpy] + [_fmt(v, 4) for v in std])


def read_poses_csv(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Rows of a poses.csv: stamp_ns int, every other column float (degrees / metres as written)."""
    rows = []
    with open(path, newline='') as handle:
        reader = csv.DictReader(handle)
        missing = set(POSES_CSV_HEADER) - set(reader.fieldnames or [])
        if missing:
            msg = f'{path} is not a poses.csv: missing columns {sorted(missing)}'
            raise ValueError(msg)
        for rec in reader:
            row: dict[str, Any] = {'stamp_ns': int(rec['stamp_ns'])}
            row.update({key: float(rec[key]) for key in POSES_CSV_HEADER[1:]})
            rows.append(row)
    return rows
