"""KML output: a GroundOverlay that puts the mosaic image on Google Earth.

The mosaic is north-up in UTM, which is not north-up in longitude/latitude (grid convergence, a
degree or two away from a zone's central meridian), so the default overlay is a
``gx:LatLonQuad`` of the image's four outer corners (exact for any quadrilateral). ``mode='box'``
writes the classic ``LatLonBox`` (north, south, east, west and a rotation) of the same corners,
for viewers without the gx extension.

Corners are (longitude, latitude) in degrees, WGS84, in the order upper-left, upper-right,
lower-right, lower-left of the image (GeoRaster.corners_lonlat gives them).
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING

import numpy as np

from .mosaic_files import atomic_path

if TYPE_CHECKING:
    from ..core.georef.georeferencer import GeoRaster

__all__ = ['KML_NS', 'GX_NS', 'write_kml', 'write_kml_for_raster', 'latlonbox_from_corners']

KML_NS = 'http://www.opengis.net/kml/2.2'
GX_NS = 'http://www.google.com/kml/ext/2.2'
MODES = ('quad', 'box')


def latlonbox_from_corners(corners_lonlat: np.ndarray) -> dict[str, float]:
    """north, south, east, west (deg) and rotation (deg, counter-clockwise) of a LatLonBox that best
    matches the four corners (upper-left, upper-right, lower-right, lower-left)."""
    c = np.asarray(corners_lonlat, dtype=np.float64)
    lon_c, lat_c = c.mean(axis=0)
    k = math.cos(math.radians(lat_c))
    xy = np.c_[(c[:, 0] - lon_c) * k, c[:, 1] - lat_c]  # locally isotropic degrees
    top = xy[1] - xy[0]
    bottom = xy[2] - xy[3]
    edge = top + bottom
    theta = math.atan2(edge[1], edge[0])
    rot = np.array([[math.cos(-theta), -math.sin(-theta)], [math.sin(-theta), math.cos(-theta)]])
    aligned = xy @ rot.T
    half_w = 0.5 * (aligned[:, 0].max() - aligned[:, 0].min())
    half_h = 0.5 * (aligned[:, 1].max() - aligned[:, 1].min())
    return {'north': lat_c + half_h, 'south': lat_c - half_h, 'east': lon_c + half_w / k, 'west': lon_c - half_w / k,
            'rotation': math.degrees(theta)}


def write_kml(path: str | os.PathLike[str], image_href: str, corners_lonlat: np.ndarray, *,
              name: str = 'srmosaic mosaic', description: str = '', mode: str = 'quad') -> None:
    """Write a KML GroundOverlay of ``image_href`` (a PNG beside the KML, relative path) on the corners.

    Args:
        corners_lonlat: (4, 2) longitude, latitude (deg) of the image's upper-left, upper-right,
            lower-right and lower-left outer corners.
        mode: 'quad' (gx:LatLonQuad, exact) or 'box' (LatLonBox with rotation).
    """
    if mode not in MODES:
        msg = f'KML mode {mode!r} is not one of {MODES}.'
        raise ValueError(msg)
    c = np.asarray(corners_lonlat, dtype=np.float64)
    if c.shape != (4, 2) or not np.all(np.isfinite(c)):
        msg = f'corners_lonlat must be 4 finite (longitude, latitude) pairs, got {c.tolist()}.'
        raise ValueError(msg)
    ET.register_namespace('', KML_NS)
    ET.register_namespace('gx', GX_NS)
    kml = ET.Element(f'{{{KML_NS}}}kml')
    doc = ET.SubElement(kml, f'{{{KML_NS}}}Document')
    ET.SubElement(doc, f'{{{KML_NS}}}name').text = name
    overlay = ET.SubElement(doc, f'{{{KML_NS}}}GroundOverlay')
    ET.SubElement(overlay, f'{{{KML_NS}}}name').text = name
    if description:
        ET.SubElement(overlay, f'{{{KML_NS}}}description').text = description
    icon = ET.SubElement(overlay, f'{{{KML_NS}}}Icon')
    ET.SubElement(icon, f'{{{KML_NS}}}href').text = image_href
    ET.SubElement(overlay, f'{{{KML_NS}}}altitudeMode').text = 'clampToGround'
    if mode == 'quad':
        quad = ET.SubElement(overlay, f'{{{GX_NS}}}LatLonQuad')
        order = (3, 2, 1, 0)  # lower-left, lower-right, upper-right, upper-left (counter-clockwise)
        ET.SubElement(quad, f'{{{KML_NS}}}coordinates').text = ' '.join(
            f'{c[i, 0]:.9f},{c[i, 1]:.9f},0' for i in order)
    else:
        box = ET.SubElement(overlay, f'{{{KML_NS}}}LatLonBox')
        for key, value in latlonbox_from_corners(c).items():
            ET.SubElement(box, f'{{{KML_NS}}}{key}').text = f'{value:.9f}' if key != 'rotation' else f'{value:.6f}'
    ET.indent(kml)
    with atomic_path(path) as tmp:
        ET.ElementTree(kml).write(tmp, encoding='UTF-8', xml_declaration=True)


def write_kml_for_raster(path: str | os.PathLike[str], image_href: str, raster: GeoRaster, width: int, height: int,
                         **kwargs: str) -> None:
    """:func:`write_kml` for a width x height image whose pixel (0, 0) is ``raster``'s pixel (0, 0)."""
    write_kml(path, image_href, raster.corners_lonlat(width, height), **kwargs)
