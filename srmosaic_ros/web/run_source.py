"""A finished ``process`` run as a :class:`~srmosaic_ros.web.source.MapSource` (``srmosaic serve OUT_DIR``).

What it reads from OUT_DIR (the file contracts of DESIGN.md):

- ``mosaic.tif`` (a COG with an alpha band): the mosaic layer, tile by tile from its overviews;
- ``sr/mosaic_sr.tif`` and ``sr/tiles.json``: the SR layer, the SR mosaic only inside the tiles that
  were super-resolved (elsewhere mosaic_sr.tif is the mosaic upsampled, which adds nothing);
- ``poses.csv``: the track and the last pose; ``frames.csv`` with report.json's ``frame_size_px``:
  the last frame's footprint; ``report.json``: the frame count and a few figures.

A folder without mosaic.tif holds a mosaic that is not georeferenced: an InputError says so and how
to get one. The files are read when the source is made; when mosaic.tif or report.json is replaced
(``process`` run again into the folder) the next :meth:`RunSource.version` reloads them and grows.
"""
from __future__ import annotations

import json
import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from .source import LAYERS, MAX_ZOOM
from .tiles import WEB_MERCATOR, RasterGrid, encode_tile, overview_for, render_block, tile_bounds, tile_transform, zoom_range

__all__ = ['RunSource', 'TRACK_POINTS_MAX']

#: Most points of the track in status.json (every n-th pose beyond; the last is always kept).
TRACK_POINTS_MAX = 2000
#: Seconds between two looks at the files for a new run (version()).
RELOAD_CHECK_S = 1.0
#: Encoded tiles kept in memory (about 30 kB each).
TILE_CACHE = 2048


@dataclass
class _Run:
    """What one reading of OUT_DIR found."""

    stamp: tuple[int, ...]
    mosaic: Path
    grid: RasterGrid
    zooms: tuple[int, int]
    status: dict[str, Any]
    sr: Path | None = None
    sr_zooms: tuple[int, int] | None = None
    sr_boxes: list[tuple[float, float, float, float]] = field(default_factory=list)  # EPSG:3857 bboxes
    sr_shapes: list[dict[str, Any]] = field(default_factory=list)  # GeoJSON polygons in EPSG:3857


class RunSource:
    """The outputs of ``srmosaic process`` in ``out_dir`` as map tiles, a status and a version.

    Thread-safe: the server renders tiles on several threads; each thread reads through its own
    open datasets.
    """

    def __init__(self, out_dir: str | Path, *, report: dict[str, Any] | None = None) -> None:
        """report: the run's report, where report.json is not written yet (``process --tiles``)."""
        self.out = Path(out_dir)
        self._report = report
        self._lock = threading.Lock()
        self._local = threading.local()
        self._cache: OrderedDict[tuple[int, str, int, int, int], bytes | None] = OrderedDict()
        self._version = 1
        self._checked = time.monotonic()
        self._run = self._read()

    # -- MapSource ---------------------------------------------------------------------------------
    def version(self) -> int:
        """1, and one more each time a new run has replaced the files (checked once a second)."""
        now = time.monotonic()
        with self._lock:
            if now - self._checked < RELOAD_CHECK_S:
                return self._version
            self._checked = now
            if _stamp(self.out) == self._run.stamp:
                return self._version
        try:
            run = self._read()
        except (InputError, OSError, ValueError):
            return self._version  # a run being moved in: looked at again in a second
        with self._lock:
            if run.stamp != self._run.stamp:
                self._run, self._version = run, self._version + 1
                self._cache.clear()
            return self._version

    def status(self) -> dict[str, Any]:
        run = self._run
        return {**run.status, 'version': self._version}

    def tile_png(self, layer: str, z: int, x: int, y: int) -> bytes | None:
        if layer not in LAYERS:
            msg = f'layer {layer!r} is not one of {LAYERS}.'
            raise ValueError(msg)
        key = (self._version, layer, z, x, y)
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
        rgba = self.tile_rgba(layer, z, x, y)
        png = None if rgba is None else encode_tile(rgba)
        with self._lock:
            self._cache[key] = png
            while len(self._cache) > TILE_CACHE:
                self._cache.popitem(last=False)
        return png

    # -- rendering ---------------------------------------------------------------------------------
    def tile_rgba(self, layer: str, z: int, x: int, y: int) -> np.ndarray | None:
        """(256, 256, 4) uint8 RGBA of a tile of ``layer``, or None where nothing is painted."""
        if z > MAX_ZOOM or not (0 <= x < 1 << z and 0 <= y < 1 << z):
            return None
        block = self.block_rgba(layer, z, x, y, 1, 1)
        return None if block is None or not block[:, :, 3].any() else block

    def block_rgba(self, layer: str, z: int, x0: int, y0: int, nx: int, ny: int) -> np.ndarray | None:
        """(256 ny, 256 nx, 4) uint8 RGBA of the nx x ny tiles of ``layer`` from (x0, y0) (tiles.render_block),
        or None where the layer does not reach them."""
        run = self._run
        if layer == 'mosaic':
            return render_block(self._dataset(run.mosaic, z), z, x0, y0, nx, ny)
        first, last = tile_bounds(z, x0, y0), tile_bounds(z, x0 + nx - 1, y0 + ny - 1)
        box = (first[0], last[1], last[2], first[3])
        if run.sr is None or not any(_meets(b, box) for b in run.sr_boxes):
            return None
        rgba = render_block(self._dataset(run.sr, z), z, x0, y0, nx, ny)
        if rgba is None:
            return None
        from rasterio.features import rasterize

        inside = rasterize(run.sr_shapes, out_shape=rgba.shape[:2], transform=tile_transform(z, x0, y0), fill=0,
                           default_value=1, dtype='uint8', all_touched=False)
        rgba[:, :, 3] *= inside
        rgba[rgba[:, :, 3] == 0, :3] = 0
        return rgba

    def _dataset(self, path: Path, z: int) -> Any:
        """``path`` opened in this thread, at the overview that suits zoom z."""
        import rasterio

        opened: dict[tuple[Path, int | None, tuple[int, ...]], Any] = self._local.__dict__.setdefault('opened', {})
        stamp = self._run.stamp
        full = opened.get((path, None, stamp))
        if full is None:
            for key in [k for k in opened if k[2] != stamp]:  # a replaced run: close the old files
                opened.pop(key).close()
            full = opened[(path, None, stamp)] = rasterio.open(path)
        level = overview_for(full, z)
        if level is None:
            return full
        ds = opened.get((path, level, stamp))
        if ds is None:
            ds = opened[(path, level, stamp)] = rasterio.open(path, overview_level=level)
        return ds

    # -- reading the folder ------------------------------------------------------------------------
    def _read(self) -> _Run:
        out = self.out
        if not out.is_dir():
            msg = f'{out}: no such folder; give the --out folder of a `srmosaic process` run.'
            raise InputError(msg)
        report = self._report if self._report is not None else _read_json(out / 'report.json')
        tif = out / 'mosaic.tif'
        if not tif.is_file():
            if report is None and not (out / 'mosaic.png').is_file():
                msg = f'{out} holds no run of `srmosaic process` (no report.json, no mosaic.tif); give its --out folder.'
                raise InputError(msg)
            why = (report or {}).get('not_georeferenced_reason')
            msg = (f'{out} has no mosaic.tif: its mosaic is not georeferenced{f" ({why})" if why else ""}, and a map needs '
                   'one. Run `srmosaic process` again on an input with positions (a GPS fix topic, KLV, a DJI .SRT, '
                   'geotagged stills, --telemetry or --gcp) with georeferencing on (georef.enabled), then serve its '
                   '--out folder.')
            raise InputError(msg)
        stamp = _stamp(out)
        import rasterio

        try:
            with rasterio.open(tif) as ds:
                grid = RasterGrid(ds.crs, ds.transform, ds.width, ds.height)
                crs_ok = ds.crs is not None
        except rasterio.errors.RasterioIOError as exc:
            msg = f'{tif} cannot be read ({exc}); run `srmosaic process` into {out} again.'
            raise InputError(msg) from None
        if not crs_ok:
            msg = f'{tif} has no CRS: not a georeferenced mosaic of srmosaic_ros.'
            raise InputError(msg)
        zooms = zoom_range(grid)
        run = _Run(stamp, tif, grid, zooms, {})
        self._read_sr(run)
        run.status = self._status(run, report or {})
        return run

    def _read_sr(self, run: _Run) -> None:
        """The SR layer: sr/mosaic_sr.tif, shown inside the boxes of sr/tiles.json."""
        sr_tif, listing = self.out / 'sr' / 'mosaic_sr.tif', _read_json(self.out / 'sr' / 'tiles.json')
        if not sr_tif.is_file() or not listing:
            return
        import rasterio
        from rasterio.warp import transform_geom

        with rasterio.open(sr_tif) as ds:
            if ds.crs is None:
                return
            sr_grid = RasterGrid(ds.crs, ds.transform, ds.width, ds.height)
        t = run.grid.transform  # tiles.json boxes are in mosaic pixels (mosaic.tif's grid), corners at integers
        for entry in listing:
            x0, y0, w, h = (float(entry[k]) for k in ('x0', 'y0', 'width', 'height'))
            ring = [list(t @ (c, r)) for c, r in ((x0, y0), (x0 + w, y0), (x0 + w, y0 + h), (x0, y0 + h), (x0, y0))]
            shape = transform_geom(run.grid.crs, WEB_MERCATOR, {'type': 'Polygon', 'coordinates': [ring]})
            xs, ys = zip(*shape['coordinates'][0], strict=True)
            run.sr_shapes.append(shape)
            run.sr_boxes.append((min(xs), min(ys), max(xs), max(ys)))
        run.sr = sr_tif
        sr_min, sr_max = zoom_range(sr_grid)
        run.sr_zooms = (max(run.zooms[0], min(run.zooms[1] - 1, sr_max)), sr_max)

    def _status(self, run: _Run, report: dict[str, Any]) -> dict[str, Any]:
        from rasterio.warp import transform

        poses = _read_poses(self.out / 'poses.csv')
        pose = None
        if poses:
            last = poses[-1]
            yaw = last['yaw']
            pose = {'lat': last['latitude'], 'lon': last['longitude'],
                    'alt': last['altitude'] if math.isfinite(last['altitude']) else None,
                    'yaw_deg': yaw if math.isfinite(yaw) else None,
                    # yaw is the body x axis counter-clockwise from east (ENU, REP 103); a heading runs clockwise from north
                    'heading_deg': (90.0 - yaw) % 360.0 if math.isfinite(yaw) else None}
        track = None
        if len(poses) >= 2:
            step = max(1, math.ceil(len(poses) / TRACK_POINTS_MAX))
            kept = poses[::step] + ([poses[-1]] if (len(poses) - 1) % step else [])
            track = {'type': 'LineString', 'coordinates': [[p['longitude'], p['latitude']] for p in kept]}
        footprint = None
        corners = _last_footprint_px(self.out / 'frames.csv', report.get('frame_size_px'))
        if corners is not None:
            t = run.grid.transform
            xy = [t @ (u + 0.5, v + 0.5) for u, v in corners]  # mosaic pixel centres at integers -> corner convention
            lon, lat = transform(run.grid.crs, 'EPSG:4326', [p[0] for p in xy], [p[1] for p in xy])
            ring = [[float(a), float(b)] for a, b in zip(lon, lat, strict=True)]
            footprint = {'type': 'Polygon', 'coordinates': [ring + ring[:1]]}
        sr = report.get('sr') or {}
        geo = report.get('georeferenced') or {}
        return {
            'frames': report.get('frames_in'),
            'pose': pose, 'footprint': footprint, 'track': track,
            'bounds': [round(v, 9) for v in run.grid.bounds_lonlat],
            'minzoom': run.zooms[0], 'maxzoom': run.zooms[1],
            'sr_minzoom': run.sr_zooms[0] if run.sr_zooms else None,
            'sr_maxzoom': run.sr_zooms[1] if run.sr_zooms else None,
            'diagnostics': {'out_dir': str(self.out.resolve()), 'input': report.get('input'),
                            'frames_registered': report.get('frames_registered'), 'wall_s': report.get('wall_s'),
                            'epsg': geo.get('epsg'), 'gsd_m_per_px': geo.get('gsd_m_per_px'),
                            'sr_tiles': len(run.sr_shapes), 'sr_factor': sr.get('factor')},
            'live': False,
        }


def _stamp(out: Path) -> tuple[int, ...]:
    """Identity of a run's files: inode and modification time of mosaic.tif and report.json (0s when missing)."""
    stamp: list[int] = []
    for name in ('mosaic.tif', 'report.json'):
        try:
            st = (out / name).stat()
            stamp += [st.st_ino, st.st_mtime_ns]
        except OSError:
            stamp += [0, 0]
    return tuple(stamp)


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        msg = f'{path} cannot be read ({exc}); the folder is not a complete run: run `srmosaic process` into it again.'
        raise InputError(msg) from None


def _read_poses(path: Path) -> list[dict[str, Any]]:
    """poses.csv's rows with a finite position (none without the file)."""
    from ..io.poses_csv import read_poses_csv

    if not path.is_file():
        return []
    try:
        rows = read_poses_csv(path)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    return [r for r in rows if math.isfinite(r['latitude']) and math.isfinite(r['longitude'])]


def _last_footprint_px(frames_csv: Path, size: Any) -> list[tuple[float, float]] | None:
    """The outer corners in mosaic pixels of the last frame placed in the mosaic, or None (no frames.csv,
    or no frame size in report.json)."""
    from ..core.georef.ground_homography import apply_H
    from ..io.mosaic_files import read_frames_csv

    if not frames_csv.is_file() or not size:
        return None
    rows = [r for r in read_frames_csv(frames_csv) if r['ok']]
    if not rows:
        return None
    w, h = float(size[0]), float(size[1])
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    xy = apply_H(rows[-1]['mosaic_H_frame'], corners)
    return [(float(u), float(v)) for u, v in xy]


def _meets(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]
