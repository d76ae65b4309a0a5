"""The map grid: UTM zone of a point (utm_epsg) and GeoRaster, a raster grid in a UTM zone with its
pixel <-> UTM <-> longitude/latitude maps.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .ground_homography import apply_H

__all__ = ['GeoRaster', 'utm_epsg']


def utm_epsg(latitude_deg: float, longitude_deg: float) -> int:
    """EPSG code of the WGS84 UTM zone of a point: 326zz north of the equator, 327zz south."""
    zone = int(math.floor((longitude_deg + 180.0) / 6.0)) % 60 + 1
    return (32600 if latitude_deg >= 0.0 else 32700) + zone


@functools.lru_cache(maxsize=8)
def _transformers(epsg: int):  # pyproj types stay lazy
    from pyproj import Transformer

    return (Transformer.from_crs(4326, epsg, always_xy=True), Transformer.from_crs(epsg, 4326, always_xy=True))


@dataclass(frozen=True)
class GeoRaster:
    """A raster grid in a UTM zone: north-up, or turned by a small angle after re-anchoring.

    epsg: the CRS (WGS84 / UTM); gsd_m_per_px: pixel size; origin_easting_m / origin_northing_m:
    the map coordinates of the *centre* of pixel (0, 0); rotation_rad: angle of the pixel axes,
    counter-clockwise on the map from east for the x axis (0: north-up, the live raster; the
    offline outputs may be re-anchored by a similarity, see anchoring.py). Convention: pixel
    (x, y), x right, y down, centres at integers, as every homography of the package.
    """

    epsg: int
    gsd_m_per_px: float
    origin_easting_m: float
    origin_northing_m: float
    rotation_rad: float = 0.0

    @property
    def utm_H_raster(self) -> np.ndarray:
        """(3, 3) raster pixel (x, y, 1) -> (easting, northing, 1) in metres:
        [[g c, g s, e0], [g s, -g c, n0]] with c, s the cosine and sine of rotation_rad."""
        g, c, s = self.gsd_m_per_px, math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        return np.array([[g * c, g * s, self.origin_easting_m], [g * s, -g * c, self.origin_northing_m], [0.0, 0.0, 1.0]])

    @property
    def raster_H_utm(self) -> np.ndarray:
        return np.linalg.inv(self.utm_H_raster)

    @property
    def geotransform(self) -> tuple[float, float, float, float, float, float]:
        """GDAL geotransform (pixel *corner* convention) of pixel (0, 0)'s outer corner:
        (x_min, gsd, 0, y_max, 0, -gsd) when north-up, with the rotation terms otherwise."""
        m = self.utm_H_raster
        return (float(m[0, 2] - 0.5 * (m[0, 0] + m[0, 1])), float(m[0, 0]), float(m[0, 1]),
                float(m[1, 2] - 0.5 * (m[1, 0] + m[1, 1])), float(m[1, 0]), float(m[1, 1]))

    @property
    def crs_wkt(self) -> str:
        from pyproj import CRS

        return CRS.from_epsg(self.epsg).to_wkt()

    def shifted(self, dx_px: float, dy_px: float) -> GeoRaster:
        """The same grid with pixel (dx_px, dy_px) of this one as its pixel (0, 0) (a crop's origin)."""
        e, n = self.utm_H_raster[:2] @ np.array([dx_px, dy_px, 1.0])
        return GeoRaster(self.epsg, self.gsd_m_per_px, float(e), float(n), self.rotation_rad)

    def transformed(self, raster_H_new: np.ndarray) -> GeoRaster:
        """The grid whose pixel p is this grid's pixel raster_H_new @ p; raster_H_new must be a
        similarity without reflection (scale, rotation, translation), e.g. from anchoring.py."""
        m = self.utm_H_raster @ np.asarray(raster_H_new, dtype=np.float64)
        g = math.hypot(m[0, 0], m[1, 0])
        if not (g > 0 and np.allclose([m[0, 1], m[1, 1]], [m[1, 0], -m[0, 0]], rtol=1e-6, atol=1e-9 * g)):
            msg = f'GeoRaster.transformed needs a similarity without reflection, got\n{raster_H_new}'
            raise ValueError(msg)
        return GeoRaster(self.epsg, float(g), float(m[0, 2]), float(m[1, 2]), math.atan2(m[1, 0], m[0, 0]))

    def utm_from_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) easting, northing (m) of raster pixels (..., 2)."""
        return apply_H(self.utm_H_raster, xy)

    def lonlat_from_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) longitude, latitude (deg) of raster pixels (..., 2)."""
        en = self.utm_from_pixels(xy)
        lon, lat = _transformers(self.epsg)[1].transform(en[..., 0], en[..., 1])
        return np.stack([np.asarray(lon), np.asarray(lat)], axis=-1)

    def pixels_from_lonlat(self, lonlat: np.ndarray) -> np.ndarray:
        """(..., 2) raster pixels of longitude, latitude (deg) points (..., 2)."""
        lonlat = np.asarray(lonlat, dtype=np.float64)
        e, n = _transformers(self.epsg)[0].transform(lonlat[..., 0], lonlat[..., 1])
        return apply_H(self.raster_H_utm, np.stack([np.asarray(e), np.asarray(n)], axis=-1))

    def corners_lonlat(self, width: int, height: int) -> np.ndarray:
        """(4, 2) longitude, latitude of the outer corners of a width x height raster: upper-left,
        upper-right, lower-right, lower-left (pixel edges, i.e. centres -0.5 / +0.5)."""
        c = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [width - 0.5, height - 0.5], [-0.5, height - 0.5]])
        return self.lonlat_from_pixels(c)
