"""The SR node's tiles on the wire like the map tiles, over real DDS: /srmosaic/sr_map_tile within its
budget, oldest first, none lost; the latched summary /srmosaic/sr_map_tiles; and a map server started
after the tiles were sent gets every one of them from /srmosaic/get_sr_map.

The SR node alone, fed frames and registrations by this test (an aircraft hovering over one spot, as
in test_sr_node.py), with a budget below one tile a second so that it binds.
"""
from __future__ import annotations

import json
import time
from typing import Any

import cv2
import numpy as np
import pytest
from live_graph import SR, srmosaic, translation
from ros_graph import GraphListener, supervised_processes, stop_process
from test_map_server import free_port, status_of

pytestmark = pytest.mark.ros

#: bytes per second of the SR tile stream: a 128 x 128 RGB tile's PNG takes several seconds of it, longer
#: than the node takes to make the next tile, so that the budget binds
BUDGET = 5_000
BURST_S = 1.0  # live/sr_tile_stream.py SRTileStream's default
FRAMES = 8


class SRWireListener(GraphListener):
    """Records /srmosaic/sr_tile, /srmosaic/sr_map_tile, their summary and the SR node's diagnostics."""

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CompressedImage, Image
        from std_msgs.msg import String

        super().__init__('srmosaic_test_sr_wire')
        self.raw = self.subscribe(Image, '/srmosaic/sr_tile', 50)
        self.wire = self.subscribe(CompressedImage, '/srmosaic/sr_map_tile',
                                   QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST))
        self.summaries = self.subscribe(String, '/srmosaic/sr_map_tiles', QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.diagnostics = self.subscribe(DiagnosticArray, '/srmosaic/diagnostics', 10)
        self.start()

    def summary(self) -> dict[str, Any] | None:
        return json.loads(self.summaries[-1].data) if self.summaries else None

    def diag_value(self, key: str) -> str | None:
        for msg in reversed(list(self.diagnostics)):
            for status in msg.status:
                if status.name == SR:
                    return {kv.key: kv.value for kv in status.values}.get(key)
        return None


@pytest.fixture(scope='module')
def sr_flight():
    from imagery import view
    from msg_adapters import numpy_to_image
    from ros_graph import ros_domain_id
    from sensor_msgs.msg import Image
    from std_msgs.msg import Float64MultiArray

    from srmosaic_ros.nodes.common import encode_registration

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv('ROS_DOMAIN_ID', str(ros_domain_id()))
        mp.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        import os

        env = dict(os.environ)
        port = free_port()
        procs = {
            'sr': srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'live.sr_worker:=thread',
                           '-p', 'sr_tiles.tile_size:=64', '-p', 'sr_tiles.max_frames:=8', '-p', 'sr.iterations:=5',
                           '-p', 'live.sr_tiles_per_round:=4', '-p', 'live.sr_refresh_growth:=0.0',
                           '-p', 'stamp_tolerance_s:=0.0', '-p', f'live.sr_map_bytes_per_s:={BUDGET}', env=env),
            'map_server': srmosaic('map-server', '--port', str(port), env=env),
        }
        listener = SRWireListener()
        with supervised_processes(procs, listener.close) as logs:
            url = f'http://127.0.0.1:{port}/'
            assert listener.wait_for(lambda: listener.diag_value('frames_received') is not None, 60), 'no SR node'
            assert listener.wait_for(lambda: status_of(url) is not None, 60), 'the map server never answered'
            images = listener.node.create_publisher(Image, '/camera/image_raw', 10)
            regs = listener.node.create_publisher(Float64MultiArray, '/srmosaic/registration', 10)
            time.sleep(1.0)  # discovery of the two publishers
            origin = np.array([300.0, 200.0])
            most_pending = 0
            for k in range(FRAMES):  # hovering, drifting right: tiles side by side
                shift = np.array([10.0 + 12.0 * k, 10.0]) + [0.37 * k % 2.0, 0.61 * k % 2.0]
                stamp = 1_000_000_000 * (k + 1)
                images.publish(numpy_to_image(view(translation(*(origin + shift)), 200, 140, noise=2.0, seed=k), 'rgb8',
                                              stamp_ns=stamp, frame_id='camera'))
                time.sleep(0.05)
                regs.publish(encode_registration(stamp, True, 100, 0.1, 0, translation(*shift), np.eye(3), True, None))
                time.sleep(0.3)
            # every tile made went on the wire (the budget lets the waiting ones out), and the summary says so
            want = lambda: int(listener.diag_value('tiles_published') or 0)  # noqa: E731

            def drained() -> bool:
                nonlocal most_pending
                summary = listener.summary()
                if summary is not None:
                    most_pending = max(most_pending, summary['pending'])
                return bool(want() >= 3 and summary and summary['pending'] == 0 and len(listener.wire) >= want()
                            and len(summary['tiles']) == len({t.header.frame_id for t in listener.raw}))
            assert listener.wait_for(drained, 120), (want(), listener.summary(), len(listener.wire))
            yield {'url': url, 'env': env, 'listener': listener, 'most_pending': most_pending, 'logs': logs}


def test_every_sr_tile_goes_on_the_wire_within_the_budget(sr_flight) -> None:
    listener = sr_flight['listener']
    wire, raw = list(listener.wire), list(listener.raw)
    assert len(raw) >= 3 and len(wire) == len(raw)  # none lost, none twice (no refresh)
    newest_raw = {t.header.frame_id: t for t in raw}
    from msg_adapters import image_to_rgb_or_mono

    for msg in wire:  # the PNG is the SR image as published raw, pixel for pixel
        assert msg.format == 'png'
        bgr = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(bgr[:, :, ::-1], image_to_rgb_or_mono(newest_raw[msg.header.frame_id]))
    assert sr_flight['most_pending'] > 0 or any(json.loads(s.data)['pending'] > 0 for s in listener.summaries), \
        'the budget never held a tile back: the test does not test it'
    stamps = np.array([t.header.stamp.sec + 1e-9 * t.header.stamp.nanosec for t in wire])
    sizes = np.array([len(t.data) for t in wire])
    assert np.all(np.diff(stamps) >= 0)  # oldest first, in order
    for t0 in stamps:  # any window of W seconds: at most the budget for W + the bucket's second, plus one tile
        for w in (1.0, 3.0):
            inside = (stamps >= t0) & (stamps < t0 + w)
            assert sizes[inside].sum() <= BUDGET * (w + BURST_S) + sizes.max(), (t0, w)
    summary = listener.summary()
    assert {f for f, _ in summary['tiles']} == {t.header.frame_id for t in wire}
    assert summary['bytes_sent'] >= sizes.sum()


def test_the_map_server_shows_the_sr_tiles_from_the_stream(sr_flight) -> None:
    listener = sr_flight['listener']
    want = len(listener.summary()['tiles'])
    assert listener.wait_for(lambda: status_of(sr_flight['url'])['tiles']['sr'] == want, 30), status_of(sr_flight['url'])


def test_a_map_server_started_after_the_tiles_gets_every_sr_tile(sr_flight) -> None:
    listener = sr_flight['listener']
    want = len(listener.summary()['tiles'])
    port = free_port()
    late = srmosaic('map-server', '--port', str(port), env=sr_flight['env'])
    url = f'http://127.0.0.1:{port}/'
    try:
        assert listener.wait_for(lambda: (s := status_of(url)) is not None and s['tiles']['sr'] == want, 60), status_of(url)
    finally:
        out = stop_process(late)
    assert late.returncode == 0, out
