"""MapServerNode: the live map at the ground station, a web page over the graph's topics.

`ros2 run srmosaic_ros map_server` (or `srmosaic map-server [--port N] [--bind ADDR]`, or
`srmosaic launch launch/srmosaic.launch.xml map:=true`) subscribes (relative names, under its
namespace) to srmosaic/map_tile (the mosaic node's changed tiles), srmosaic/map_tiles (their summary,
transient local), srmosaic/raster (where the live plane lies), srmosaic/sr_tile, srmosaic/fix and
srmosaic/pose (the aircraft), srmosaic/footprint (the ground its camera sees) and
srmosaic/diagnostics, feeds what they say to a :class:`LiveMapSource`, and serves it
with the map server of web/server.py at http://live.map_bind:live.map_port/ (the page, /tiles/,
/sr/, /status.json, /events).

A late joiner gets the whole map: at start, and whenever a summary lists tiles it lacks, it asks
the mosaic node's srmosaic/get_map service (and the SR node's srmosaic/get_sr_map) for every tile
sent so far; the tiles not sent yet come on the topics (nodes/map_tile_feed.py).

Its own process: rclpy spins on the main thread, the web server (aiohttp, its own event loop) on
another, its tiles rendered on a thread pool; the mosaic node never waits for it.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PolygonStamped, PoseWithCovarianceStamped
from rclpy.node import Node
from sensor_msgs.msg import NavSatFix

from ..errors import ConfigError, SrMosaicError
from ..live.map_tiles import FOOTPRINT_FRAME
from ..web.live_source import LiveMapSource
from .common import TOPICS, WarnOnce
from .map_tile_feed import ASK_EVERY_S, TileFeed
from .messages import Messages, message_kind
from .parameters import MAP_SERVER_PARAMETERS, declare_pipeline_parameters
from .tile_stream_publisher import LATCHED_QOS

__all__ = ['ASK_EVERY_S', 'MapServerNode', 'MOSAIC_STATUS']

#: The diagnostic status of the mosaic node (nodes/mosaic_node.py) whose values the status shows.
MOSAIC_STATUS = 'srmosaic: registration and mosaic'


class MapServerNode(Node):
    """The live web map (module docstring). ``port`` and ``bind`` override live.map_port and live.map_bind."""

    def __init__(self, *, port: int | None = None, bind: str | None = None, **kwargs: Any) -> None:
        super().__init__('srmosaic_map_server', **kwargs)
        declare_pipeline_parameters(self, MAP_SERVER_PARAMETERS)
        port = int(self.get_parameter('live.map_port').value) if port is None else int(port)
        bind = str(self.get_parameter('live.map_bind').value) if bind is None else str(bind)
        if not 0 <= port <= 65535 or not bind:
            msg = f'live.map_port must be in 1..65535 (0: any free port) and live.map_bind an address, got {port} and {bind!r}.'
            raise ConfigError(msg)
        self.warn = WarnOnce(self)
        self.messages = Messages(message_kind(self))
        self.source = LiveMapSource()
        self.feeds = {'mosaic': TileFeed(self, self.source, 'mosaic', self.warn, tile='map_tile', summary='map_tiles',
                                         service='get_map'),
                      'sr': TileFeed(self, self.source, 'sr', self.warn, tile='sr_map_tile', summary='sr_map_tiles',
                                     service='get_sr_map')}
        self.create_subscription(self.messages.raster_type, TOPICS['raster'], self._on_raster, LATCHED_QOS)
        self.create_subscription(NavSatFix, TOPICS['fused_fix'], self._on_fix, 50)
        self.create_subscription(PoseWithCovarianceStamped, TOPICS['pose'], self._on_pose, 50)
        self.create_subscription(PolygonStamped, TOPICS['footprint'], self._on_footprint, 10)
        self.create_subscription(DiagnosticArray, 'srmosaic/diagnostics', self._on_diagnostics, 10)
        from ..web.server import start_in_thread

        try:
            self.server = start_in_thread(self.source, port=port, bind=bind,
                                          page_config={'title': f'srmosaic live map ({self.get_namespace()})'
                                                       if self.get_namespace() != '/' else 'srmosaic live map'})
        except OSError as exc:
            msg = (f'the map server cannot listen on {bind}:{port} ({exc.strerror or exc}): set live.map_port to a free '
                   'port (srmosaic map-server --port N) or live.map_bind to an address of this machine.')
            raise ConfigError(msg) from None
        self.get_logger().info(f'live map at {self.server.url}')

    @property
    def url(self) -> str:
        return self.server.url

    # -- where the map lies, the aircraft, the footprint, the node's state --------------------------
    def _on_raster(self, msg: Any) -> None:
        try:
            self.source.set_raster(self.messages.read_raster(msg))
        except SrMosaicError as exc:
            self.warn('raster', f'/srmosaic/raster skipped: {exc}')

    def _on_fix(self, msg: NavSatFix) -> None:
        self.source.set_pose(float(msg.latitude), float(msg.longitude), float(msg.altitude))

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        q = msg.pose.pose.orientation  # body in ENU: yaw counter-clockwise from east (REP 103)
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        self.source.set_yaw(math.degrees(yaw))

    def _on_footprint(self, msg: PolygonStamped) -> None:
        if msg.header.frame_id != FOOTPRINT_FRAME:
            self.warn('footprint frame', f'/srmosaic/footprint in frame {msg.header.frame_id!r} skipped (expected {FOOTPRINT_FRAME!r})')
            return
        self.source.set_footprint(np.array([[p.x, p.y] for p in msg.polygon.points], np.float64))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == MOSAIC_STATUS:
                values = {kv.key: kv.value for kv in status.values}
                self.source.set_diagnostics({'level': int.from_bytes(status.level, 'little')
                                             if isinstance(status.level, bytes) else int(status.level),
                                             'message': status.message, **values})
                if str(values.get('frames_processed', '')).isdigit():
                    self.source.set_frames(int(values['frames_processed']))

    def finish(self) -> None:
        self.server.stop()

