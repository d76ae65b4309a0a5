"""MosaicPeriodic: the mosaic node's round every live.preview_period_s (preview, raster, map tiles, diagnostics).

Each round runs in a thread of its own (the executor is single-threaded, and rendering a large
mosaic takes longer than an image callback may wait); a round still running when the next is due
is skipped and counted as preview_rounds_skipped (the diagnostics still go out). Under the
worker's lock (waited for at most LOCK_WAIT_S, else the round publishes diagnostics only) it syncs
the paint thread, takes the raster when it moved, renders the preview incrementally and collects
the changed map tiles; outside it, it publishes them:

- /srmosaic/raster (transient local) when new or moved by more than 2 mm (live/raster.py);
- /srmosaic/mosaic_preview (Image) and /srmosaic/mosaic_preview/compressed (JPEG), header.frame_id
  the plane region shown (live.raster.ImagePlacement);
- with live.map_tiles, the changed tiles through a TileStreamPublisher (read only while something
  subscribes: otherwise they wait and go to the first subscriber);
- /srmosaic/diagnostics (MosaicDiagnostics).
"""
from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image

from msg_adapters import numpy_to_compressed, numpy_to_image

from ..io.outputs import preview_image
from ..live.raster import ImagePlacement, LiveRaster
from .common import TOPICS

__all__ = ['LOCK_WAIT_S', 'MosaicPeriodic']

#: seconds a round waits for the worker's lock (it holds it per frame) before it skips the render
LOCK_WAIT_S = 2.0
#: the raster is published again when the plane moved by more than this (m)
RASTER_MOVE_M = 0.002


class MosaicPeriodic:
    """One round every period (module docstring). ``tiles``: a TileStreamPublisher of a MapTileStream, or None."""

    def __init__(self, node: Any, worker: Any, diagnostics: Any, tiles: Any, preview_max_side_px: int) -> None:
        self._node = node
        self._worker = worker
        self._diagnostics = diagnostics
        self._tiles = tiles
        self._max_side = int(preview_max_side_px)
        self._pub_image = node.create_publisher(Image, TOPICS['preview'], 1)
        self._pub_compressed = node.create_publisher(CompressedImage, TOPICS['preview_compressed'], 1)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             history=HistoryPolicy.KEEP_LAST)
        self._pub_raster = node.create_publisher(node.messages.raster_type, TOPICS['raster'], latched)
        self._raster_sent: LiveRaster | None = None
        self._thread: threading.Thread | None = None

    def tick(self) -> None:
        """Timer: start a round, or skip it (counted) while the previous one still runs."""
        if self._thread is not None and self._thread.is_alive():
            self._node.warn.count('preview_rounds_skipped')
            self._diagnostics.publish(self._worker, self._node.active)
            return
        self._thread = threading.Thread(target=self._round, name='srmosaic-preview', daemon=True)
        self._thread.start()

    def join(self, timeout_s: float = 60.0) -> None:
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)

    def _round(self) -> None:
        image = coverage = raster = None
        tiles: list = []
        region = 'srmosaic_mosaic'
        worker = self._worker
        if worker.lock.acquire(timeout=LOCK_WAIT_S):  # the worker holds it per frame; skip a round when busy
            try:
                pipeline = worker.pipeline
                try:
                    pipeline.sync()  # the frames still being painted
                except Exception as exc:  # noqa: BLE001 - a paint that failed skips its frame, not the node
                    self._node.warn(f'paint: {type(exc).__name__}', f'a frame was not painted: {exc!r}')
                raster = self._moved_raster(pipeline)
                seg = pipeline.segments[-1] if pipeline.segments else None
                if seg is not None and not seg.canvas.is_empty:
                    # Incremental and reduced: the worker waits for this lock, so its cost must not
                    # grow with the mosaic (a full render of a long flight takes seconds).
                    image, coverage = seg.canvas.render_preview(self._max_side)
                    region = ImagePlacement(seg.index, *seg.canvas.last_preview_region).frame_id()
                if self._tiles is not None:  # the changed tiles: marked always, read only for a subscriber
                    tiles = self._tiles.stream.collect(pipeline.segments, time.monotonic(), send=self._tiles.listened())
            finally:
                worker.lock.release()
        clock = self._node.get_clock()
        if raster is not None:
            self._pub_raster.publish(self._node.messages.raster(raster, clock.now().nanoseconds))
        if image is not None:
            self._publish_preview(image, coverage, region, clock.now().nanoseconds)
        if self._tiles is not None:
            stamp_ns = clock.now().nanoseconds  # the tiles' stamp, as the summary lists it
            self._tiles.publish(self._tiles.stream.encode(tiles, stamp_ns), stamp_ns)
        self._diagnostics.publish(worker, self._node.active)

    def _publish_preview(self, image: np.ndarray, coverage: np.ndarray, region: str, stamp_ns: int) -> None:
        preview = preview_image(image, coverage, self._max_side)
        u8 = np.clip(preview * 255.0 + 0.5, 0, 255).astype(np.uint8)
        encoding = 'mono8' if u8.ndim == 2 else 'rgb8'
        # header.frame_id: the plane region the preview shows (live.raster.ImagePlacement)
        self._pub_image.publish(numpy_to_image(u8, encoding, stamp_ns=stamp_ns, frame_id=region))
        self._pub_compressed.publish(numpy_to_compressed(u8, stamp_ns=stamp_ns, frame_id=region))

    def _moved_raster(self, pipeline: Any) -> LiveRaster | None:
        """The raster to publish on /srmosaic/raster: when it is new, or drift control's canvas
        similarity moved the plane by more than RASTER_MOVE_M (else None). Under the worker's lock."""
        georef = pipeline.georef
        if georef is None or georef.raster is None:
            return None
        new = LiveRaster.from_georaster(georef.raster, georef.canvas_similarity)
        if new.moved_m(self._raster_sent) <= RASTER_MOVE_M:
            return None
        self._raster_sent = new
        return new
