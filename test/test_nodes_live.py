"""The live graph over real DDS on loopback: `srmosaic launch` + `srmosaic play`, observed by a subscriber.

Each test uses its own ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.io.mosaic_files import read_frames_csv

ROOT = Path(__file__).resolve().parent.parent
DEMO = ROOT / 'bags' / 'demo'
pytestmark = pytest.mark.ros

_DOMAIN = 30 + os.getpid() % 150  # test-unique domain, distinct from other runs on the machine


@pytest.fixture
def ros_env(monkeypatch, request):
    domain = _DOMAIN + (hash(request.node.name) % 7)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return env


def srmosaic(*args: str, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.cli', *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


class Listener:
    """An rclpy node in this process that records what the graph publishes."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import CompressedImage, Image
        from std_msgs.msg import Float64MultiArray

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('srmosaic_test_listener', context=self.context)
        self.previews: list = []
        self.compressed: list = []
        self.diagnostics: list = []
        self.registrations: list = []
        self.poses: list = []
        self.fixes: list = []
        self.node.create_subscription(Image, '/srmosaic/mosaic_preview', self.previews.append, 10)
        self.node.create_subscription(CompressedImage, '/srmosaic/mosaic_preview/compressed',
                                      self.compressed.append, 10)
        self.node.create_subscription(DiagnosticArray, '/srmosaic/diagnostics', self.diagnostics.append, 10)
        self.node.create_subscription(Float64MultiArray, '/srmosaic/registration', self.registrations.append, 100)
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from sensor_msgs.msg import NavSatFix

        self.node.create_subscription(PoseWithCovarianceStamped, '/srmosaic/pose', self.poses.append, 100)
        self.node.create_subscription(NavSatFix, '/srmosaic/fix', self.fixes.append, 100)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._stop = False
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop:
            self.executor.spin_once(timeout_sec=0.1)

    def diag_value(self, key: str) -> str | None:
        if not self.diagnostics:
            return None
        values = {kv.key: kv.value for kv in self.diagnostics[-1].status[0].values}
        return values.get(key)

    def wait_for(self, predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.2)
        return False

    def publisher(self, msg_type, topic: str):
        return self.node.create_publisher(msg_type, topic, 10)

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=5)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def _stop(proc: subprocess.Popen, timeout: float = 60) -> str:
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=timeout)
    return out


def test_live_graph_matches_offline_process(ros_env, tmp_path):
    live_dir = tmp_path / 'live'
    # Reliable inputs: the comparison with the offline run needs every frame (best effort may drop
    # some on a loaded machine, which the node would count and survive, but the mosaics would differ).
    graph = srmosaic('launch', '--ros-args', '-p', f'live.output_dir:={live_dir}', '-p', 'live.queue_size:=100',
                     '-p', 'live.preview_period_s:=0.5', '-p', 'live.reliable_inputs:=true', env=ros_env)
    listener = Listener()
    try:
        assert listener.wait_for(lambda: listener.diagnostics, 30), 'graph published no diagnostics'
        player = srmosaic('play', str(DEMO), '--rate', '2.0', '--delay', '15', env=ros_env)
        out, _ = player.communicate(timeout=120)
        assert player.returncode == 0, out
        assert listener.wait_for(lambda: listener.diag_value('frames_processed') == '60', 240), \
            (f'graph did not process the 60 frames: received {listener.diag_value("frames_received")}, '
             f'processed {listener.diag_value("frames_processed")}')
        time.sleep(1.0)
        assert listener.previews and listener.compressed
        assert len(listener.registrations) == 60
        preview = listener.previews[-1]
        assert preview.encoding == 'rgb8' and max(preview.width, preview.height) <= 1024
        assert listener.diag_value('dropped_frames') == '0'
        # The fused pose of every frame, near the simulated flight (100 m above the ground plane).
        # (frames whose pose is not valid yet, e.g. before the filter has its first fix, publish none)
        assert len(listener.poses) >= 30 and len(listener.fixes) == len(listener.poses)
        assert all(abs(p.pose.pose.position.z - 100.0) < 10.0 for p in listener.poses)
        assert all(abs(f.latitude - 30.17) < 0.01 for f in listener.fixes)
    except AssertionError as exc:
        raise AssertionError(f'{exc}\n--- graph output ---\n{_stop(graph)}') from None
    finally:
        log = _stop(graph) if graph.returncode is None else ''
        listener.close()
    assert graph.returncode == 0, log
    offline_dir = tmp_path / 'offline'
    run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', 'process', str(DEMO), '--out', str(offline_dir),
                          '--no-progress'], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    live = read_frames_csv(live_dir / 'frames.csv')
    offline = read_frames_csv(offline_dir / 'frames.csv')
    assert [r['stamp_ns'] for r in live] == [r['stamp_ns'] for r in offline]
    assert [r['ok'] for r in live] == [r['ok'] for r in offline]
    # Same frames registered; the two mosaic planes are compared up to a global homography (the
    # georeferencing filter saw the telemetry interleaved differently live, which moves the anchor).
    from srmosaic_ros.core.metrics import mosaic_corner_errors

    pairs = [(a['mosaic_H_frame'], b['mosaic_H_frame']) for a, b in zip(live, offline) if a['ok']]
    errors, _ = mosaic_corner_errors([p[0] for p in pairs], [p[1] for p in pairs], 640, 480)
    assert errors.max() < 1.0, errors
    assert (live_dir / 'mosaic.tif').is_file() and (live_dir / 'poses.csv').is_file()
    report = json.loads((live_dir / 'report.json').read_text())
    assert report['frames_in'] == 60 and 'wall_s' in report and 'peak_rss_mb' in report


def test_node_survives_bad_input(ros_env, tmp_path):
    from sensor_msgs.msg import Image, NavSatFix

    graph = srmosaic('launch', '--ros-args', '-p', 'live.preview_period_s:=0.3', env=ros_env)
    listener = Listener()
    try:
        assert listener.wait_for(lambda: listener.diagnostics, 30)
        images = listener.publisher(Image, '/camera/image_raw')
        fixes = listener.publisher(NavSatFix, '/fix')
        assert listener.wait_for(lambda: images.get_subscription_count() > 0, 20)
        bad = Image(height=4, width=4, encoding='yuv422', step=8, data=bytes(32))
        empty = Image(height=0, width=0, encoding='mono8', step=0, data=b'')
        nan_fix = NavSatFix(latitude=math.nan, longitude=1.0, altitude=1.0)
        for _ in range(3):
            images.publish(bad)
            images.publish(empty)
            fixes.publish(nan_fix)
            time.sleep(0.1)
        later, earlier = Image(height=32, width=32, encoding='mono8', step=32, data=bytes(1024)), None
        later.header.stamp.sec = 100
        earlier = Image(height=32, width=32, encoding='mono8', step=32, data=bytes(1024))
        earlier.header.stamp.sec = 50
        images.publish(later)
        time.sleep(0.2)
        images.publish(earlier)

        def counted() -> bool:
            return all(listener.diag_value(k) for k in ('rejected: image: MessageError', 'rejected: fix',
                                                        'rejected: image time going backwards'))
        assert listener.wait_for(counted, 20), listener.diagnostics[-1] if listener.diagnostics else None
        assert graph.poll() is None, 'the node died on bad input'
    finally:
        log = _stop(graph)
        listener.close()
    assert graph.returncode == 0, log
    assert log.count('not supported') == 1  # logged once per kind, not per message


def test_invalid_parameter_refused_at_start(ros_env):
    graph = srmosaic('launch', '--ros-args', '-p', 'registration.ratio:=3.0', env=ros_env)
    out, _ = graph.communicate(timeout=60)
    assert graph.returncode == 2, out
    assert 'ratio' in out
