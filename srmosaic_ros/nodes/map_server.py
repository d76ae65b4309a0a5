"""MapServerNode: the live map at the ground station, a web page over the graph's topics.

`ros2 run srmosaic_ros map_server` (or `srmosaic map-server [--port N] [--bind ADDR]`, or
`srmosaic launch launch/srmosaic.launch.xml map:=true`) subscribes (relative names, under its
namespace) to srmosaic/map_tile (the mosaic node's changed tiles), srmosaic/map_tiles (their summary,
transient local), srmosaic/raster (where the live plane lies), srmosaic/sr_tile, srmosaic/fix and
srmosaic/pose (the aircraft), srmosaic/footprint (the ground its camera sees) and
srmosaic/diagnostics, feeds what they say to a :class:`LiveMapSource`, and serves it
with the map server of web/server.py at http://live.map_bind:live.map_port/ (the page, /tiles/,
/sr/, /status.json, /events).

A late joiner gets the whole map: at start, and whenever the summary lists tiles it lacks, it asks
the mosaic node's srmosaic/get_map service for every tile sent so far; the tiles the mosaic node
had not sent yet come on the topic (it sends the changed tiles while something subscribes).

Its own process: rclpy spins on the main thread, the web server (aiohttp, its own event loop) on
another, its tiles rendered on a thread pool; the mosaic node never waits for it.
"""
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PolygonStamped, PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image, NavSatFix
from std_msgs.msg import String
from std_srvs.srv import Trigger

from msg_adapters import image_to_rgb_or_mono

from ..errors import ConfigError, SrMosaicError
from ..live.map_tiles import FOOTPRINT_FRAME, parse_whole_map
from ..web.live_source import LiveMapSource
from .common import SERVICES, TOPICS, WarnOnce
from .messages import Messages, message_kind
from .parameters import MAP_SERVER_PARAMETERS, declare_pipeline_parameters

__all__ = ['MapServerNode', 'MOSAIC_STATUS']

#: The diagnostic status of the mosaic node (nodes/mosaic_node.py) whose values the status shows.
MOSAIC_STATUS = 'srmosaic: registration and mosaic'
#: Seconds between two asks for the whole map (srmosaic/get_map) while tiles are missing.
ASK_EVERY_S = 5.0


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
        self._asked_at = -math.inf
        self._asking = False
        self.got_whole_map = 0  # tiles taken from srmosaic/get_map answers
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             history=HistoryPolicy.KEEP_LAST)
        tiles_qos = QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
        self.create_subscription(CompressedImage, TOPICS['map_tile'], self._on_map_tile, tiles_qos)
        self.create_subscription(String, TOPICS['map_tiles'], self._on_summary, latched)
        self.create_subscription(self.messages.raster_type, TOPICS['raster'], self._on_raster, latched)
        self.create_subscription(Image, TOPICS['sr_tile'], self._on_sr_tile, 20)
        self.create_subscription(NavSatFix, TOPICS['fused_fix'], self._on_fix, 50)
        self.create_subscription(PoseWithCovarianceStamped, TOPICS['pose'], self._on_pose, 50)
        self.create_subscription(PolygonStamped, TOPICS['footprint'], self._on_footprint, 10)
        self.create_subscription(DiagnosticArray, 'srmosaic/diagnostics', self._on_diagnostics, 10)
        self._client = self.create_client(Trigger, SERVICES['get_map'])
        self.create_timer(1.0, self._ask_if_missing)
        self._missing = True  # at start: whatever was sent before this node joined
        self._newest_tile_ns: int | None = None  # stamp of the newest tile the topic brought
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

    # -- tiles ----------------------------------------------------------------------------------
    def _on_map_tile(self, msg: CompressedImage) -> None:
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self._newest_tile_ns = max(stamp_ns, self._newest_tile_ns or stamp_ns)
        try:
            self.source.add_png('mosaic', msg.header.frame_id, bytes(msg.data), stamp_ns=stamp_ns)
        except SrMosaicError as exc:
            self.warn('map tile', f'map tile skipped: {exc}')

    def _on_sr_tile(self, msg: Image) -> None:
        try:
            self.source.add_tile('sr', msg.header.frame_id, image_to_rgb_or_mono(msg))
        except (SrMosaicError, ValueError) as exc:
            self.warn('sr tile', f'SR tile skipped: {exc}')

    def _on_summary(self, msg: String) -> None:
        """The whole map is asked for when the summary lists a tile version older than one the topic
        already brought, which is not held: it was lost on the way (tiles come in order on one topic;
        a tile merely still on its way, or the summary outrunning it, is no reason)."""
        import json

        try:
            listed = [(str(t[0]), int(t[1])) for t in json.loads(msg.data)['tiles']]
        except (ValueError, KeyError, TypeError, IndexError) as exc:
            self.warn('map summary', f'/srmosaic/map_tiles skipped: {exc}')
            return
        arrived = self._newest_tile_ns
        if arrived is not None and self.source.lacking('mosaic', [(f, s) for f, s in listed if s < arrived]):
            self._missing = True

    def _ask_if_missing(self) -> None:
        """Timer: ask srmosaic/get_map for the whole map when tiles are missing (at most every ASK_EVERY_S)."""
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
            self.warn('whole map', f'srmosaic/get_map answer skipped: {exc}')
            return
        self._missing = False
        for frame_id, stamp_ns, data in tiles:
            try:
                self.source.add_png('mosaic', frame_id, data, stamp_ns=stamp_ns)  # a newer one from the topic stays
                self.got_whole_map += 1
            except SrMosaicError as exc:
                self.warn('map tile', f'map tile skipped: {exc}')

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

