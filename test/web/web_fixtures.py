"""A small georeferenced run folder for the web map's tests, written by the package's own GeoTIFF writer.

``synthetic_run(dir)`` writes what ``process --sr`` leaves that the map reads: mosaic.tif (RGBA COG
on a UTM grid, a covered disc, corners transparent, a red marker at a known pixel), sr/mosaic_sr.tif
(the same picture on the grid refined by 2) with sr/tiles.json (one SR box), poses.csv and a
report.json; and returns where things are.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from srmosaic_ros.core.georef import GeoRaster
from srmosaic_ros.io.geotiff import write_geotiff

#: Mosaic size (px) and ground sample distance (m).
WIDTH, HEIGHT, GSD = 600, 400, 0.2
#: Centre of pixel (0, 0), UTM zone 14N (central Texas, as the demo).
E0, N0, EPSG = 587500.0, 3338200.0, 32614
#: The red marker: mosaic pixel centre and half side (px).
MARKER_PX = (412.0, 137.0)
MARKER_HALF = 3
#: The SR box in mosaic pixels (x0, y0, width, height) and the SR factor.
SR_BOX = (64, 64, 128, 128)
SR_FACTOR = 2


@dataclass
class SyntheticRun:
    out: Path
    raster: GeoRaster
    marker_lonlat: tuple[float, float]
    image: np.ndarray  # (H, W, 4) uint8 RGBA as written


def mosaic_picture(width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """(H, W, 4) uint8: a smooth colour ramp inside an ellipse touching the edges' middles, alpha 0 outside
    (so the raster's corners are uncovered), a red square at MARKER_PX."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    inside = ((xx - (width - 1) / 2) / (width / 2)) ** 2 + ((yy - (height - 1) / 2) / (height / 2)) ** 2 <= 1.0
    rgba = np.zeros((height, width, 4), np.uint8)
    rgba[..., 0] = 40
    rgba[..., 1] = (80 + 100 * xx / width).astype(np.uint8)
    rgba[..., 2] = (80 + 100 * yy / height).astype(np.uint8)
    mx, my = (round(v) for v in MARKER_PX)
    rgba[my - MARKER_HALF:my + MARKER_HALF + 1, mx - MARKER_HALF:mx + MARKER_HALF + 1, :3] = (255, 0, 0)
    rgba[..., 3] = np.where(inside, 255, 0)
    return rgba


def synthetic_run(out: Path, *, rotation_rad: float = 0.0, sr: bool = True) -> SyntheticRun:
    out.mkdir(parents=True, exist_ok=True)
    raster = GeoRaster(EPSG, GSD, E0, N0, rotation_rad)
    image = mosaic_picture()
    write_geotiff(out / 'mosaic.tif', image, raster)
    if sr:
        import cv2

        s = SR_FACTOR
        up = cv2.resize(image, (WIDTH * s, HEIGHT * s), interpolation=cv2.INTER_NEAREST)
        # SR pixel (u, v) shows mosaic point ((u + 0.5) / s - 0.5, ...): the grid refined by s
        refine = np.array([[1 / s, 0, 0.5 / s - 0.5], [0, 1 / s, 0.5 / s - 0.5], [0, 0, 1]])
        write_geotiff(out / 'sr' / 'mosaic_sr.tif', up, raster.transformed(refine))
        x0, y0, w, h = SR_BOX
        (out / 'sr' / 'tiles.json').write_text(json.dumps([{'file': 'tile.png', 'x0': x0, 'y0': y0, 'width': w,
                                                             'height': h, 'factor': s}]))
    lonlat = raster.lonlat_from_pixels(np.array([MARKER_PX]))[0]
    track = raster.lonlat_from_pixels(np.array([[100.0 + 40 * k, 200.0] for k in range(10)]))
    rows = ['stamp_ns,latitude,longitude,altitude,roll,pitch,yaw,std_east_m,std_north_m,std_up_m']
    rows += [f'{1_000_000_000 * k},{lat:.9f},{lon:.9f},120.0,0,0,{-30.0 + 3 * k},0.5,0.5,1.0'
             for k, (lon, lat) in enumerate(track)]
    (out / 'poses.csv').write_text('\n'.join(rows) + '\n')
    (out / 'report.json').write_text(json.dumps({'frames_in': 10, 'frames_registered': 10, 'input': 'synthetic',
                                                 'georeferenced': {'epsg': EPSG, 'gsd_m_per_px': GSD},
                                                 'sr': {'factor': SR_FACTOR} if sr else None}))
    return SyntheticRun(out, raster, (float(lonlat[0]), float(lonlat[1])), image)


def ground_pixel_m(z: int, lat_deg: float) -> float:
    """Ground size (m) of an XYZ tile pixel at zoom z and a latitude: the equator's 2 pi R / 256 / 2**z
    shrunk by cos(latitude) (Web Mercator's scale), R = 6378137 m."""
    return 2 * math.pi * 6378137.0 / 256 / 2 ** z * math.cos(math.radians(lat_deg))
