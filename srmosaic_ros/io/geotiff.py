"""GeoTIFF output: a mosaic on its north-up UTM grid, readable in place by GDAL-based tools.

``write_geotiff(path, image, raster)`` writes 8-bit RGB(A) or grey(+alpha) with the raster's CRS
(EPSG code of the UTM zone) and affine geotransform, uncovered pixels transparent (an alpha band
marked as such, which QGIS and GDAL honour), DEFLATE-compressed; outputs larger than
``TILED_ABOVE_PX`` on a side are tiled (256 x 256) with internal overviews (average) so that GIS
tools pan them quickly. The file is written under a temporary name and renamed into place.

``write_geotiff_blocks(path, strips, raster)`` writes the same file from strips of rows (e.g.
``TiledCanvas.render_blocks``), never holding the whole image: mosaic.tif is written this way,
tiled in ``MOSAIC_BLOCK_PX`` (512) blocks with internal overviews. GDAL's block cache is capped at
``GDAL_CACHE_BYTES`` while writing, so the memory held does not grow with the raster's area.
``png_from_geotiff(src, dst)`` then makes mosaic.png from that file with GDAL's PNG CreateCopy,
which reads the source a scanline at a time; grey+alpha sources become RGBA PNGs (grey repeated),
as ``mosaic_files.write_png`` writes them. ``raster=None`` writes a plain (not georeferenced) TIFF,
the intermediate of mosaic.png for runs without georeferencing.

Convention: the image's pixel (x, y) (centres at integers) is the raster's pixel (x, y); the
GeoTIFF geotransform is that of the pixel *corners*, GeoRaster.geotransform.
"""
from __future__ import annotations

import logging
import os
import uuid
import warnings
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ..errors import OutputError
from .mosaic_files import atomic_path

if TYPE_CHECKING:
    from ..core.georef.georeferencer import GeoRaster

__all__ = ['GDAL_CACHE_BYTES', 'MOSAIC_BLOCK_PX', 'TILED_ABOVE_PX', 'GeoGrid', 'overview_factors', 'png_from_geotiff',
           'read_raster', 'write_geotiff', 'write_geotiff_blocks']

TILED_ABOVE_PX = 1024
_BLOCK_PX = 256
#: Block side (px) of mosaic.tif (write_geotiff_blocks' default).
MOSAIC_BLOCK_PX = 512
#: GDAL block cache while writing or converting (bytes); dirty blocks beyond it are flushed to disk.
GDAL_CACHE_BYTES = 64 * 2**20
#: Rows converted to uint8 and handed to GDAL at a time (strips are cut to this).
CONVERT_ROWS = 128
#: zlib level of PNGs made by png_from_geotiff (1: fastest, as OpenCV's default for write_png).
PNG_ZLEVEL = 1
#: A COG whose raster holds at most this many bytes (all bands, uncompressed) is staged in memory
#: (GDAL's /vsimem/), uncompressed, for the COG copy: no stage written to disk, compressed and read
#: back; larger ones are staged on disk beside the output, so that memory stays bounded.
STAGE_IN_MEMORY_BYTES = 32 * 2**20

#: One strip of rows: (first row, image (rows, W) / (rows, W, C), coverage (rows, W) bool or None).
Strip = tuple[int, np.ndarray, 'np.ndarray | None']


class GeoGrid(NamedTuple):
    """Any affine grid for the writers, where a GeoRaster (square pixels) does not fit: EPSG code,
    GDAL geotransform (pixel corners) and the pixel size recorded in the GSD tag (m)."""

    epsg: int
    geotransform: tuple[float, float, float, float, float, float]
    gsd_m_per_px: float


def _to_u8(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img
    if np.issubdtype(img.dtype, np.floating):
        # round(clip(x, 0, 1) * 255), NaN as 0: one temporary, updated in place (fmax and fmin take
        # a NaN to the bound, as nan_to_num's 0 would end) -- the bytes of
        # np.clip(np.nan_to_num(img) * 255 + 0.5, 0, 255).astype(np.uint8), at a third of the passes
        t = np.multiply(img, 255.0)
        t += 0.5
        np.fmax(t, 0.0, out=t)
        np.fmin(t, 255.0, out=t)
        return t.astype(np.uint8)
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


def overview_factors(height: int, width: int, block_px: int) -> list[int]:
    """Decimation factors 2, 4, 8, ... while the longer side at that factor is at least block_px / 2."""
    factors, f = [], 2
    while max(height, width) / f >= block_px / 2:
        factors.append(f)
        f *= 2
    return factors


def _profile(width: int, height: int, count: int, has_alpha: bool, raster: GeoRaster | GeoGrid | None, *,
             tiled: bool, block_px: int, compress: str, threads: int = 1, zlevel: int | None = None) -> dict[str, Any]:
    """rasterio creation profile of a GTiff of ``count`` uint8 bands (alpha last when has_alpha);
    ``threads`` > 1 compresses blocks on that many GDAL threads, ``zlevel`` the DEFLATE level (None:
    GDAL's default, 6)."""
    colour = count - int(has_alpha)
    profile: dict[str, Any] = {
        'driver': 'GTiff', 'width': width, 'height': height, 'count': count, 'dtype': 'uint8',
        'interleave': 'pixel', 'photometric': 'RGB' if colour == 3 else 'MINISBLACK', 'BIGTIFF': 'IF_SAFER',
    }
    if raster is not None:
        from rasterio.crs import CRS
        from rasterio.transform import Affine

        profile.update(crs=CRS.from_epsg(raster.epsg), transform=Affine.from_gdal(*raster.geotransform))
    if compress and compress.lower() != 'none':
        profile.update(compress=compress, predictor=2)
        if zlevel is not None and compress.lower() == 'deflate':
            profile['zlevel'] = int(zlevel)
    if threads > 1:
        profile['num_threads'] = int(threads)
    if has_alpha:
        profile['alpha'] = 'YES'
    if tiled:
        profile.update(tiled=True, blockxsize=block_px, blockysize=block_px)
    return profile


@contextmanager
def _gdal_env(**options: Any) -> Iterator[None]:
    """GDAL settings of the writers: a bounded block cache, no .aux.xml sidecars (and ``options``)."""
    import rasterio

    with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_BYTES, GDAL_PAM_ENABLED='NO', **options), warnings.catch_warnings():
        from rasterio.errors import NotGeoreferencedWarning

        warnings.simplefilter('ignore', NotGeoreferencedWarning)
        yield


class _GdalErrors(logging.Handler):
    """The errors GDAL signals while a file is written. A failed block write (a full disk, a file
    size limit) is only logged by rasterio, not raised, and GDAL building overviews on the damaged
    file then crashes the process; so the writer checks this after each step."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if 'GDAL signalled an error' in text:
            self.messages.append(text.split('msg=', 1)[-1].strip("'\""))

    def check(self, path: str | os.PathLike[str]) -> None:
        if self.messages:
            msg = (f'{Path(path).name} could not be written ({self.messages[0]}): the disk is full or a file size '
                   'limit was reached; free space, or give --out elsewhere.')
            raise OutputError(msg)


#: Room the internal overviews need, as a fraction of the file without them (factors 2, 4, ...
#: add at most 1/4 + 1/16 + ... = 1/3 of the base; with a margin for the directory).
OVERVIEW_ROOM = 0.4


def _check_room(tmp: str | os.PathLike[str], path: str | os.PathLike[str], fraction: float, *,
                size: int | None = None) -> None:
    """OutputError unless the file ``tmp`` can grow by ``fraction`` of its size, or, with ``size``, a
    file of ``size`` bytes grown by that fraction can be written beside it: free space on its disk and
    the process's file size limit (RLIMIT_FSIZE). GDAL crashes when an overview block cannot be
    written, so this is checked before, not found after."""
    import resource
    import shutil

    written = size is None  # the bytes are on the disk already
    size = os.path.getsize(tmp) if size is None else size
    need = int(size * (1.0 + fraction))
    new_bytes = need - size if written else need
    free = shutil.disk_usage(os.path.dirname(os.path.abspath(tmp))).free
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if free < new_bytes or (limit != resource.RLIM_INFINITY and limit < need):
        where = 'the disk is full' if free < new_bytes else f'the file size limit is {limit} bytes'
        msg = (f'{Path(path).name} needs about {need // 2**20 + 1} MiB with its overviews and {where}; free space, '
               'or give --out elsewhere.')
        raise OutputError(msg)


@contextmanager
def _gdal_errors(path: str | os.PathLike[str]) -> Iterator[_GdalErrors]:
    """Collects GDAL's errors while ``path`` is written; a GDAL failure raised meanwhile (libpng's
    'Write Error' on a full disk) becomes the OutputError of :meth:`_GdalErrors.check`."""
    from rasterio._err import CPLE_BaseError  # the base of GDAL errors raised by rasterio

    handler = _GdalErrors()
    logger = logging.getLogger('rasterio._env')
    level = logger.level
    logger.addHandler(handler)
    if logger.getEffectiveLevel() > logging.INFO:
        logger.setLevel(logging.INFO)  # rasterio logs GDAL's errors at INFO
    try:
        yield handler
    except CPLE_BaseError as exc:
        handler.messages.insert(0, str(exc))
        handler.check(path)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


def _write_strips(dst: Any, first: tuple[int, np.ndarray], strips: Iterator[Strip],
                  height: int, width: int, coverage_given: bool) -> None:
    """Write band strips (count, rows, W) in order; check that they tile rows 0 .. height exactly."""
    from rasterio.windows import Window

    row, bands = first
    expected = 0
    while True:
        if row != expected or bands.shape[2] != width or row + bands.shape[1] > height:
            msg = (f'strip at row {row} of {bands.shape[1]}x{bands.shape[2]} px does not continue the raster '
                   f'({height}x{width} px, next row {expected}); strips must be contiguous, top to bottom.')
            raise ValueError(msg)
        dst.write(bands, window=Window(0, row, width, bands.shape[1]))
        expected = row + bands.shape[1]
        item = next(strips, None)
        if item is None:
            break
        if (item[2] is not None) != coverage_given:
            msg = 'every strip must come with a coverage mask, or none may.'
            raise ValueError(msg)
        row, bands = item[0], _bands(item[1], item[2])[0]

    if expected != height:
        msg = f'the strips end at row {expected} of {height}: the raster would be incomplete.'
        raise ValueError(msg)


def _chunked(strips: Iterable[Strip], rows: int) -> Iterator[Strip]:
    """The strips cut into pieces of at most ``rows`` rows (views), so that the uint8 conversion's
    float temporaries stay small whatever the strips' height."""
    for row, image, coverage in strips:
        for r in range(0, max(len(image), 1), rows):
            yield row + r, image[r:r + rows], None if coverage is None else coverage[r:r + rows]


def write_geotiff_blocks(path: str | os.PathLike[str], strips: Iterable[Strip], raster: GeoRaster | GeoGrid | None,
                         height: int, width: int, *, block_px: int = MOSAIC_BLOCK_PX, tiled: bool = True,
                         overviews: bool = True, compress: str = 'deflate', threads: int = 1,
                         zlevel: int | None = None, cog: bool = True) -> None:
    """Write a GeoTIFF strip by strip, atomically; a Cloud Optimized GeoTIFF unless ``cog`` is False.

    Args:
        path: output file (.tif); it appears only once complete (temporary name, then a rename):
            an exception or a kill mid-way leaves no file under this name.
        strips: ``(row, image, coverage)`` in order top to bottom, together rows 0 .. height - 1:
            image (rows, W) grey, (rows, W, 3) RGB (or with an alpha channel, as write_geotiff),
            uint8, uint16 or float in [0, 1]; coverage (rows, W) bool (False: transparent) or
            None. ``TiledCanvas.render_blocks`` yields exactly these.
        raster: the grid (CRS, gsd) of pixel (0, 0); None writes a TIFF without georeferencing.
        height, width: the raster's size in pixels.
        block_px: tile side when tiled (a multiple of 16); strips of a multiple of block_px rows
            complete whole tile rows, which GDAL then compresses and writes out.
        tiled, overviews: tiled layout; internal overviews (average, factors of overview_factors).
        compress: GDAL compression (deflate, lzw, none).
        threads: GDAL threads compressing the blocks and computing the overviews (1: GDAL's
            defaults, the bytes of every earlier release); the pixels do not depend on it.
        zlevel: DEFLATE level of the blocks and the overviews (None: GDAL's default, 6).
        cog: lay the file out as a COG (GDAL's COG driver, CreateCopy of a staged GTiff with its
            overviews): tiled, the overviews' blocks after the main image's, smallest first, and the
            directories ahead of the data, so that a reader of a byte range (HTTP, QGIS) opens it
            cheaply. ``tiled`` is then implied. False writes a plain GTiff (scratch files).

    Memory: one strip, the uint8 conversion of CONVERT_ROWS of its rows, and GDAL's cache
    (GDAL_CACHE_BYTES); overviews are built by GDAL from the file, in blocks.
    """
    import rasterio
    from rasterio.enums import ColorInterp, Resampling

    if height < 1 or width < 1:
        msg = f'a GeoTIFF needs at least one pixel, got {height}x{width}; is the mosaic empty?'
        raise ValueError(msg)
    if block_px < 16 or block_px % 16:
        msg = f'block_px must be a positive multiple of 16 (a TIFF requirement), got {block_px}.'
        raise ValueError(msg)
    it = _chunked(strips, CONVERT_ROWS)
    head = next(it, None)
    if head is None:
        msg = f'no strips to write for a {height}x{width} raster.'
        raise ValueError(msg)
    bands, has_alpha = _bands(head[1], head[2])
    count = bands.shape[0]
    colour = count - int(has_alpha)
    profile = _profile(width, height, count, has_alpha, raster, tiled=tiled, block_px=block_px, compress=compress,
                       threads=threads, zlevel=zlevel)
    options: dict[str, Any] = {}
    if threads > 1:
        options['GDAL_NUM_THREADS'] = str(int(threads))  # the overviews
    if zlevel is not None:
        options['ZLEVEL_OVERVIEW'] = str(int(zlevel))
    interp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue] if colour == 3 else [ColorInterp.gray] * colour
    if has_alpha:
        interp.append(ColorInterp.alpha)
    in_memory = cog and height * width * count <= STAGE_IN_MEMORY_BYTES
    if cog:  # the stage is read once, by the COG copy: uncompressed in memory, else the fastest DEFLATE level
        profile = _profile(width, height, count, has_alpha, raster, tiled=True, block_px=block_px,
                           compress='none' if in_memory else 'deflate', threads=threads, zlevel=None if in_memory else 1)
    with atomic_path(path) as tmp, _gdal_env(**options), _gdal_errors(path) as errors:
        os.unlink(tmp)  # GDAL creates the file itself
        stage = (f'/vsimem/srmosaic-stage-{uuid.uuid4().hex}.tif' if in_memory else f'{tmp}.stage.tif') if cog else tmp
        try:
            with rasterio.open(stage, 'w', **profile) as dst:
                _write_strips(dst, (head[0], bands), it, height, width, head[2] is not None)
                del bands, head
                dst.colorinterp = interp
                tags = {'SOFTWARE': 'srmosaic_ros'}
                if raster is not None:
                    tags['GSD_M_PER_PX'] = f'{raster.gsd_m_per_px:.6g}'
                dst.update_tags(**tags)
            errors.check(path)  # the cached blocks and the directory are written on close
            factors = overview_factors(height, width, block_px) if overviews else []
            if factors:
                if not in_memory:
                    _check_room(stage, path, OVERVIEW_ROOM)
                with rasterio.open(stage, 'r+') as dst:
                    dst.build_overviews(factors, Resampling.average)
                    dst.update_tags(ns='rio_overview', resampling='average')
                errors.check(path)
            if cog:  # an uncompressed stage's size bounds the COG's from above
                if in_memory:
                    _check_room(tmp, path, OVERVIEW_ROOM, size=height * width * count)
                else:
                    _check_room(stage, path, 1.0 + OVERVIEW_ROOM)
                _copy_as_cog(stage, tmp, block_px=block_px, compress=compress, threads=threads, zlevel=zlevel,
                             overviews=bool(factors))
                errors.check(path)
        finally:
            if in_memory:
                _unlink_vsimem(stage)
            elif cog and os.path.exists(stage):
                os.unlink(stage)


def _unlink_vsimem(path: str) -> None:
    """Free an in-memory (/vsimem/) file, if GDAL made it."""
    from rasterio.shutil import delete, exists

    if exists(path):
        delete(path)


def _copy_as_cog(src: str, dst: str, *, block_px: int, compress: str, threads: int, zlevel: int | None,
                 overviews: bool) -> None:
    """GDAL's COG driver: ``src`` (a tiled GTiff, with its overviews when ``overviews``) copied to
    ``dst`` in COG layout, the overviews taken as they are (average, factors of overview_factors)."""
    import rasterio.shutil

    options: dict[str, Any] = {'BLOCKSIZE': block_px, 'BIGTIFF': 'IF_SAFER',
                               'OVERVIEWS': 'FORCE_USE_EXISTING' if overviews else 'NONE'}
    if compress and compress.lower() != 'none':
        options.update(COMPRESS=compress.upper(), PREDICTOR='YES')
        if zlevel is not None and compress.lower() == 'deflate':
            options['LEVEL'] = int(zlevel)
    else:
        options['COMPRESS'] = 'NONE'
    if threads > 1:
        options['NUM_THREADS'] = int(threads)
    rasterio.shutil.copy(src, dst, driver='COG', **options)


def write_geotiff(path: str | os.PathLike[str], image: np.ndarray, raster: GeoRaster | GeoGrid, *,
                  coverage: np.ndarray | None = None, tiled: bool | None = None, overviews: bool | None = None,
                  compress: str = 'deflate', cog: bool = True) -> None:
    """Write ``image`` on ``raster``'s grid as a GeoTIFF.

    Args:
        path: output file (.tif).
        image: (H, W) grey, (H, W, 3) RGB, (H, W, 2) grey+alpha or (H, W, 4) RGBA; uint8, uint16 or
            float in [0, 1] (NaN: uncovered).
        raster: the grid (CRS, gsd, pixel (0, 0) centre) of image pixel (0, 0): a GeoRaster, or a
            GeoGrid for any affine grid.
        coverage: (H, W) bool, False where nothing was painted (transparent); combined with an
            alpha channel if the image has one.
        tiled, overviews: default True when a side exceeds ``TILED_ABOVE_PX`` (256 x 256 tiles).
        compress: GDAL compression (deflate, lzw, none).
        cog: a Cloud Optimized GeoTIFF (write_geotiff_blocks); False for a file whose georeference
            is updated in place later (GDAL refuses to edit a COG's directory without breaking it).
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3):
        msg = f'write_geotiff takes (H, W) or (H, W, C) images, not {img.shape}.'
        raise ValueError(msg)
    height, width = img.shape[:2]
    big = max(height, width) > TILED_ABOVE_PX
    write_geotiff_blocks(path, [(0, img, coverage)], raster, height, width, block_px=_BLOCK_PX,
                         tiled=big if tiled is None else tiled, overviews=big if overviews is None else overviews,
                         compress=compress, cog=cog)


def _grey_alpha_as_rgba_vrt(src: Path, width: int, height: int) -> str:
    """VRT XML presenting a grey+alpha raster as RGBA (band 1 as red, green and blue; band 2 as alpha)."""
    def band(n: int, interp: str, source_band: int) -> str:
        return (f'<VRTRasterBand dataType="Byte" band="{n}"><ColorInterp>{interp}</ColorInterp>'
                f'<SimpleSource><SourceFilename relativeToVRT="0">{src}</SourceFilename>'
                f'<SourceBand>{source_band}</SourceBand>'
                f'<SrcRect xOff="0" yOff="0" xSize="{width}" ySize="{height}"/>'
                f'<DstRect xOff="0" yOff="0" xSize="{width}" ySize="{height}"/></SimpleSource></VRTRasterBand>')

    bands = band(1, 'Red', 1) + band(2, 'Green', 1) + band(3, 'Blue', 1) + band(4, 'Alpha', 2)
    return f'<VRTDataset rasterXSize="{width}" rasterYSize="{height}">{bands}</VRTDataset>'


def png_from_geotiff(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
    """mosaic.png from a GeoTIFF written by this module, streamed by GDAL's PNG CreateCopy, atomically.

    The PNG has the TIFF's pixels: RGB(A) as is, grey as grey, grey+alpha as RGBA with the grey
    repeated (the layout of ``mosaic_files.write_png``). No georeferencing is carried over (no
    .aux.xml, no world file): mosaic.tif and mosaic.kml carry it. Memory: GDAL's cache
    (GDAL_CACHE_BYTES), which holds a row of the source's blocks as the scanlines are read.
    """
    import rasterio
    import rasterio.shutil
    from rasterio.enums import ColorInterp
    from rasterio.io import MemoryFile

    src = Path(src).resolve()
    with _gdal_env():
        with rasterio.open(src) as ds:
            if ds.dtypes[0] != 'uint8' or ds.count not in (1, 2, 3, 4):
                msg = f'{src}: png_from_geotiff takes 1 to 4 uint8 bands, not {ds.count} {ds.dtypes[0]}.'
                raise ValueError(msg)
            grey_alpha = ds.count == 2 and ds.colorinterp[1] == ColorInterp.alpha
            width, height = ds.width, ds.height
        with atomic_path(dst) as tmp, _gdal_errors(dst) as errors:
            os.unlink(tmp)  # GDAL creates the file itself
            if grey_alpha:
                with MemoryFile(_grey_alpha_as_rgba_vrt(src, width, height).encode(), ext='vrt') as mem, \
                        mem.open() as vrt:
                    rasterio.shutil.copy(vrt, tmp, driver='PNG', ZLEVEL=PNG_ZLEVEL)
            else:
                rasterio.shutil.copy(src, tmp, driver='PNG', ZLEVEL=PNG_ZLEVEL)
            errors.check(dst)


def read_raster(path: str | os.PathLike[str]) -> GeoRaster:
    """The grid of a GeoTIFF this package wrote (mosaic.tif): its EPSG code and geotransform as a
    GeoRaster (pixel (0, 0)'s centre, gsd, rotation). Raises ValueError for a file without a CRS
    with an EPSG code, or whose pixels are not square (not one of ours)."""
    import math

    import rasterio

    from ..core.georef.georeferencer import GeoRaster

    with _gdal_env(), rasterio.open(path) as src:
        crs, t = src.crs, src.transform
    epsg = crs.to_epsg() if crs is not None else None
    if epsg is None:
        msg = f'{path} has no CRS with an EPSG code; it is not a georeferenced mosaic of srmosaic_ros.'
        raise ValueError(msg)
    g = math.hypot(t.a, t.d)
    if not (g > 0 and math.isclose(t.e, -t.a, rel_tol=1e-6, abs_tol=1e-9 * g)
            and math.isclose(t.b, t.d, rel_tol=1e-6, abs_tol=1e-9 * g)):
        msg = f'{path} has no square, unmirrored pixels (geotransform {tuple(t)[:6]}); not a mosaic of srmosaic_ros.'
        raise ValueError(msg)
    e0, n0 = t @ (0.5, 0.5)  # the centre of pixel (0, 0)
    return GeoRaster(int(epsg), float(g), float(e0), float(n0), math.atan2(t.d, t.a))
