"""TileStreamPublisher: a stream of PNG tiles on the wire with its latched summary and whole-map service.

The ROS side of a tile stream (live/map_tiles.py says the encoding): the mosaic node's
/srmosaic/map_tile + /srmosaic/map_tiles + /srmosaic/get_map, and the SR node's /srmosaic/sr_map_tile
+ /srmosaic/sr_map_tiles + /srmosaic/get_sr_map. The stream (a MapTileStream or an SRTileStream)
decides which tiles go and keeps what was sent; this class publishes them:

    tiles = TileStreamPublisher(node, stream, 'map_tile', 'map_tiles', 'get_map')
    tiles.publish(stream.encode(batch, stamp_ns), stamp_ns)   # the tiles, then the summary if it changed

Tiles: sensor_msgs/CompressedImage (format png, reliable, depth 256: a round's tiles are not lost on
the way), header.frame_id their placement; summary: std_msgs/String JSON, transient local (a late
subscriber gets the newest); service: std_srvs/Trigger, answered with every tile sent so far.
"""
from __future__ import annotations

from typing import Any

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..live.map_tiles import MAP_TILE_FORMAT
from .common import SERVICES, TOPICS

__all__ = ['LATCHED_QOS', 'TILES_QOS', 'TileStreamPublisher']

#: the summary's QoS: reliable, transient local, the newest only
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         history=HistoryPolicy.KEEP_LAST)
#: the tiles' QoS: reliable and deep enough for a round's tiles
TILES_QOS = QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


class TileStreamPublisher:
    """Publishes a tile stream's tiles and summary and answers its whole-map service (module docstring).

    ``stream`` has ``summary() -> str``, ``whole_map() -> str``, ``spend(nbytes)`` and ``pending``; ``tile``,
    ``summary`` are keys of nodes.common.TOPICS and ``service`` of SERVICES."""

    def __init__(self, node: Any, stream: Any, tile: str, summary: str, service: str) -> None:
        self.stream = stream
        self._pub_tile = node.create_publisher(CompressedImage, TOPICS[tile], TILES_QOS)
        self._pub_summary = node.create_publisher(String, TOPICS[summary], LATCHED_QOS)
        self._pending_said: int | None = None  # the pending count of the last summary (None: none sent)
        node.create_service(Trigger, SERVICES[service], self._whole_map, callback_group=MutuallyExclusiveCallbackGroup())

    def listened(self) -> bool:
        """Whether something subscribes to the tiles."""
        return self._pub_tile.get_subscription_count() > 0

    def publish(self, tiles: list[tuple[str, bytes]], stamp_ns: int) -> None:
        """Publish (frame_id, PNG) tiles stamped ``stamp_ns``, then the summary when tiles went out or
        the count of those waiting changed (its bytes count against the stream's budget too)."""
        for frame_id, data in tiles:
            msg = CompressedImage(format=MAP_TILE_FORMAT, data=data)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
            msg.header.frame_id = frame_id
            self._pub_tile.publish(msg)
        # The summary again when tiles went out or the count waiting changed: its bytes_sent counts
        # the summaries themselves, so comparing the text would send one every round for ever.
        pending = self.stream.pending
        if tiles or pending != self._pending_said:
            summary = self.stream.summary()
            self._pub_summary.publish(String(data=summary))
            self.stream.spend(len(summary))
            self._pending_said = pending

    def _whole_map(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Every tile sent so far (live/map_tiles.whole_map_text)."""
        response.success, response.message = True, self.stream.whole_map()
        return response
