"""The map of a finished run as files: ``process --tiles`` (XYZ tiles and the offline page) and ``--kmz``.

``write_tiles(out, fmt)`` writes, into a georeferenced run's folder ``out``:

- ``tiles/{z}/{x}/{y}.png`` (or ``.webp``): the mosaic layer for its zoom range (web/tiles.py's
  zoom_range), rendered as ``srmosaic serve`` renders it (:class:`~srmosaic_ros.web.run_source.RunSource`);
- ``sr/{z}/{x}/{y}.png`` (or ``.webp``) when the run has SR tiles: the SR layer, the same URLs
  relative to the page as the server's ``/sr/...``;
- ``map.html`` with ``map_config.js`` (the settings and the status, a script because a page opened
  from file:// may not fetch) and ``map_files/`` (Leaflet and the page's script and style): the
  server's page, which opens offline from the folder.

``write_kmz(out)`` writes ``mosaic.kmz``: a zip of ``doc.kml`` (first, as KMZ readers expect), a
GroundOverlay with the gx:LatLonQuad of mosaic.tif's corners (io/kml.py), and ``mosaic.png``, the
mosaic with its alpha, downscaled to at most ``KMZ_MAX_SIDE`` px on its longer side (Google Earth
draws an overlay as one texture).

The page and the KMZ are written under a temporary name and renamed into place; the tiles are
written as they are (into the run's staging folder, which ``process`` moves in whole).
"""
from __future__ import annotations

import os
import shutil
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from ..io.mosaic_files import atomic_path
from .run_source import RunSource
from .server import ASSETS, PAGE_FILE, STATIC_FILES, page_config_js, static_bytes
from .source import TILE_SIZE
from .tiles import ENCODINGS, encode_tile, tiles_covering

__all__ = ['KMZ_MAX_SIDE', 'TILE_FORMATS', 'write_kmz', 'write_page', 'write_tiles']

#: Formats of ``process --tiles``.
TILE_FORMATS = tuple(ENCODINGS)
#: Tiles on a side of the blocks ``write_tiles`` warps at once (16 MB of RGBA at 8).
BLOCK_TILES = 8
#: Longest side (px) of the image in mosaic.kmz.
KMZ_MAX_SIDE = 8192
#: zlib level of the KMZ's PNG (as the tiles': level 6 makes them a sixth smaller at twice the time).
KMZ_PNG_LEVEL = 3


def write_tiles(out: Path, fmt: str = 'png', *, threads: int = 1, report: dict[str, Any] | None = None,
                name: str | None = None) -> dict[str, Any]:
    """The XYZ tiles of both layers and the offline page into ``out`` (a georeferenced run's folder).

    report: the run's report when report.json is not written yet (its frame count goes on the page);
    name: the run's name in the page's title (default: the folder's).
    Returns report.json's figures: tiles written per layer, zooms, format, bytes.
    """
    if fmt not in TILE_FORMATS:
        msg = f'--tiles {fmt}: the tile format is one of {", ".join(TILE_FORMATS)}.'
        raise ValueError(msg)
    source = RunSource(out, report=report)
    status = source.status()
    status['diagnostics'].pop('out_dir', None)  # the page goes where the folder goes
    ext = ENCODINGS[fmt][0]
    figures: dict[str, Any] = {'format': fmt, 'layers': {}}
    jobs = []
    for layer, folder, zooms in (('mosaic', 'tiles', (status['minzoom'], status['maxzoom'])),
                                 ('sr', 'sr', (status['sr_minzoom'], status['sr_maxzoom']))):
        if zooms[1] is None:
            continue
        root = out / folder
        if folder == 'tiles' and root.exists():
            shutil.rmtree(root)  # an earlier --tiles run's: its zooms or format may differ
        for z in range(zooms[0], zooms[1] + 1):
            jobs += _blocks(layer, root, z, [(x, y) for _, x, y in tiles_covering(status['bounds'], z)])
        figures['layers'][layer] = {'minzoom': zooms[0], 'maxzoom': zooms[1], 'tiles': 0, 'bytes': 0}

    def one(job: tuple[str, Path, int, int, int, int, int]) -> tuple[str, int, int]:
        layer, root, z, x0, y0, nx, ny = job
        block = source.block_rgba(layer, z, x0, y0, nx, ny)
        count = size = 0
        for j in range(ny if block is not None else 0):
            for i in range(nx):
                rgba = block[TILE_SIZE * j:TILE_SIZE * (j + 1), TILE_SIZE * i:TILE_SIZE * (i + 1)]
                if not rgba[:, :, 3].any():
                    continue
                data = encode_tile(np.ascontiguousarray(rgba), fmt)
                path = root / str(z) / str(x0 + i) / f'{y0 + j}{ext}'
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(data)  # inside the run's staging folder, or a folder the run owns
                count, size = count + 1, size + len(data)
        return layer, count, size

    with ThreadPoolExecutor(max(1, threads)) as pool:
        for layer, count, size in pool.map(one, jobs):
            figures['layers'][layer]['tiles'] += count
            figures['layers'][layer]['bytes'] += size
    layers = {'mosaic': f'tiles/{{z}}/{{x}}/{{y}}{ext}', 'sr': f'sr/{{z}}/{{x}}/{{y}}{ext}'}
    write_page(out, status, layers, title=f'srmosaic map: {name or out.resolve().name}')
    figures['page'] = 'map.html'
    return figures


def _blocks(layer: str, root: Path, z: int, tiles: list[tuple[int, int]]) -> list[tuple[str, Path, int, int, int, int, int]]:
    """The tiles of one zoom as blocks of at most BLOCK_TILES x BLOCK_TILES (one warp each):
    (layer, root, z, x0, y0, nx, ny)."""
    groups: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for x, y in tiles:
        groups.setdefault((x // BLOCK_TILES, y // BLOCK_TILES), []).append((x, y))
    blocks = []
    for members in groups.values():
        xs, ys = [x for x, _ in members], [y for _, y in members]
        blocks.append((layer, root, z, min(xs), min(ys), max(xs) - min(xs) + 1, max(ys) - min(ys) + 1))
    return blocks


def write_page(out: Path, status: dict[str, Any], layers: dict[str, str], *, title: str = 'srmosaic map') -> None:
    """map.html, map_config.js (the settings with ``status`` inline) and map_files/ into ``out``."""
    config = {'mode': 'static', 'title': title, 'layers': layers, 'status': status}
    for name, (path, _) in STATIC_FILES.items():
        target = out / ASSETS / name
        target.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(target) as tmp:
            Path(tmp).write_bytes(static_bytes(path))
    with atomic_path(out / 'map_config.js') as tmp:
        Path(tmp).write_text(page_config_js(config))
    with atomic_path(out / 'map.html') as tmp:
        Path(tmp).write_bytes(static_bytes(PAGE_FILE))


def write_kmz(out: Path) -> dict[str, Any]:
    """mosaic.kmz beside mosaic.tif in ``out``: doc.kml (a gx:LatLonQuad GroundOverlay) and mosaic.png.

    Returns report.json's figures: the image's size, bytes.
    """
    import cv2
    import rasterio
    from rasterio.enums import Resampling

    from ..io.geotiff import read_raster
    from ..io.kml import write_kml

    tif = out / 'mosaic.tif'
    raster = read_raster(tif)
    with rasterio.open(tif) as ds:
        width, height, count = ds.width, ds.height, ds.count
        scale = min(1.0, KMZ_MAX_SIDE / max(width, height))
        shape = (count, max(1, round(height * scale)), max(1, round(width * scale)))
        bands = ds.read(out_shape=shape, resampling=Resampling.average if scale < 1.0 else Resampling.nearest)
    colour = bands[:-1] if count in (2, 4) else bands
    alpha = bands[-1] if count in (2, 4) else np.full(shape[1:], 255, np.uint8)
    rgb = np.repeat(colour, 3, axis=0) if colour.shape[0] == 1 else colour
    bgra = np.dstack([rgb[2], rgb[1], rgb[0], alpha])
    ok, png = cv2.imencode('.png', bgra, [cv2.IMWRITE_PNG_COMPRESSION, KMZ_PNG_LEVEL])
    if not ok:
        msg = 'OpenCV could not encode the KMZ image.'
        raise RuntimeError(msg)
    corners = raster.corners_lonlat(width, height)  # the outer corners: the same whatever the image's scale
    with atomic_path(out / 'mosaic.kmz') as tmp:
        kml = Path(f'{tmp}.doc.kml')
        try:
            write_kml(kml, 'mosaic.png', corners, name=f'srmosaic mosaic {out.resolve().name}')
            with zipfile.ZipFile(tmp, 'w') as zf:
                zf.write(kml, 'doc.kml', compress_type=zipfile.ZIP_DEFLATED)
                zf.writestr('mosaic.png', png.tobytes(), compress_type=zipfile.ZIP_STORED)  # PNG is compressed already
        finally:
            if kml.exists():
                os.unlink(kml)
    return {'file': 'mosaic.kmz', 'image_px': [shape[2], shape[1]], 'bytes': (out / 'mosaic.kmz').stat().st_size}
