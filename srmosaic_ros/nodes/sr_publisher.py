"""SRPublisher: the SR node's tiles on /srmosaic/sr_tile and, with live.map_tiles, on the budgeted tile stream.

Every tile made goes at once on /srmosaic/sr_tile (sensor_msgs/Image, rgb8 or mono8, header.stamp
the newest frame used, header.frame_id its live.sr.SRTilePlacement), and is offered to the SR tile
stream (live/sr_tile_stream.py): /srmosaic/sr_map_tile (CompressedImage PNG, reliable), within
live.sr_map_bytes_per_s, oldest first, none lost; the latched summary /srmosaic/sr_map_tiles and the
service /srmosaic/get_sr_map (std_srvs/Trigger: every tile sent so far) for late joiners, as the
mosaic node's map tiles (nodes/tile_stream_publisher.py). The stream is drained every DRAIN_S on the
executor. It also keeps the reconstruction times of the diagnostics.
"""
from __future__ import annotations

import collections
import time
from typing import Any

import numpy as np
from sensor_msgs.msg import Image

from msg_adapters import numpy_to_image

from ..live.sr_tile_stream import SRTileStream
from .common import TOPICS
from .tile_stream_publisher import TileStreamPublisher

__all__ = ['DRAIN_S', 'SRPublisher']

#: seconds between two drains of the SR tile stream (tiles held back by the budget go out then)
DRAIN_S = 0.25
#: reconstruction times kept for the diagnostics' median and p95
TIMES_KEPT = 200


class SRPublisher:
    """Publishes the SR tiles (module docstring). ``bytes_per_s``: the stream's budget; None: no stream."""

    def __init__(self, node: Any, bytes_per_s: float | None) -> None:
        self.times_s: collections.deque[float] = collections.deque(maxlen=TIMES_KEPT)
        self._node = node
        self._raw = node.create_publisher(Image, TOPICS['sr_tile'], 10)
        self.stream = SRTileStream(bytes_per_s) if bytes_per_s is not None else None
        self._wire = None
        if self.stream is not None:
            self._wire = TileStreamPublisher(node, self.stream, 'sr_map_tile', 'sr_map_tiles', 'get_sr_map')
            node.create_timer(DRAIN_S, self.drain)

    def publish(self, image: np.ndarray, frame_id: str, stamp_ns: int, seconds: float) -> None:
        """A tile made in ``seconds``: on /srmosaic/sr_tile now, on the stream when the budget allows."""
        encoding = 'mono8' if image.ndim == 2 else 'rgb8'
        self._raw.publish(numpy_to_image(image, encoding, stamp_ns=stamp_ns, frame_id=frame_id))
        self.times_s.append(seconds)
        if self.stream is not None:
            self.stream.offer(frame_id, image, time.monotonic())

    def drain(self) -> None:
        """Timer: the tiles the budget lets out now, then the summary when it changed."""
        stamp_ns = self._node.get_clock().now().nanoseconds
        self._wire.publish(self.stream.take(stamp_ns, time.monotonic()), stamp_ns)

    def set_budget(self, bytes_per_s: float) -> None:
        if self.stream is not None:
            self.stream.set_budget(float(bytes_per_s))
