"""TileFeed: one layer of the map server, fed from a tile stream, its summary and its whole-map service.

A tile stream (nodes/tile_stream_publisher.py) is a topic of PNG tiles, a latched JSON summary of
the tiles sent so far, and a std_srvs/Trigger service answering all of them. The map server has two
(mosaic: srmosaic/map_tile, srmosaic/map_tiles, srmosaic/get_map; sr: srmosaic/sr_map_tile,
srmosaic/sr_map_tiles, srmosaic/get_sr_map); each feeds one layer of its LiveMapSource.

A late joiner gets the whole layer: at start, and whenever the summary lists a tile version older
than one the topic already brought which is not held (lost on the way: tiles come in order on one
topic; a tile merely still on its way, or the summary outrunning it, is no reason), the feed asks
the service for every tile sent so far, at most every ASK_EVERY_S. A newer tile from the topic
stays over an older one from the answer (LiveMapSource.add_png compares stamps).
"""
from __future__ import annotations

import json
import math
import time
from typing import Any

from sensor_msgs.msg import CompressedImage
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..errors import SrMosaicError
from ..live.map_tiles import parse_whole_map
from .common import SERVICES, TOPICS
from .tile_stream_publisher import LATCHED_QOS, TILES_QOS

__all__ = ['ASK_EVERY_S', 'TileFeed']

#: Seconds between two asks for the whole layer while tiles are missing.
ASK_EVERY_S = 5.0


class TileFeed:
    """Feeds ``layer`` of ``source`` (a LiveMapSource) from one tile stream (module docstring);
    ``tile``, ``summary`` are keys of nodes.common.TOPICS, ``service`` of SERVICES; ``warn``: the
    node's WarnOnce."""

    def __init__(self, node: Any, source: Any, layer: str, warn: Any, *, tile: str, summary: str, service: str) -> None:
        self.layer = layer
        self.got_whole_map = 0  # tiles taken from the service's answers
        self._source = source
        self._warn = warn
        self._names = (TOPICS[tile], TOPICS[summary], SERVICES[service])
        node.create_subscription(CompressedImage, TOPICS[tile], self._on_tile, TILES_QOS)
        node.create_subscription(String, TOPICS[summary], self._on_summary, LATCHED_QOS)
        self._client = node.create_client(Trigger, SERVICES[service])
        node.create_timer(1.0, self._ask_if_missing)
        self._missing = True  # at start: whatever was sent before this node joined
        self._asking = False
        self._asked_at = -math.inf
        self._newest_tile_ns: int | None = None  # stamp of the newest tile the topic brought

    def _on_tile(self, msg: CompressedImage) -> None:
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self._newest_tile_ns = max(stamp_ns, self._newest_tile_ns or stamp_ns)
        try:
            self._source.add_png(self.layer, msg.header.frame_id, bytes(msg.data), stamp_ns=stamp_ns)
        except SrMosaicError as exc:
            self._warn(f'{self.layer} tile', f'{self._names[0]} tile skipped: {exc}')

    def _on_summary(self, msg: String) -> None:
        try:
            listed = [(str(t[0]), int(t[1])) for t in json.loads(msg.data)['tiles']]
        except (ValueError, KeyError, TypeError, IndexError) as exc:
            self._warn(f'{self.layer} summary', f'{self._names[1]} skipped: {exc}')
            return
        arrived = self._newest_tile_ns
        try:
            lacking = arrived is not None and self._source.lacking(self.layer, [(f, s) for f, s in listed if s < arrived])
        except SrMosaicError as exc:
            self._warn(f'{self.layer} summary', f'{self._names[1]} skipped: {exc}')
            return
        if lacking:
            self._missing = True

    def _ask_if_missing(self) -> None:
        """Timer: ask the service for the whole layer when tiles are missing (at most every ASK_EVERY_S)."""
        if not self._missing or self._asking or time.monotonic() - self._asked_at < ASK_EVERY_S:
            return
        if not self._client.service_is_ready():
            return
        self._asking, self._asked_at = True, time.monotonic()
        self._client.call_async(Trigger.Request()).add_done_callback(self._on_whole_map)

    def _on_whole_map(self, future: Any) -> None:
        self._asking = False
        try:
            tiles = parse_whole_map(future.result().message)
        except (SrMosaicError, AttributeError) as exc:
            self._warn(f'{self.layer} whole map', f'{self._names[2]} answer skipped: {exc}')
            return
        self._missing = False
        for frame_id, stamp_ns, data in tiles:
            try:
                self._source.add_png(self.layer, frame_id, data, stamp_ns=stamp_ns)  # a newer one from the topic stays
                self.got_whole_map += 1
            except SrMosaicError as exc:
                self._warn(f'{self.layer} tile', f'{self._names[0]} tile skipped: {exc}')
