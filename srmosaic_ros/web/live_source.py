"""LiveMapSource: the live graph's map as a MapSource, fed tiles, poses and footprints (no ROS here).

The map server node (nodes/map_server.py) receives /srmosaic/map_tile, /srmosaic/sr_tile,
/srmosaic/raster, the fused fix and pose, the registrations and the diagnostics, and hands what they
say to this class as numpy arrays and numbers; the web server (web/server.py) asks it for XYZ tiles
and the status. Every method is thread-safe (the ROS executor feeds it while the server's threads
read it).

Tiles lie on the live plane (an :class:`ImagePlacement` each: a region of plane pixels and its image)
and the plane lies on the map by the newest /srmosaic/raster (:class:`LiveRaster`: UTM, with drift
control's canvas similarity taken out). An XYZ tile is made by pasting the plane tiles it meets into
one array (reduced by a power of two when the XYZ pixel is coarser, premultiplied alpha) and
reprojecting it with GDAL's warper (web/tiles.render_tile); SR tiles are reprojected one by one over
each other. Rendered tiles are cached until a tile they show, or the raster, changes.
"""
from __future__ import annotations

import collections
import math
import threading
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..errors import SrMosaicError
from ..live.map_tiles import decode_tile
from ..live.raster import ImagePlacement, LiveRaster
from .source import LAYERS, MAX_ZOOM, TILE_SIZE
from .tiles import RasterGrid, encode_tile, render_tile, tile_bounds, zoom_range

__all__ = ['LiveMapSource']

#: Rendered XYZ tiles kept (each with what it was made from).
TILE_CACHE = 1024
#: Track points kept (the oldest are thinned to every other one when full).
TRACK_POINTS = 4000


@dataclass
class _PlaneTile:
    placement: ImagePlacement
    rgba: np.ndarray  # (h, w, 4) uint8
    serial: int
    stamp_ns: int | None = None

    @property
    def box(self) -> tuple[int, int, int, int]:
        p = self.placement
        return p.x0, p.y0, p.x0 + p.width, p.y0 + p.height


class LiveMapSource:
    """The live map (module docstring). Feed it with the ``set_*`` and ``add_*`` methods."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._version = 0
        self._serial = 0
        self._raster: LiveRaster | None = None
        self._raster_serial = 0
        self._tiles: dict[str, dict[tuple[int, int, int, int, int], _PlaneTile]] = {layer: {} for layer in LAYERS}
        self._frames = 0
        self._pose: dict[str, float | None] | None = None
        self._yaw: float | None = None
        self._footprint_raster: np.ndarray | None = None  # (N, 2) raster pixels
        self._track: list[tuple[float, float]] = []
        self._diagnostics: dict[str, Any] = {}
        self._boxes: dict[tuple[int, int, int, int], tuple[float, float, float, float]] = {}  # plane box of each XYZ tile
        self._cache: collections.OrderedDict[tuple[str, int, int, int], tuple[Any, bytes | None]] = collections.OrderedDict()

    # -- feeding ---------------------------------------------------------------------------------
    def _changed(self) -> None:
        self._version += 1

    def set_raster(self, raster: LiveRaster) -> None:
        """Where the live plane lies (the newest /srmosaic/raster); a move of more than 1 mm re-renders."""
        with self._lock:
            if self._raster is not None and raster.moved_m(self._raster) <= 0.001:
                return
            self._raster = raster
            self._raster_serial += 1
            self._changed()

    def add_tile(self, layer: str, frame_id: str, rgba: np.ndarray, *, stamp_ns: int | None = None) -> None:
        """A tile of ``layer`` ('mosaic' or 'sr'): its placement text (header.frame_id) and image, RGBA
        uint8 (h, w, 4) (or RGB / grey: opaque). It replaces the tile of the same region unless both
        have stamps and the one held is newer (a late joiner's whole map after the topic's tiles)."""
        if layer not in LAYERS:
            msg = f'layer {layer!r} is not one of {LAYERS}.'
            raise SrMosaicError(msg)
        placement = ImagePlacement.parse(frame_id)
        img = np.asarray(rgba)
        if img.ndim == 2:
            img = np.dstack([img, img, img, np.full(img.shape, 255, np.uint8)])
        elif img.shape[2] == 3:
            img = np.dstack([img, np.full(img.shape[:2], 255, np.uint8)])
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 4 or min(img.shape[:2]) < 1:
            msg = f'a map tile must be an RGBA, RGB or grey uint8 image, got {img.dtype} {img.shape}.'
            raise SrMosaicError(msg)
        img = np.ascontiguousarray(img)
        img[img[:, :, 3] == 0, :3] = 0  # premultiplied where transparent (what the reduction averages)
        key = (placement.segment, placement.x0, placement.y0, placement.width, placement.height)
        with self._lock:
            held = self._tiles[layer].get(key)
            if held is not None and held.stamp_ns is not None and stamp_ns is not None and stamp_ns < held.stamp_ns:
                return
            self._serial += 1
            self._tiles[layer][key] = _PlaneTile(placement, img, self._serial, stamp_ns)
            self._changed()

    def add_png(self, layer: str, frame_id: str, data: bytes, *, stamp_ns: int | None = None) -> None:
        """:meth:`add_tile` of a tile's PNG (as /srmosaic/map_tile carries it)."""
        self.add_tile(layer, frame_id, decode_tile(bytes(data)), stamp_ns=stamp_ns)

    def lacking(self, layer: str, tiles: list[tuple[str, int]]) -> list[str]:
        """Of the tiles named (placement text, stamp), those not held at that stamp or a newer one."""
        out = []
        with self._lock:
            held = self._tiles[layer]
            for frame_id, stamp_ns in tiles:
                p = ImagePlacement.parse(frame_id)
                tile = held.get((p.segment, p.x0, p.y0, p.width, p.height))
                if tile is None or (tile.stamp_ns is not None and tile.stamp_ns < stamp_ns):
                    out.append(frame_id)
        return out

    def set_frames(self, frames: int) -> None:
        with self._lock:
            if int(frames) != self._frames:
                self._frames = int(frames)
                self._changed()

    def set_pose(self, lat: float, lon: float, alt: float | None = None, yaw_deg: float | None = None) -> None:
        """The aircraft's fused position (WGS84 degrees, metres) and yaw (degrees, ENU: counter-clockwise
        from east, REP 103); it also extends the track."""
        if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90):
            return
        with self._lock:
            yaw_deg = self._yaw if yaw_deg is None else float(yaw_deg)
            self._yaw = yaw_deg
            self._pose = {'lat': float(lat), 'lon': float(lon), 'alt': None if alt is None else float(alt),
                          'yaw_deg': None if yaw_deg is None else float(yaw_deg),
                          'heading_deg': None if yaw_deg is None else (90.0 - float(yaw_deg)) % 360.0}
            if not self._track or self._track[-1] != (float(lon), float(lat)):
                self._track.append((float(lon), float(lat)))
                if len(self._track) > TRACK_POINTS:
                    half = len(self._track) // 2
                    self._track = self._track[:half:2] + self._track[half:]
            self._changed()

    def set_yaw(self, yaw_deg: float) -> None:
        """The yaw alone (degrees, ENU), as /srmosaic/pose says it; kept for the next position too."""
        if not math.isfinite(yaw_deg):
            return
        with self._lock:
            self._yaw = float(yaw_deg)
            if self._pose is not None:
                self._pose['yaw_deg'] = self._yaw
                self._pose['heading_deg'] = (90.0 - self._yaw) % 360.0
            self._changed()

    def set_footprint(self, corners_raster: np.ndarray) -> None:
        """The ground the aircraft's camera sees now: (N, 2) corners in pixels of the /srmosaic/raster
        grid (as /srmosaic/footprint carries them; LiveRaster.utm_H_raster puts them on the map)."""
        pts = np.asarray(corners_raster, np.float64).reshape(-1, 2)
        if len(pts) < 3 or not np.all(np.isfinite(pts)):
            return
        with self._lock:
            self._footprint_raster = pts
            self._changed()

    def set_diagnostics(self, values: dict[str, Any]) -> None:
        """The mosaic node's diagnostics (its status's message, level and values)."""
        with self._lock:
            if values != self._diagnostics:
                self._diagnostics = dict(values)
                self._changed()

    # -- MapSource -------------------------------------------------------------------------------
    def version(self) -> int:
        with self._lock:
            return self._version

    def status(self) -> dict[str, Any]:
        with self._lock:
            raster = self._raster
            boxes = {layer: [t.box for t in tiles.values()] for layer, tiles in self._tiles.items()}
            scales = {layer: min((t.placement.width / t.rgba.shape[1] for t in tiles.values()), default=1.0)
                      for layer, tiles in self._tiles.items()}
            out: dict[str, Any] = {'frames': self._frames, 'pose': None if self._pose is None else dict(self._pose),
                                   'diagnostics': dict(self._diagnostics), 'version': self._version, 'live': True,
                                   'tiles': {layer: len(b) for layer, b in boxes.items()},
                                   'track': {'type': 'LineString', 'coordinates': [list(p) for p in self._track]}
                                   if len(self._track) >= 2 else None}
            footprint = self._footprint_raster
        out.update({'footprint': None, 'bounds': None, 'minzoom': 0, 'maxzoom': 0, 'sr_minzoom': None, 'sr_maxzoom': None,
                    'georeferenced': raster is not None})
        if raster is None:
            return out
        from rasterio.warp import transform

        crs = f'EPSG:{raster.epsg}'
        if footprint is not None:
            utm = _apply(raster.utm_H_raster, footprint)
            lon, lat = transform(crs, 'EPSG:4326', list(utm[:, 0]), list(utm[:, 1]))
            ring = [[float(a), float(b)] for a, b in zip(lon, lat, strict=True)]
            out['footprint'] = {'type': 'Polygon', 'coordinates': [[*ring, ring[0]]]}
        for layer, prefix in (('mosaic', ''), ('sr', 'sr_')):
            if not boxes[layer]:
                continue
            grid = _grid(raster, _union(boxes[layer]), scales[layer])
            zmin, zmax = zoom_range(grid)
            out[f'{prefix}minzoom'], out[f'{prefix}maxzoom'] = zmin, zmax
            if layer == 'mosaic':
                out['bounds'] = [float(v) for v in grid.bounds_lonlat]
        return out

    def tile_png(self, layer: str, z: int, x: int, y: int) -> bytes | None:
        if layer not in LAYERS:
            msg = f'layer {layer!r} is not one of {LAYERS}.'
            raise ValueError(msg)
        if not (0 <= z <= MAX_ZOOM and 0 <= x < 1 << z and 0 <= y < 1 << z):
            return None
        with self._lock:
            raster = self._raster
            raster_serial = self._raster_serial
            tiles = list(self._tiles[layer].values())
        if raster is None or not tiles:
            return None
        box = self._boxes.get((raster_serial, z, x, y))
        if box is None:  # (PROJ per request: a page asks for the tiles in view at every change)
            box = _plane_box(raster, z, x, y)
            with self._lock:
                self._boxes[(raster_serial, z, x, y)] = box
                while len(self._boxes) > TILE_CACHE:
                    self._boxes.pop(next(iter(self._boxes)))
        meets = [t for t in tiles if t.box[0] < box[2] and box[0] < t.box[2] and t.box[1] < box[3] and box[1] < t.box[3]]
        if not meets:
            return None
        signature = (raster_serial, tuple(sorted(t.serial for t in meets)))
        key = (layer, z, x, y)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None and hit[0] == signature:
                self._cache.move_to_end(key)
                return hit[1]
        rgba = _render_pasted(raster, meets, z, x, y) if layer == 'mosaic' else _render_each(raster, meets, z, x, y)
        png = None if rgba is None else encode_tile(rgba)
        with self._lock:
            self._cache[key] = (signature, png)
            self._cache.move_to_end(key)
            while len(self._cache) > TILE_CACHE:
                self._cache.popitem(last=False)
        return png


# -- geometry and rendering ----------------------------------------------------------------------
def _apply(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    p = m @ np.vstack([pts.T, np.ones(len(pts))])
    return (p[:2] / p[2]).T


def _union(boxes: list[tuple[int, int, int, int]]) -> tuple[int, int, int, int]:
    a = np.array(boxes)
    return int(a[:, 0].min()), int(a[:, 1].min()), int(a[:, 2].max()), int(a[:, 3].max())


def _affine(raster: LiveRaster, box: tuple[int, int, int, int], width: int, height: int) -> Any:
    """rasterio Affine (pixel corners) of an image of width x height pixels showing plane region ``box``."""
    from rasterio.transform import Affine

    x0, y0, x1, y1 = box
    return Affine.from_gdal(*raster.image_geotransform(ImagePlacement(0, x0, y0, x1 - x0, y1 - y0).frame_id(), width, height))


def _grid(raster: LiveRaster, box: tuple[int, int, int, int], scale: float) -> RasterGrid:
    """The raster grid of plane region ``box`` at ``scale`` plane pixels per image pixel."""
    w, h = max(1, round((box[2] - box[0]) / scale)), max(1, round((box[3] - box[1]) / scale))
    return RasterGrid(f'EPSG:{raster.epsg}', _affine(raster, box, w, h), w, h)


def _plane_box(raster: LiveRaster, z: int, x: int, y: int) -> tuple[float, float, float, float]:
    """The plane-pixel box (x0, y0, x1, y1) an XYZ tile covers (its edges densified through PROJ)."""
    from rasterio.warp import transform_bounds

    left, bottom, right, top = transform_bounds('EPSG:3857', f'EPSG:{raster.epsg}', *tile_bounds(z, x, y), densify_pts=21)
    corners = np.array([[left, bottom], [right, bottom], [right, top], [left, top]])
    plane = _apply(np.linalg.inv(raster.utm_H_plane()), corners)
    return float(plane[:, 0].min()) - 1, float(plane[:, 1].min()) - 1, float(plane[:, 0].max()) + 1, float(plane[:, 1].max()) + 1


def _reduce(rgba: np.ndarray, k: int) -> np.ndarray:
    """RGBA (premultiplied where transparent) reduced by k: area means, colour un-premultiplied."""
    if k == 1:
        return rgba
    h, w = rgba.shape[0] // k, rgba.shape[1] // k
    small = cv2.resize(rgba[:h * k, :w * k].astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    a = small[:, :, 3:4]
    rgb = np.divide(small[:, :, :3] * 255.0, a, out=np.zeros_like(small[:, :, :3]), where=a > 0)
    return np.dstack([np.clip(rgb + 0.5, 0, 255), np.clip(a + 0.5, 0, 255)]).astype(np.uint8)


def _render_pasted(raster: LiveRaster, meets: list[_PlaneTile], z: int, x: int, y: int) -> np.ndarray | None:
    """The mosaic tiles ``meets`` (one grid: same image scale) pasted into one array, reduced as far
    as the XYZ pixel allows, reprojected into tile (z, x, y); newest on top where they overlap."""
    scale = min(t.placement.width / t.rgba.shape[1] for t in meets)  # plane pixels per image pixel
    box = _union([t.box for t in meets])
    side = min(min(t.rgba.shape[:2]) for t in meets)
    xyz_px = (tile_bounds(z, x, y)[2] - tile_bounds(z, x, y)[0]) / TILE_SIZE
    k = 1
    plane_px = _grid(raster, box, scale).pixel_size_3857
    while 2 * k <= side and side % (2 * k) == 0 and 2 * k * plane_px <= xyz_px:
        k *= 2
    step = scale * k  # plane pixels per pasted pixel
    w, h = max(1, math.ceil((box[2] - box[0]) / step)), max(1, math.ceil((box[3] - box[1]) / step))
    canvas = np.zeros((h, w, 4), np.uint8)
    for t in sorted(meets, key=lambda t: t.serial):
        img = t.rgba
        n_w, n_h = round(t.placement.width / step), round(t.placement.height / step)
        img = _reduce(img, k) if img.shape[1] // k == n_w else cv2.resize(img, (n_w, n_h), interpolation=cv2.INTER_AREA)
        c0, r0 = round((t.placement.x0 - box[0]) / step), round((t.placement.y0 - box[1]) / step)
        sub = canvas[r0:r0 + img.shape[0], c0:c0 + img.shape[1]]
        img = img[:sub.shape[0], :sub.shape[1]]
        opaque = img[:, :, 3] > 0
        sub[opaque] = img[opaque]
    transform = _affine(raster, (box[0], box[1], box[0] + round(w * step), box[1] + round(h * step)), w, h)
    return render_tile(canvas.transpose(2, 0, 1), z, x, y, transform=transform, crs=f'EPSG:{raster.epsg}')


def _render_each(raster: LiveRaster, meets: list[_PlaneTile], z: int, x: int, y: int) -> np.ndarray | None:
    """Each tile of ``meets`` reprojected into tile (z, x, y), newest over older (alpha over)."""
    out = None
    for t in sorted(meets, key=lambda t: t.serial):
        transform = _affine(raster, t.box, t.rgba.shape[1], t.rgba.shape[0])
        rgba = render_tile(t.rgba.transpose(2, 0, 1), z, x, y, transform=transform, crs=f'EPSG:{raster.epsg}')
        if rgba is None:
            continue
        if out is None:
            out = rgba
            continue
        a = rgba[:, :, 3:4].astype(np.float32) / 255.0
        out = np.dstack([(rgba[:, :, :3] * a + out[:, :, :3] * (1 - a)).astype(np.uint8),
                         np.maximum(out[:, :, 3], rgba[:, :, 3])])
    return out
