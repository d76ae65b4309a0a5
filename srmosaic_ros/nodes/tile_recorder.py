"""TileRecorderNode: the ground station's end of the live graph, SR tiles (and the preview) as GeoTIFFs.

`srmosaic record-tiles DIR [--preview]` (or `ros2 run srmosaic_ros tile_recorder DIR [--preview]`)
subscribes to srmosaic/sr_tile, srmosaic/raster (relative: under its namespace; transient local:
the last one arrives at once) and, with --preview, /srmosaic/mosaic_preview, and
writes what it receives into DIR:

- ``sr_tiles/seg<k>_x<x0>_y<y0>.tif``: each SR tile as a GeoTIFF on the map (the live raster's CRS,
  drift control's canvas similarity taken out: live/raster.py); a tile published again (a refresh,
  made from more frames) replaces its file. When a newer /srmosaic/raster moves the estimate by
  more than 2 cm (at 1000 px from the plane's origin), the geotransforms of the tiles written so far
  are updated in place (pixels untouched), so that all tiles follow the newest estimate and stay
  consistent with each other. Without georeferencing (no
  /srmosaic/raster yet) the tile is written as ``.png`` with its placement in ``.json`` beside it;
- ``preview.tif`` (or ``preview.png``): the newest mosaic preview, placed the same way.

Files are written under temporary names and renamed into place (a GIS tool watching the folder
never reads half a file). Messages that cannot be placed are counted and logged once per kind.
"""
from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from msg_adapters import image_to_rgb_or_mono

from ..core.image_ops import to_float01
from ..errors import SrMosaicError
from ..io.geotiff import GeoGrid, write_geotiff
from ..io.mosaic_files import write_json, write_png
from ..live.raster import ImagePlacement, LiveRaster
from .common import TOPICS, WarnOnce
from .messages import Messages, message_kind

__all__ = ['TileRecorderNode']


class TileRecorderNode(Node):
    """Writes /srmosaic/sr_tile (and /srmosaic/mosaic_preview) into a folder (module docstring)."""

    def __init__(self, out_dir: str | Path, *, previews: bool = False, **kwargs: Any) -> None:
        super().__init__('srmosaic_tile_recorder', **kwargs)
        self.out = Path(out_dir)
        (self.out / 'sr_tiles').mkdir(parents=True, exist_ok=True)
        self.warn = WarnOnce(self)
        self._raster: LiveRaster | None = None
        self._placed: dict[Path, tuple[str, int, int]] = {}  # GeoTIFFs written: frame_id, width, height
        self._updated_for: LiveRaster | None = None  # the raster the written files were last placed by
        self._lock = threading.Lock()
        self.written: dict[str, int] = {'tiles': 0, 'previews': 0}
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.declare_parameter('live.message_types', 'portable')  # as the graph's (nodes/messages.py)
        self.messages = Messages(message_kind(self))
        self.create_subscription(self.messages.raster_type, TOPICS['raster'], self._on_raster, latched)
        self.create_subscription(Image, TOPICS['sr_tile'], self._on_tile, 20)
        if previews:
            self.create_subscription(Image, TOPICS['preview'], self._on_preview, 1)
        self.get_logger().info(f'recording SR tiles{" and previews" if previews else ""} into {self.out}')

    def _on_raster(self, msg: Any) -> None:
        try:
            raster = self.messages.read_raster(msg)
        except SrMosaicError as exc:
            self.warn('raster', f'/srmosaic/raster skipped: {exc}')
            return
        with self._lock:
            self._raster = raster
            placed = dict(self._placed)
            moved = raster.moved_m(self._updated_for) > 0.02
        if moved:  # (the estimate moves by millimetres most seconds: leave the files alone then)
            self._update_geotransforms(raster, placed)
            self._updated_for = raster

    def _update_geotransforms(self, raster: LiveRaster, placed: dict[Path, tuple[str, int, int]]) -> None:
        """Put the GeoTIFFs written so far where the newest raster estimate says (metadata only)."""
        import rasterio
        from rasterio._err import CPLE_BaseError  # GDAL's errors as rasterio raises them
        from rasterio.transform import Affine

        for path, (frame_id, width, height) in placed.items():
            gt = raster.image_geotransform(frame_id, width, height)
            try:
                with rasterio.open(path, 'r+') as ds:
                    old = ds.transform.to_gdal()
                    if ds.crs is not None and ds.crs.to_epsg() == raster.epsg and \
                            max(abs(a - b) for a, b in zip(old, gt, strict=True)) <= 1e-3:
                        continue
                    ds.crs = f'EPSG:{raster.epsg}'
                    ds.transform = Affine.from_gdal(*gt)
            except (OSError, rasterio.errors.RasterioError, CPLE_BaseError) as exc:
                self.warn('geotransform update', f'{path}: geotransform not updated: {exc}')

    def _on_tile(self, msg: Image) -> None:
        try:
            place = ImagePlacement.parse(msg.header.frame_id)
        except SrMosaicError as exc:
            self.warn('tile placement', f'SR tile skipped: {exc}')
            return
        self._write(msg, self.out / 'sr_tiles' / f'seg{place.segment}_x{place.x0}_y{place.y0}', 'tiles')

    def _on_preview(self, msg: Image) -> None:
        self._write(msg, self.out / 'preview', 'previews')

    def _write(self, msg: Image, stem: Path, kind: str) -> None:
        try:
            image = image_to_rgb_or_mono(msg)
            with self._lock:
                raster = self._raster
            if raster is not None:
                gt = raster.image_geotransform(msg.header.frame_id, int(msg.width), int(msg.height))
                # a plain GeoTIFF: its geotransform is updated in place as the raster estimate moves
                write_geotiff(stem.with_suffix('.tif'), image, GeoGrid(raster.epsg, gt, abs(gt[1])), cog=False)
                with self._lock:
                    self._placed[stem.with_suffix('.tif')] = (msg.header.frame_id, int(msg.width), int(msg.height))
            else:
                write_png(stem.with_suffix('.png'), to_float01(image))
                write_json(stem.with_suffix('.json'), {'frame_id': msg.header.frame_id, 'width': int(msg.width),
                                                       'height': int(msg.height)})
        except (SrMosaicError, ValueError, OSError) as exc:
            self.warn(f'{kind} not written', f'{kind[:-1]} not written to {stem}: {exc}')
            return
        self.written[kind] += 1

    def finish(self) -> None:
        self.get_logger().info(f"wrote {self.written['tiles']} SR tiles and {self.written['previews']} previews "
                               f'into {self.out}')
