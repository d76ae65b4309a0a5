"""Live map latency: from a frame's publication to the map server serving the ground under it.

Issue 54's goal "a tile under the aircraft is served within 2 s of the frame that painted it", timed
live: `srmosaic launch launch/srmosaic.launch.xml map:=true` runs the graph in child processes (a
ROS domain of its own), `srmosaic play BAG` publishes the flight into it, and this process listens to
the camera topics (when each frame is published: its first arrival here), /srmosaic/footprint
(where each fused frame looks, in /srmosaic/raster pixels) and /srmosaic/raster, and polls the map
server's /tiles/{z}/{x}/{y}.png (z: the status's maxzoom) at the centre of every frame's footprint
every POLL_S until the pixel there is served painted (alpha > 0). Per frame with a footprint: the
latency is the first such moment minus its publication. Printed as p50 / p95 / max over all those
frames, over the frames published after the first pixel was served (past the start of the graph:
"steady"), and over the "new ground" frames, whose centre was not yet painted when first polled (the
others' ground was painted by earlier frames, which their overlap shows at once); the new-ground
latency is split at the footprint's arrival: publication to footprint (the mosaic node received,
registered and fused the frame) and footprint to served (painting, the map tile round every
live.preview_period_s within live.map_bytes_per_s, the map server's reprojection, this probe's poll).

Frames are painted mosaic.revisit_spread_frames frames after they are registered (by design: a
keyframe's correction is spread over the frames before it), so `--param
mosaic.revisit_spread_frames:=0` shows the latency of the map path itself. Each `--param` run and
the default run go one after the other in the same invocation (`--compare-spread`).

    .venv/bin/python bench/map_latency.py [--bag bags/demo] [--rate 1.0] [--compare-spread] [--json out.json]

The probe (:class:`MapLatencyProbe`) is also used by test/nodes/test_map_server.py, which asserts
only that every frame's centre is served (no timing in tests).
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
#: seconds between two polls of the tiles waiting to be painted
POLL_S = 0.1


@dataclass
class FrameWatch:
    """One frame's way to the map: when it was published (monotonic s), where its footprint centre
    lies (XYZ tile and pixel, once known), when the map server first served that pixel painted."""

    published_s: float
    centre: np.ndarray | None = None  # footprint centre, /srmosaic/raster pixels
    footprint_s: float | None = None  # when its footprint arrived (the node fused it)
    tile: tuple[int, int, int] | None = None
    pixel: tuple[int, int] | None = None
    served_s: float | None = None
    new_ground: bool | None = None  # the centre was unpainted at the first poll

    @property
    def latency_s(self) -> float | None:
        return None if self.served_s is None else self.served_s - self.published_s


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, b''
    except (urllib.error.URLError, ConnectionError, TimeoutError):
        return 0, b''


def status(url: str) -> dict[str, Any] | None:
    code, body = _get(url + 'status.json')
    return json.loads(body) if code == 200 else None


class MapLatencyProbe:
    """Listens to the graph (its own rclpy context) and polls the map server at ``url`` (module docstring)."""

    def __init__(self, url: str, namespace: str = '') -> None:
        import rclpy
        from geometry_msgs.msg import PolygonStamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CompressedImage, Image
        from std_msgs.msg import String

        import cv2  # noqa: F401 - imported now, not at the first poll (a cold import is seconds on a loaded host)
        import morecantile  # noqa: F401
        import rasterio.warp  # noqa: F401

        self.url = url
        self.frames: dict[int, FrameWatch] = {}  # stamp_ns -> watch
        self._lock = threading.Lock()
        self._raster: Any = None
        self._zoom: int | None = None
        self._stop = threading.Event()
        self._context = rclpy.Context()
        rclpy.init(context=self._context)
        self._node = rclpy.create_node('srmosaic_map_latency_probe', context=self._context)
        ns = namespace.rstrip('/')
        for msg_type, topic in ((Image, '/camera/image_raw'), (CompressedImage, '/camera/image_raw/compressed')):
            self._node.create_subscription(msg_type, ns + topic, self._on_image, 50)
        self._node.create_subscription(PolygonStamped, ns + '/srmosaic/footprint', self._on_footprint, 50)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             history=HistoryPolicy.KEEP_LAST)
        self._node.create_subscription(String, ns + '/srmosaic/raster', self._on_raster, latched)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._threads = [threading.Thread(target=self._spin, daemon=True), threading.Thread(target=self._poll, daemon=True)]
        for t in self._threads:
            t.start()

    # -- what the graph says --------------------------------------------------------------------
    @staticmethod
    def _stamp(msg: Any) -> int:
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def _on_image(self, msg: Any) -> None:
        now = time.monotonic()
        with self._lock:
            self.frames.setdefault(self._stamp(msg), FrameWatch(now))

    def _on_raster(self, msg: Any) -> None:
        from srmosaic_ros.live.raster import LiveRaster

        with self._lock:
            self._raster = LiveRaster.parse(msg.data)

    def _on_footprint(self, msg: Any) -> None:
        corners = np.array([[p.x, p.y] for p in msg.polygon.points], np.float64)
        with self._lock:
            watch = self.frames.get(self._stamp(msg))
            if watch is not None and watch.centre is None and len(corners) >= 3:
                watch.centre = corners.mean(axis=0)
                watch.footprint_s = time.monotonic()

    # -- polling the map server -------------------------------------------------------------------
    def _place(self, centre: np.ndarray) -> tuple[tuple[int, int, int], tuple[int, int]]:
        """The XYZ tile (z, x, y) and its pixel (col, row) showing raster pixel ``centre``."""
        import morecantile
        from rasterio.warp import transform

        raster, z = self._raster, self._zoom
        e, n, w = raster.utm_H_raster @ np.array([centre[0], centre[1], 1.0])
        lon, lat = transform(f'EPSG:{raster.epsg}', 'EPSG:4326', [e / w], [n / w])
        tms = morecantile.tms.get('WebMercatorQuad')
        tile = tms.tile(lon[0], lat[0], z)
        b = tms.xy_bounds(tile)
        mx, my = tms.xy(lon[0], lat[0])
        col = min(255, int((mx - b.left) / (b.right - b.left) * 256))
        row = min(255, int((b.top - my) / (b.top - b.bottom) * 256))
        return (z, tile.x, tile.y), (col, row)

    def _poll(self) -> None:
        import cv2

        while not self._stop.wait(POLL_S):
            if self._zoom is None:
                s = status(self.url)
                if s is None or s.get('maxzoom') in (None, 0):
                    continue
                self._zoom = int(s['maxzoom'])
            with self._lock:
                if self._raster is None:
                    continue
                waiting = [w for w in self.frames.values() if w.centre is not None and w.served_s is None]
                for w in waiting:
                    if w.tile is None:
                        w.tile, w.pixel = self._place(w.centre)
            fetched: dict[tuple[int, int, int], np.ndarray | None] = {}
            for w in waiting:
                if w.tile not in fetched:
                    code, body = _get(self.url + 'tiles/{}/{}/{}.png'.format(*w.tile))
                    fetched[w.tile] = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED) if code == 200 else None
                rgba = fetched[w.tile]
                painted = rgba is not None and rgba.ndim == 3 and rgba.shape[2] == 4 and rgba[w.pixel[1], w.pixel[0], 3] > 0
                with self._lock:
                    if w.new_ground is None:
                        w.new_ground = not painted
                    if painted:
                        w.served_s = time.monotonic()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self._executor.spin_once(timeout_sec=0.1)

    # -- results ----------------------------------------------------------------------------------
    def watched(self) -> list[FrameWatch]:
        """The frames with a footprint, by stamp."""
        with self._lock:
            return [w for _, w in sorted(self.frames.items()) if w.centre is not None]

    def all_served(self) -> bool:
        watched = self.watched()
        return bool(watched) and all(w.served_s is not None for w in watched)

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5)
        self._node.destroy_node()
        self._context.try_shutdown()


def _stats(values: list[float]) -> dict[str, Any]:
    v = np.array(values, np.float64)
    if not v.size:
        return {'n': 0}
    return {'n': int(v.size), 'p50_s': round(float(np.percentile(v, 50)), 3), 'p95_s': round(float(np.percentile(v, 95)), 3),
            'max_s': round(float(v.max()), 3)}


def summarise(watched: list[FrameWatch]) -> dict[str, Any]:
    """p50 / p95 / max latency (s) of all watched frames and of the new-ground ones, the unserved count,
    and the two parts of the new-ground latency: publication to footprint (the mosaic node fused the
    frame) and footprint to served (painting, the tile stream, the map server); per frame in 'frames_s'."""
    new = [w for w in watched if w.new_ground and w.served_s is not None]
    t0 = min((w.published_s for w in watched), default=0.0)
    first_served = min((w.served_s for w in watched if w.served_s is not None), default=np.inf)
    return {'frames': len(watched), 'unserved': sum(w.served_s is None for w in watched),
            'all': _stats([w.latency_s for w in watched if w.latency_s is not None]),
            # the frames published once the map server served its first painted pixel (past the start)
            'steady': _stats([w.latency_s for w in watched if w.latency_s is not None and w.published_s >= first_served]),
            'new_ground': _stats([w.latency_s for w in new]),
            'new_ground_to_footprint': _stats([w.footprint_s - w.published_s for w in new]),
            'new_ground_footprint_to_served': _stats([w.served_s - w.footprint_s for w in new]),
            'frames_s': [[round(w.published_s - t0, 3), None if w.latency_s is None else round(w.latency_s, 3),
                          round(w.footprint_s - w.published_s, 3), bool(w.new_ground)] for w in watched]}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def run(bag: Path, rate: float, params: list[str], domain: int, *, sr: bool, wait_s: float) -> dict[str, Any]:
    """One flight: the launched graph with map:=true, the bag played into it, the probe's summary."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    os.environ.update(ROS_DOMAIN_ID=env['ROS_DOMAIN_ID'], ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')  # the probe's
    port = _free_port()
    url = f'http://127.0.0.1:{port}/'
    ros_params = ['live.reliable_inputs:=true', 'live.queue_size:=100', f'live.map_port:={port}', *params]
    command = [sys.executable, '-m', 'srmosaic_ros.cli', 'launch', str(REPO / 'launch' / 'srmosaic.launch.xml'), 'map:=true',
               f"sr:={'true' if sr else 'false'}", '--ros-args', *[a for p in ros_params for a in ('-p', p)]]
    log = tempfile.TemporaryFile(mode='w+')
    graph = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)
    probe = MapLatencyProbe(url)
    try:
        deadline = time.monotonic() + 120
        while status(url) is None and time.monotonic() < deadline:
            time.sleep(0.5)
        player = subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', 'play', str(bag), '--rate', str(rate),
                                 '--delay', '30'], env=env, capture_output=True, text=True, check=False)
        if player.returncode != 0:
            raise RuntimeError(player.stdout + player.stderr)
        end = time.monotonic() + wait_s
        while not probe.all_served() and time.monotonic() < end and graph.poll() is None:
            time.sleep(0.5)
        if graph.poll() is not None or not probe.watched():
            log.seek(0)
            raise RuntimeError(f'the graph ({" ".join(params)}) ended or gave no footprint:\n{log.read()[-3000:]}')
        return {'params': params, 'rate': rate, **summarise(probe.watched())}
    finally:
        probe.close()
        graph.send_signal(2)
        try:
            graph.wait(timeout=60)
        except subprocess.TimeoutExpired:
            graph.kill()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--bag', type=Path, default=REPO / 'bags' / 'demo')
    ap.add_argument('--rate', type=float, default=1.0, help='playback speed factor')
    ap.add_argument('--param', action='append', default=[], help='name:=value for every node (repeatable)')
    ap.add_argument('--compare-spread', action='store_true',
                    help='also run with mosaic.revisit_spread_frames:=0 (frames painted at once), same invocation')
    ap.add_argument('--no-sr', action='store_true', help='the graph without the SR node')
    ap.add_argument('--wait', type=float, default=30.0, help='seconds after the flight for the last frames to be served')
    ap.add_argument('--repeat', type=int, default=1, help='run the set this many times, one after the other')
    ap.add_argument('--json', type=Path, help='write the results here')
    args = ap.parse_args()
    runs = ([args.param] + ([[*args.param, 'mosaic.revisit_spread_frames:=0']] if args.compare_spread else [])) * args.repeat
    results = []
    for i, params in enumerate(runs):
        r = run(args.bag, args.rate, params, 160 + (os.getpid() + i) % 30, sr=not args.no_sr, wait_s=args.wait)
        results.append(r)
        print(f"{' '.join(params) or 'defaults'}: {r['frames']} frames with a footprint, {r['unserved']} not served; "
              + '; '.join(f"{k}: n {r[k]['n']}" + (f", p50 {r[k]['p50_s']:.2f} s, p95 {r[k]['p95_s']:.2f} s, max {r[k]['max_s']:.2f} s"
                                                   if r[k]['n'] else '') for k in ('all', 'steady', 'new_ground', 'new_ground_to_footprint',
                                                                                    'new_ground_footprint_to_served')), flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
