"""Where the live mosaic plane lies on the map: the text of /srmosaic/raster, and its use.

With georeferencing, the mosaic node paints every segment on one north-up UTM raster (the
Georeferencer's) and /srmosaic/registration and /srmosaic/sr_tile give positions in its pixels.
/srmosaic/raster (std_msgs/String, reliable, transient local: a late subscriber gets the last one)
says where that raster lies, as JSON::

    {"version": 1, "epsg": 32614, "gsd_m_per_px": 0.18, "origin_easting_m": 587501.44,
     "origin_northing_m": 3338166.2, "rotation_rad": 0.0,
     "canvas_H_raster": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] or null}

(origin: the map coordinates of the centre of pixel (0, 0); rotation: of the pixel axes,
counter-clockwise from east, as GeoRaster). canvas_H_raster is drift control's current estimate of
the live canvas frame against the raster (core/georef/drift.py: the first pose's offset, rotation
and scale error, which the live canvas keeps and the offline outputs take out): canvas pixel =
canvas_H_raster @ raster pixel. :meth:`LiveRaster.utm_H_plane` takes it out, so that positions of
the live plane land where the filter now believes they are. The mosaic node publishes it when the
raster is made and whenever the estimate changes by more than 0.01 px at 1000 px.

    raster = LiveRaster.parse(msg.data)
    gt = raster.image_geotransform(image.header.frame_id, image.width, image.height)   # GDAL order
    # (an SR tile of /srmosaic/sr_tile, or the preview of /srmosaic/mosaic_preview)
    # -> rasterio.open('tile.tif', 'w', ..., crs=f'EPSG:{raster.epsg}', transform=Affine.from_gdal(*gt))
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import SrMosaicError
from .placement import ImagePlacement

if TYPE_CHECKING:
    from ..core.georef.georeferencer import GeoRaster
    from .sr import SRTilePlacement

__all__ = ['ImagePlacement', 'LiveRaster']

#: 'version' of the JSON: keys are only ever added (a reader ignores keys it does not know).
TEXT_VERSION = 1


@dataclass(frozen=True)
class LiveRaster:
    """The live raster (GeoRaster's fields) and drift control's canvas similarity (3, 3) or None."""

    epsg: int
    gsd_m_per_px: float
    origin_easting_m: float
    origin_northing_m: float
    rotation_rad: float = 0.0
    canvas_H_raster: np.ndarray | None = None

    @classmethod
    def from_georaster(cls, raster: GeoRaster, canvas_H_raster: np.ndarray | None) -> LiveRaster:
        return cls(int(raster.epsg), float(raster.gsd_m_per_px), float(raster.origin_easting_m),
                   float(raster.origin_northing_m), float(raster.rotation_rad),
                   None if canvas_H_raster is None else np.asarray(canvas_H_raster, dtype=np.float64))

    def text(self) -> str:
        """The JSON carried in /srmosaic/raster."""
        sim = None if self.canvas_H_raster is None else [[float(v) for v in row] for row in self.canvas_H_raster]
        return json.dumps({'version': TEXT_VERSION, 'epsg': self.epsg, 'gsd_m_per_px': self.gsd_m_per_px,
                           'origin_easting_m': self.origin_easting_m, 'origin_northing_m': self.origin_northing_m,
                           'rotation_rad': self.rotation_rad, 'canvas_H_raster': sim})

    @classmethod
    def parse(cls, text: str) -> LiveRaster:
        """Inverse of :meth:`text`; SrMosaicError names what is wrong with any other text."""
        try:
            d = json.loads(text)
            sim = d.get('canvas_H_raster')
            raster = cls(int(d['epsg']), float(d['gsd_m_per_px']), float(d['origin_easting_m']),
                         float(d['origin_northing_m']), float(d.get('rotation_rad', 0.0)),
                         None if sim is None else np.asarray(sim, dtype=np.float64).reshape(3, 3))
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            msg = f'not a /srmosaic/raster text ({type(exc).__name__}: {exc}); expected the JSON of srmosaic_ros.live.raster.'
            raise SrMosaicError(msg) from None
        if not (raster.gsd_m_per_px > 0 and math.isfinite(raster.origin_easting_m)
                and math.isfinite(raster.origin_northing_m)):
            msg = f'/srmosaic/raster text with an impossible grid: {text!r}.'
            raise SrMosaicError(msg)
        return raster

    @property
    def utm_H_raster(self) -> np.ndarray:
        """(3, 3) raster pixel (centres at integers) -> (easting, northing) m: GeoRaster's."""
        from ..core.georef.raster import GeoRaster

        return GeoRaster(self.epsg, self.gsd_m_per_px, self.origin_easting_m, self.origin_northing_m,
                         self.rotation_rad).utm_H_raster

    def utm_H_plane(self, *, canvas_frame_removed: bool = True) -> np.ndarray:
        """(3, 3) live plane pixel -> UTM; by default with the canvas similarity taken out (the best
        live estimate); ``canvas_frame_removed=False``: the raster as painted."""
        if canvas_frame_removed and self.canvas_H_raster is not None:
            return self.utm_H_raster @ np.linalg.inv(self.canvas_H_raster)
        return self.utm_H_raster

    def moved_m(self, other: LiveRaster | None) -> float:
        """How far (m) this raster puts the live plane from where ``other`` put it: the largest
        displacement of plane points 1000 px from the origin (canvas similarity taken out); inf when
        other is None or in another CRS."""
        if other is None or other.epsg != self.epsg:
            return math.inf
        probe = np.array([[0.0, 1000.0, 0.0], [0.0, 0.0, 1000.0], [1.0, 1.0, 1.0]])
        return float(np.abs(self.utm_H_plane() @ probe - other.utm_H_plane() @ probe).max())

    def image_geotransform(self, frame_id: str, image_width: int, image_height: int, *,
                           canvas_frame_removed: bool = True) -> tuple[float, float, float, float, float, float]:
        """GDAL geotransform (pixel corners) of an image placed on the live plane by its
        header.frame_id: an SR tile of /srmosaic/sr_tile or the mosaic preview of
        /srmosaic/mosaic_preview (see :class:`ImagePlacement`)."""
        placement = ImagePlacement.parse(frame_id)
        corner = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])  # corner (u, v) = centre - 0.5
        m = (self.utm_H_plane(canvas_frame_removed=canvas_frame_removed)
             @ placement.plane_H_image(image_width, image_height) @ corner)
        m = m / m[2, 2]
        return (float(m[0, 2]), float(m[0, 0]), float(m[0, 1]), float(m[1, 2]), float(m[1, 0]), float(m[1, 1]))

    def tile_geotransform(self, placement: SRTilePlacement, *,
                          canvas_frame_removed: bool = True) -> tuple[float, float, float, float, float, float]:
        """GDAL geotransform (pixel corners) of an SR tile of /srmosaic/sr_tile."""
        return self.image_geotransform(placement.frame_id(), placement.width * placement.factor,
                                       placement.height * placement.factor, canvas_frame_removed=canvas_frame_removed)
