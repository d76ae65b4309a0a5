"""The live web map over real DDS: `srmosaic play` of the demo flight into the mosaic node and
`srmosaic map-server`, looked at over HTTP, in headless Chromium and by a listener on the tile topic.

One graph per module (the flight takes most of the time); each test looks at one side of it.
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import pytest
from ros_graph import GraphListener, ros_domain_id, supervised_processes, stop_process

from repo_paths import REPO

DEMO = REPO / 'bags' / 'demo'
FRAMES = 60  # in the demo bag
#: The budget of the flight, bytes per second: below what the demo's changed tiles need at twice real
#: time, so that it binds.
BUDGET = 150_000
BURST_S = 1.0  # live/map_tiles.py MapTileStream's default
pytestmark = pytest.mark.ros


def srmosaic(*args: str, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.cli', *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def get(url: str) -> tuple[int, str, bytes]:
    """(status, content type, body) of a GET; (0, '', b'') when nothing listens."""
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.headers.get('Content-Type', ''), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.headers.get('Content-Type', ''), exc.read()
    except (urllib.error.URLError, ConnectionError, TimeoutError):
        return 0, '', b''


def status_of(url: str) -> dict[str, Any] | None:
    code, _, body = get(url + 'status.json')
    return json.loads(body) if code == 200 else None


class TileListener(GraphListener):
    """Records /srmosaic/map_tile (publish stamp, bytes, frame_id), its summary and the fused fixes."""

    def __init__(self) -> None:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CompressedImage, NavSatFix
        from std_msgs.msg import String

        super().__init__('srmosaic_test_map_listener')
        self.tiles = self.subscribe(CompressedImage, '/srmosaic/map_tile',
                                    QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST))
        self.summaries = self.subscribe(String, '/srmosaic/map_tiles', QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.fixes = self.subscribe(NavSatFix, '/srmosaic/fix', 100)

    def summary(self) -> dict[str, Any] | None:
        return json.loads(self.summaries[-1].data) if self.summaries else None


def map_latency() -> Any:
    """bench/map_latency.py as a module (its probe times the way of each frame to the map)."""
    import importlib.util

    if 'map_latency' not in sys.modules:  # (registered before it runs: its dataclasses look themselves up)
        spec = importlib.util.spec_from_file_location('map_latency', REPO / 'bench' / 'map_latency.py')
        sys.modules['map_latency'] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules['map_latency'])
    return sys.modules['map_latency']


def page_holds(page: Any, expression: str, timeout_s: float) -> bool:
    """Poll a JavaScript expression on the page until it is true (False after timeout_s, times the
    graph's wait scale). A loop of evaluate calls: Playwright's wait_for_function never saw the
    condition hold on this page (whose event stream stays open), where evaluate does."""
    from ros_graph import WAIT_SCALE

    deadline = time.monotonic() + timeout_s * WAIT_SCALE
    while time.monotonic() < deadline:
        if page.evaluate(expression):
            return True
        page.wait_for_timeout(250)
    return False


@dataclass
class Flight:
    url: str
    env: dict[str, str]
    listener: TileListener
    probe: Any  # bench/map_latency.py's: each frame's footprint centre, polled on /tiles/ until served painted
    statuses: list[dict[str, Any]] = field(default_factory=list)  # polled while the bag played
    most_pending: int = 0  # the most tiles the summary said were waiting for the budget


@pytest.fixture(scope='module')
def flight():
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv('ROS_DOMAIN_ID', str(ros_domain_id()))
        mp.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        env = dict(os.environ)
        port = free_port()
        listener = TileListener()
        listener.start()
        probe = map_latency().MapLatencyProbe(f'http://127.0.0.1:{port}/')  # before the processes: none is left behind
        procs = {
            'mosaic': srmosaic('node', 'mosaic', '--ros-args', '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100',
                               '-p', f'live.map_bytes_per_s:={BUDGET}', env=env),
            'map_server': srmosaic('map-server', '--port', str(port), env=env),
        }

        def close() -> None:
            probe.close()
            listener.close()
        with supervised_processes(procs, close):
            f = Flight(f'http://127.0.0.1:{port}/', env, listener, probe)
            assert listener.wait_for(lambda: status_of(f.url) is not None, 60), 'the map server never answered'
            player = srmosaic('play', str(DEMO), '--rate', '2.0', '--delay', '20', env=env)
            while player.poll() is None:
                if (s := status_of(f.url)) is not None:
                    f.statuses.append(s)
                if (summary := listener.summary()) is not None:
                    f.most_pending = max(f.most_pending, summary['pending'])
                time.sleep(0.5)
            assert player.returncode == 0, player.communicate()[0]

            changed = [0, time.monotonic()]  # summaries received, when that count last changed

            def converged() -> bool:  # every frame processed, every changed tile sent and held by the server
                s, summary = status_of(f.url), listener.summary()
                if summary is not None:
                    f.most_pending = max(f.most_pending, summary['pending'])
                if len(listener.summaries) != changed[0]:
                    changed[:] = [len(listener.summaries), time.monotonic()]
                # and no new summary for two preview rounds: the frames counted as processed may still be
                # on the paint thread when a round collects the changed tiles, and go in the next one
                return bool(s and summary and s['frames'] == FRAMES and summary['pending'] == 0
                            and s['tiles']['mosaic'] == len(summary['tiles']) > 0 and time.monotonic() - changed[1] > 2.5)
            assert listener.wait_for(converged, 120), (status_of(f.url), listener.summary())
            yield f


def test_status_shows_the_frames_the_pose_and_its_footprint(flight: Flight) -> None:
    status = status_of(flight.url)
    assert status['live'] is True and status['georeferenced'] is True and status['frames'] == FRAMES
    assert any(s['frames'] and s['pose'] for s in flight.statuses), 'no pose while the bag played'
    fix = flight.listener.fixes[-1]
    pose = status['pose']
    assert pose['lat'] == pytest.approx(fix.latitude, abs=1e-9) and pose['lon'] == pytest.approx(fix.longitude, abs=1e-9)
    assert -10 < pose['yaw_deg'] < 10 and 80 < pose['heading_deg'] < 100  # the demo flies east
    ring = np.array(status['footprint']['coordinates'][0], np.float64)
    assert len(ring) == 5 and (ring[0] == ring[-1]).all()
    # nadir camera: the aircraft is over its footprint (lon/lat scaled to metres around it)
    scale = np.array([np.cos(np.radians(pose['lat'])), 1.0]) * 111_320.0
    local = ((ring - [pose['lon'], pose['lat']]) * scale).astype(np.float32)
    assert cv2.pointPolygonTest(local.reshape(-1, 1, 2), (0.0, 0.0), True) > 10.0  # more than 10 m inside
    assert status['track']['type'] == 'LineString' and len(status['track']['coordinates']) > 10
    w, s, e, n = status['bounds']
    assert w < pose['lon'] < e + 0.001 and s < pose['lat'] < n
    assert status['diagnostics']['frames_processed'] == str(FRAMES)


def test_a_tile_under_the_aircraft_is_served_once_painted(flight: Flight) -> None:
    import morecantile

    status = status_of(flight.url)
    pose, z = status['pose'], status['maxzoom']
    tms = morecantile.tms.get('WebMercatorQuad')
    tile = tms.tile(pose['lon'], pose['lat'], z)
    code, content_type, body = get(flight.url + f'tiles/{z}/{tile.x}/{tile.y}.png')
    assert code == 200 and content_type == 'image/png'
    rgba = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)
    assert rgba.shape == (256, 256, 4)
    b = tms.xy_bounds(tile)
    mx, my = tms.xy(pose['lon'], pose['lat'])
    col, row = int((mx - b.left) / (b.right - b.left) * 256), int((b.top - my) / (b.top - b.bottom) * 256)
    assert rgba[row, col, 3] == 255 and rgba[row, col, :3].std() < 80  # painted ground, not a hole
    far = tms.tile(pose['lon'] + 0.05, pose['lat'], z)
    assert get(flight.url + f'tiles/{z}/{far.x}/{far.y}.png')[0] == 404
    for hostile in ('tiles/99/0/0.png', 'tiles/../status.json', 'tiles/1/-1/0.png', 'sr/x/0/0.png'):
        assert get(flight.url + hostile)[0] in (400, 404), hostile


def test_the_ground_under_every_frame_is_served_painted_while_it_flies(flight: Flight) -> None:
    """Polled live (bench/map_latency.py's probe): for every frame with a footprint, the XYZ tile at its
    centre is served painted there at some moment (how soon is bench/map_latency.py's figure, not a test's)."""
    probe = flight.probe
    assert flight.listener.wait_for(probe.all_served, 60), [
        (w.tile, w.pixel) for w in probe.watched() if w.served_s is None]
    watched = probe.watched()
    assert len(watched) >= FRAMES // 2, f'{len(watched)} of {FRAMES} frames had a footprint'
    assert all(w.served_s >= w.published_s for w in watched)
    assert any(w.new_ground for w in watched), 'no frame brought new ground: the probe saw the map only at the end'


def test_the_page_shows_the_mosaic_the_aircraft_and_the_footprint(flight: Flight, chromium, tmp_path) -> None:
    page = chromium.new_page(viewport={'width': 900, 'height': 640})
    try:
        page.goto(flight.url)
        assert page_holds(page, '!!(window.srmosaic && window.srmosaic.events > 0 && window.srmosaic.status)', 60), \
            'the page got no status or no event'
        assert page_holds(page, 'document.querySelectorAll(".srm-layer-1 img.leaflet-tile-loaded").length > 0', 60), \
            'no mosaic tile loaded'
        assert page.locator('.srm-aircraft svg').count() == 1
        assert page.locator('path.srm-footprint').count() == 1 and page.locator('path.srm-track').count() == 1
        page.wait_for_timeout(500)  # the tiles fade in
        shot = tmp_path / 'live_map.png'
        page.screenshot(path=str(shot))
    finally:
        page.close()
    img = cv2.imread(str(shot))
    background = np.median(img[5:40, 300:600].reshape(-1, 3), axis=0)  # the map's empty top edge
    painted = np.abs(img.astype(int) - background).max(axis=2) > 30
    assert painted[100:540, 100:800].mean() > 0.1, 'no mosaic pixels on the page'


def test_the_budget_holds_and_no_tile_is_lost(flight: Flight) -> None:
    tiles = list(flight.listener.tiles)
    stamps = np.array([t.header.stamp.sec + 1e-9 * t.header.stamp.nanosec for t in tiles])
    sizes = np.array([len(t.data) for t in tiles])
    assert flight.most_pending > 0, 'the budget never held a tile back: the test does not test it'
    # any window of W seconds: at most the budget for W + the bucket's second, plus one tile
    for t0 in stamps:
        for w in (1.0, 3.0, 10.0):
            inside = (stamps >= t0) & (stamps < t0 + w)
            assert sizes[inside].sum() <= BUDGET * (w + BURST_S) + sizes.max(), (t0, w)
    span = stamps.max() - stamps.min()
    assert sizes.sum() / max(span, 1.0) <= BUDGET * (1 + BURST_S / max(span, 1.0)) + sizes.max()
    summary = flight.listener.summary()
    sent = {t.header.frame_id for t in tiles}
    assert {frame_id for frame_id, _ in summary['tiles']} == sent  # every tile listed arrived
    assert status_of(flight.url)['tiles']['mosaic'] == len(sent)


def test_a_map_server_started_after_the_flight_gets_the_whole_map(flight: Flight) -> None:
    port = free_port()
    late = srmosaic('map-server', '--port', str(port), env=flight.env)
    url = f'http://127.0.0.1:{port}/'
    try:
        want = len(flight.listener.summary()['tiles'])
        assert flight.listener.wait_for(lambda: (s := status_of(url)) is not None and s['tiles']['mosaic'] == want, 60), \
            status_of(url)
        assert status_of(url)['georeferenced'] is True
    finally:
        out = stop_process(late)
    assert late.returncode == 0, out


def test_map_true_in_the_launch_file_adds_the_map_server_in_a_process_of_its_own(tmp_path) -> None:
    from srmosaic_ros.nodes.launch_xml import read_launch_xml
    from srmosaic_ros.nodes.launcher import xml_node_command

    launch = REPO / 'launch' / 'srmosaic.launch.xml'
    assert 'map_server' not in [n.executable for n in read_launch_xml(launch)]
    nodes = read_launch_xml(launch, {'map': 'true', 'namespace': 'uav1'})
    server = next(n for n in nodes if n.executable == 'map_server')
    assert server.namespace == '/uav1' and server.name == 'srmosaic_map_server'
    command = xml_node_command(server, [], ['--ros-args', '-p', 'live.map_port:=9000'], tmp_path)
    assert command[3] == 'map_server' and 'live.map_port:=9000' in ' '.join(command)
