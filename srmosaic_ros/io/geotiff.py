"""GeoTIFF output: a mosaic on its north-up UTM grid, readable in place by GDAL-based tools.

``write_geotiff(path, image, raster)`` writes 8-bit RGB(A) or grey(+alpha) with the raster's CRS
(EPSG code of the UTM zone) and affine geotransform, uncovered pixels transparent (an alpha band
marked as such, which QGIS and GDAL honour), DEFLATE-compressed; outputs larger than
``TILED_ABOVE_PX`` on a side are tiled (256 x 256) with internal overviews (average) so that GIS
tools pan them quickly. The file is written under a temporary name and renamed into place.

Convention: the image's pixel (x, y) (centres at integers) is the raster's pixel (x, y); the
GeoTIFF geotransform is that of the pixel *corners*, GeoRaster.geotransform.
"""
from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from .mosaic_files import atomic_path

if TYPE_CHECKING:
    from ..core.georef.georeferencer import GeoRaster

__all__ = ['TILED_ABOVE_PX', 'write_geotiff']

TILED_ABOVE_PX = 1024
_BLOCK_PX = 256


def _to_u8(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img
    if np.issubdtype(img.dtype, np.floating):
        return np.clip(np.nan_to_num(img, nan=0.0) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if img.dtype == np.uint16:
        return (img >> 8).astype(np.uint8)
    msg = f'write_geotiff takes uint8, uint16 or float images in [0, 1], not {img.dtype}.'
    raise TypeError(msg)


def _bands(image: np.ndarray, coverage: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """(bands (C, H, W) uint8, has_alpha). Colour first, alpha last."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[2] not in (1, 2, 3, 4):
        msg = f'write_geotiff takes (H, W), (H, W, 1), (H, W, 2), (H, W, 3) or (H, W, 4) images, not {img.shape}.'
        raise ValueError(msg)
    has_alpha = img.shape[2] in (2, 4)
    colour = img[:, :, :-1] if has_alpha else img
    alpha = _to_u8(img[:, :, -1]) if has_alpha else None
    nan_mask = np.isnan(colour).any(axis=2) if np.issubdtype(colour.dtype, np.floating) else None
    colour = _to_u8(colour)
    if coverage is not None:
        cov = np.asarray(coverage, dtype=bool)
        if cov.shape != colour.shape[:2]:
            msg = f'coverage {cov.shape} does not match the image {colour.shape[:2]}.'
            raise ValueError(msg)
        alpha = np.where(cov, 255, 0).astype(np.uint8) if alpha is None else np.where(cov, alpha, 0).astype(np.uint8)
    elif alpha is None and nan_mask is not None and nan_mask.any():
        alpha = np.where(nan_mask, 0, 255).astype(np.uint8)
    bands = [colour[:, :, c] for c in range(colour.shape[2])]
    if alpha is not None:
        bands.append(alpha)
    return np.ascontiguousarray(np.stack(bands)), alpha is not None


def write_geotiff(path: str | os.PathLike[str], image: np.ndarray, raster: GeoRaster, *,
                  coverage: np.ndarray | None = None, tiled: bool | None = None, overviews: bool | None = None,
                  compress: str = 'deflate') -> None:
    """Write ``image`` on ``raster``'s grid as a GeoTIFF.

    Args:
        path: output file (.tif).
        image: (H, W) grey, (H, W, 3) RGB, (H, W, 2) grey+alpha or (H, W, 4) RGBA; uint8, uint16 or
            float in [0, 1] (NaN: uncovered).
        raster: the grid (CRS, gsd, pixel (0, 0) centre) of image pixel (0, 0).
        coverage: (H, W) bool, False where nothing was painted (transparent); combined with an
            alpha channel if the image has one.
        tiled, overviews: default True when a side exceeds ``TILED_ABOVE_PX``.
        compress: GDAL compression (deflate, lzw, none).
    """
    import rasterio
    from rasterio.crs import CRS
    from rasterio.enums import ColorInterp, Resampling
    from rasterio.transform import Affine

    bands, has_alpha = _bands(image, coverage)
    count, height, width = bands.shape
    big = max(height, width) > TILED_ABOVE_PX
    tiled = big if tiled is None else tiled
    overviews = big if overviews is None else overviews
    colour = count - int(has_alpha)
    profile: dict[str, object] = {
        'driver': 'GTiff', 'width': width, 'height': height, 'count': count, 'dtype': 'uint8',
        'crs': CRS.from_epsg(raster.epsg), 'transform': Affine.from_gdal(*raster.geotransform),
        'interleave': 'pixel', 'photometric': 'RGB' if colour == 3 else 'MINISBLACK', 'BIGTIFF': 'IF_SAFER',
    }
    if compress and compress.lower() != 'none':
        profile.update(compress=compress, predictor=2)
    if has_alpha:
        profile['alpha'] = 'YES'
    if tiled:
        profile.update(tiled=True, blockxsize=_BLOCK_PX, blockysize=_BLOCK_PX)
    interp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue] if colour == 3 else [ColorInterp.gray]
    if has_alpha:
        interp.append(ColorInterp.alpha)
    with atomic_path(path) as tmp:
        os.unlink(tmp)  # GDAL creates the file itself
        with rasterio.open(tmp, 'w', **profile) as dst:
            dst.write(bands)
            dst.colorinterp = interp
            dst.update_tags(SOFTWARE='srmosaic_ros', GSD_M_PER_PX=f'{raster.gsd_m_per_px:.6g}')
            if overviews:
                factors = []
                f = 2
                while max(height, width) / f >= _BLOCK_PX / 2:
                    factors.append(f)
                    f *= 2
                if factors:
                    dst.build_overviews(factors, Resampling.average)
                    dst.update_tags(ns='rio_overview', resampling='average')
