"""WGS84 geodetic coordinates <-> a local ENU tangent plane.

Exact (no small-area approximation): geodetic -> ECEF -> ENU rotation about the origin, and back
with Bowring's closed form refined by Newton-free fixed-point iterations (sub-micrometre after
three). pyproj is not needed for this and is not used.

Convention: latitude and longitude in degrees, heights in metres above the WGS84 ellipsoid, ENU in
metres (x east, y north, z up; REP 103).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    'WGS84_A_M',
    'WGS84_F',
    'LocalTangentPlane',
    'ecef_from_geodetic',
    'geodetic_from_ecef',
]

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)
_B = WGS84_A_M * (1.0 - WGS84_F)
_EP2 = _E2 / (1.0 - _E2)


def ecef_from_geodetic(lat_deg: np.ndarray | float, lon_deg: np.ndarray | float,
                       alt_m: np.ndarray | float) -> np.ndarray:
    """Earth-centred Earth-fixed coordinates (..., 3) in metres of WGS84 geodetic points."""
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    alt = np.asarray(alt_m, dtype=np.float64)
    sin_lat = np.sin(lat)
    n = WGS84_A_M / np.sqrt(1.0 - _E2 * sin_lat**2)
    x = (n + alt) * np.cos(lat) * np.cos(lon)
    y = (n + alt) * np.cos(lat) * np.sin(lon)
    z = (n * (1.0 - _E2) + alt) * sin_lat
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def geodetic_from_ecef(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lat_deg, lon_deg, alt_m) of ECEF points (..., 3); valid away from the Earth's centre."""
    xyz = np.asarray(xyz, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    # Bowring's initial value, then fixed-point refinement of the latitude.
    theta = np.arctan2(z * WGS84_A_M, p * _B)
    lat = np.arctan2(z + _EP2 * _B * np.sin(theta) ** 3, p - _E2 * WGS84_A_M * np.cos(theta) ** 3)
    for _ in range(3):
        n = WGS84_A_M / np.sqrt(1.0 - _E2 * np.sin(lat) ** 2)
        alt = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.maximum(np.cos(lat), 1e-300) - n,
                       np.abs(z) - _B)
        lat = np.arctan2(z, p * (1.0 - _E2 * n / (n + alt)))
    n = WGS84_A_M / np.sqrt(1.0 - _E2 * np.sin(lat) ** 2)
    alt = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.maximum(np.cos(lat), 1e-300) - n, np.abs(z) - _B)
    return np.degrees(lat), np.degrees(lon), alt


@dataclass(frozen=True)
class LocalTangentPlane:
    """The ENU tangent plane at a WGS84 origin (lat0_deg, lon0_deg, alt0_m)."""

    lat0_deg: float
    lon0_deg: float
    alt0_m: float = 0.0

    @property
    def R_enu_from_ecef(self) -> np.ndarray:  # rotation name carries its frames
        """(3, 3) rotation taking ECEF vectors to ENU vectors at the origin."""
        lat, lon = np.radians(self.lat0_deg), np.radians(self.lon0_deg)
        sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
        return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])

    @property
    def origin_ecef_m(self) -> np.ndarray:
        return ecef_from_geodetic(self.lat0_deg, self.lon0_deg, self.alt0_m)

    def enu_from_geodetic(self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float,
                          alt_m: np.ndarray | float) -> np.ndarray:
        """ENU metres (..., 3) of geodetic points."""
        d = ecef_from_geodetic(lat_deg, lon_deg, alt_m) - self.origin_ecef_m
        return d @ self.R_enu_from_ecef.T

    def geodetic_from_enu(self, enu_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lat_deg, lon_deg, alt_m) of ENU points (..., 3)."""
        xyz = np.asarray(enu_m, dtype=np.float64) @ self.R_enu_from_ecef + self.origin_ecef_m
        return geodetic_from_ecef(xyz)
