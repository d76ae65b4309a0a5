"""The mosaic node in a live graph over real DDS on loopback (`srmosaic launch` + `srmosaic play`, observed by
a subscriber): the same mosaic as offline, bad input survived, stamps, rate limits, parameter files."""
from __future__ import annotations

import collections
import json
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from srmosaic_ros.io.mosaic_files import read_frames_csv
from repo_paths import REPO

from live_graph import (
    DEMO,
    GEOREF,
    MOSAIC,
    SR,
    check_recorded_tiles,
    check_sr_tile_against_truth,
    play_into,
    sr_tile_map_error_m,
    srmosaic,
    supervised,
)

pytestmark = pytest.mark.ros


def test_live_graph_matches_offline_process(ros_env, tmp_path):
    live_dir = tmp_path / 'live'
    # Reliable inputs: the comparison with the offline run needs every frame (best effort may drop
    # some on a loaded machine, which the node would count and survive, but the mosaics would differ).
    # Telemetry kept 60 s: on a loaded host the node's queue of 100 frames falls behind the telemetry by more than
    # the default 10 s, and the filter would step past frames still queued (out of order: no pose), which the
    # comparison with the offline run is not about (test_a_node_falling_behind_says_so_and_how_to_catch_up is).
    graph = srmosaic('launch', '--ros-args', '-p', f'live.output_dir:={live_dir}', '-p', 'live.queue_size:=100',
                     '-p', 'live.preview_period_s:=0.5', '-p', 'live.reliable_inputs:=true',
                     '-p', 'georef.telemetry_buffer_s:=60.0', env=ros_env)
    recorder = srmosaic('record-tiles', str(tmp_path / 'ground'), '--preview', env=ros_env)  # a ground station
    with supervised(graph=graph, recorder=recorder) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diagnostics, 30), 'graph published no diagnostics'
        play_into(listener, DEMO, 60, delay_s=15, env=ros_env)
        assert listener.previews and listener.compressed
        assert len(listener.registrations) == 60
        preview = listener.previews[-1]
        assert preview.encoding == 'rgb8' and max(preview.width, preview.height) <= 1024
        # The preview says which region of the plane it shows, hence where it lies on the map.
        from srmosaic_ros.live.raster import ImagePlacement, LiveRaster

        region = ImagePlacement.parse(preview.header.frame_id)
        assert region.segment == 0 and region.width >= preview.width
        gt = LiveRaster.parse(listener.rasters[-1].data).image_geotransform(preview.header.frame_id, preview.width,
                                                                            preview.height)
        assert gt[1] > 0 > gt[5]  # north-up to first order, x east, y south
        assert listener.diag_value('dropped_frames') == '0'
        # The fused pose of every frame, near the simulated flight (100 m above the ground plane).
        # (frames whose pose is not valid yet, e.g. before the filter has its first fix, publish none)
        assert len(listener.poses) >= 30 and len(listener.fixes) == len(listener.poses)
        assert all(abs(p.pose.pose.position.z - 100.0) < 10.0 for p in listener.poses)
        assert all(abs(f.latitude - 30.17) < 0.01 for f in listener.fixes)
        # The SR node in the same process: tiles placed where the simulator's world is, and close to it.
        assert listener.wait_for(lambda: listener.tiles, 120), \
            f"no SR tile: {listener.diag_value('tiles_published', SR)} published"
        for tile in listener.tiles:
            fit = check_sr_tile_against_truth(tile, listener.registrations)
            print('TILE', tile.header.frame_id, tile.header.stamp.sec, tile.header.stamp.nanosec, round(fit['mae'], 3),
                  fit['best_shift'], round(fit['errors'][fit['best_shift']], 3))
        for tile in listener.tiles[:3]:
            fit = check_sr_tile_against_truth(tile, listener.registrations)
            assert max(abs(v) for v in fit['best_shift']) <= 1, fit
            assert fit['mae'] < 6.0, fit
        # On the map: /srmosaic/raster puts the tiles where the ground is (GPS sigma 2.5 m in the demo).
        assert listener.rasters, 'no /srmosaic/raster'
        for tile in listener.tiles[:3]:
            err = sr_tile_map_error_m(tile, listener.registrations, listener.rasters[-1].data)
            print('SR tile on the map: error', err)
            assert err['removed'] < 3.0, err
        # Tiles published again (live.sr_refresh_growth) are counted, and each placement at most
        # 1 + log2(max_frames / min_frames) times with the defaults (8 / 3: twice).
        assert listener.diag_value('tiles_refreshed', SR) is not None
        placements = collections.Counter(t.header.frame_id for t in listener.tiles)
        assert max(placements.values()) <= 2, placements
    check_recorded_tiles(tmp_path / 'ground', listener.tiles, listener.rasters[-1].data)
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
    """Every node of the graph (georef active) gets garbage; each counts it, logs once, goes on."""
    from sensor_msgs.msg import Image, NavSatFix
    from std_msgs.msg import Float64MultiArray

    from srmosaic_ros.nodes.common import encode_registration

    graph = srmosaic('launch', '--ros-args', '-p', 'live.preview_period_s:=0.3', '-p', 'live.sr_period_s:=0.3',
                     '-p', 'live.georef_standalone:=true', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: all(listener.diag_value('frames_received', n) is not None
                                             for n in (MOSAIC, SR)) and listener.diag_value('frames_fused', GEOREF),
                                 60), 'a node of the graph is missing'
        images = listener.publisher(Image, '/camera/image_raw')
        fixes = listener.publisher(NavSatFix, '/fix')
        registrations = listener.publisher(Float64MultiArray, '/srmosaic/registration')
        assert listener.wait_for(lambda: images.get_subscription_count() >= 2
                                 and registrations.get_subscription_count() >= 2, 20)
        short = Float64MultiArray(data=[1.0, 2.0, 3.0])
        nan_stamp = Float64MultiArray(data=[math.nan] * 89)
        eye = np.eye(3)
        newer = encode_registration(200 * 10**9, True, 50, 0.3, 0, eye, eye, True, None)
        older = encode_registration(195 * 10**9, True, 50, 0.3, 0, eye, eye, True, None)
        for msg in (short, nan_stamp, newer, older):
            registrations.publish(msg)
        bad = Image(height=4, width=4, encoding='yuv422', step=8, data=bytes(32))
        empty = Image(height=0, width=0, encoding='mono8', step=0, data=b'')
        nan_fix = NavSatFix(latitude=math.nan, longitude=1.0, altitude=1.0)
        for _ in range(3):
            images.publish(bad)
            images.publish(empty)
            fixes.publish(nan_fix)
            time.sleep(0.1)
        from sensor_msgs.msg import CameraInfo

        infos = listener.publisher(CameraInfo, '/camera/camera_info')
        assert listener.wait_for(lambda: infos.get_subscription_count() >= 3, 20)  # mosaic, SR and georef
        info = CameraInfo(width=16, height=16, k=[20.0, 0.0, 7.5, 0.0, 20.0, 7.5, 0.0, 0.0, 1.0])
        # The camera info and the images come on two topics, handled in two callback groups: the node
        # may see an image before a camera info sent just ahead of it. So, as a camera driver does, the
        # info is sent before each 32x32 frame (same aspect ratio: scaled to it) until the mosaic node
        # counts one scaled; stamps follow the wall clock from 100 s, so the stamp gate passes them.
        t0 = time.monotonic()

        def frame(height: int, width: int, stamp_ns: int) -> Image:
            msg = Image(height=height, width=width, encoding='mono8', step=width, data=bytes(height * width))
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
            return msg

        for _ in range(40):
            infos.publish(info)
            time.sleep(0.3)
            stamp_ns = 100 * 10**9 + int((time.monotonic() - t0) * 1e9)
            images.publish(frame(32, 32, stamp_ns))
            if listener.wait_for(lambda: listener.diag_value('camera_info_scaled', MOSAIC), 2.0, scaled=False):
                break
        images.publish(frame(20, 32, stamp_ns + 10**9))  # another aspect ratio: refused
        time.sleep(0.2)
        images.publish(frame(32, 32, stamp_ns - 5 * 10**9))  # within stamp_tolerance_s: older, not off the clock

        expected = {
            MOSAIC: ('rejected: image: MessageError', 'rejected: fix', 'rejected: image time going backwards',
                     'rejected: image: size unlike the camera info', 'camera_info_scaled'),
            SR: ('rejected: image: MessageError', 'rejected: image: empty', 'rejected: image time going backwards',
                 'rejected: registration'),
            GEOREF: ('rejected: fix', 'rejected: registration', 'rejected: registration time going backwards'),
        }

        def counted() -> bool:
            return all(listener.diag_value(k, n) for n, keys in expected.items() for k in keys)
        assert listener.wait_for(counted, 30), {n: [k for k in keys if not listener.diag_value(k, n)]
                                                for n, keys in expected.items()}
        assert graph.poll() is None, 'a node died on bad input'
    log = sup.logs['graph']
    # Logged once per kind and node, not per message.
    assert log.count('not supported') == 1, log
    assert log.count("image with encoding 'yuv422'") == 1, log
    assert log.count('registration skipped') == 2, log  # SR node and georef node, once each


def tampered_demo(dst: Path, *, image: int, fix: int, shift_s: int = 10**6) -> Path:
    """The demo bag rewritten (rosbags) with the header stamp of its ``image``-th image and
    ``fix``-th fix moved ``shift_s`` seconds into the future (a driver's glitch)."""
    from demo_bags import rewrite_demo

    def tamper(kind: str, index: int, msg: Any) -> None:
        if index == {'image': image, 'fix': fix}.get(kind):
            msg.header.stamp.sec += shift_s

    return rewrite_demo(dst, tamper)


def test_one_future_stamp_costs_one_message_offline_and_live(ros_env, tmp_path):
    """One image and one fix stamped 10^6 s in the future. Offline they used to cost the flight (a
    mosaic.tif of 10^6 m pixels, then a traceback; 63 fixes out of order, 14.6 m RMS); live, the
    frozen mosaic node said 'registering' at level OK. Now each costs its message: counted, said,
    and diagnostics WARN while it happens; the rest of the flight as without it."""
    from diagnostic_msgs.msg import DiagnosticStatus

    bag = tampered_demo(tmp_path / 'glitch', image=10, fix=10)
    out = tmp_path / 'offline'
    run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', 'process', str(bag), '--out', str(out),
                          '--no-progress'], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert 'Traceback' not in run.stderr and 'stamp_tolerance_s' in run.stderr, run.stderr
    report = json.loads((out / 'report.json').read_text())
    assert report['frames_in'] == 59 and report['frames_registered'] == 59, report
    assert sorted(report['skipped_messages'].values()) == [1, 1], report['skipped_messages']
    assert not report['georeferenced']['skipped_telemetry'], report['georeferenced']
    gt = report['georeferenced']['geotransform']
    assert 0.15 < gt[1] < 0.21, gt  # the demo's 0.18 m pixels (they were 10^6 m)

    graph = srmosaic('node', 'mosaic', '--ros-args', '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100',
                     '-p', 'live.preview_period_s:=0.3', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diagnostics, 30), 'no diagnostics'
        # reliable, a queue for all: none lost; at twice the flight's pace, which a loaded 2-core machine keeps
        play_into(listener, bag, 59, delay_s=5, env=ros_env, rate=2.0)
        assert listener.diag_value('rejected: image stamp off the clock') == '1'
        assert listener.diag_value('rejected: fix stamp off the clock') == '1'
        warned = [st for msg in list(listener.diagnostics) for st in msg.status
                  if st.name == MOSAIC and st.level == DiagnosticStatus.WARN and 'stamp off the clock' in st.message]
        assert warned, 'diagnostics never said the stamps were refused'
        assert listener.diagnostics[-1].status[0].level == DiagnosticStatus.OK  # not WARN for ever after
        assert len(listener.poses) >= 30
        assert all(math.isfinite(p.pose.pose.position.x) and abs(p.pose.pose.position.z - 100.0) < 10.0
                   for p in listener.poses)
    assert sup.logs['graph'].count('stamp_tolerance_s') == 2, sup.logs['graph']  # once per stream


def test_a_node_falling_behind_says_so_and_how_to_catch_up(ros_env):
    """Frames faster than the node processes them (the demo bag at 20x into a queue of one): the
    dropped frames are counted, the log says once what to do, and the diagnostics WARN while frames
    are being dropped and stop saying so (the count kept) once the node has caught up."""
    from diagnostic_msgs.msg import DiagnosticStatus

    graph = srmosaic('node', 'mosaic', '--ros-args', '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=1',
                     '-p', 'live.preview_period_s:=0.3', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diagnostics, 30), 'no diagnostics'
        player = srmosaic('play', str(DEMO), '--rate', '20.0', '--delay', '15', env=ros_env)
        out, _ = player.communicate(timeout=120)
        assert player.returncode == 0, out
        assert listener.wait_for(lambda: int(listener.diag_value('frames_received') or 0) == 60, 60)
        dropped = int(listener.diag_value('dropped_frames'))
        assert 0 < dropped < 60
        n = len(listener.diagnostics)
        assert listener.wait_for(lambda: len(listener.diagnostics) >= n + 3, 10)  # reports after the input stopped
        statuses = [st for msg in list(listener.diagnostics) for st in msg.status if st.name == MOSAIC]
        behind = [st for st in statuses if st.level == DiagnosticStatus.WARN and 'falling behind' in st.message]
        assert behind and 'frames dropped since the last report' in behind[0].message, [st.message for st in statuses]
        last = statuses[-1]
        # (its level may still WARN for the last frame: with most frames dropped, pairs may not overlap)
        assert 'since the last report' not in last.message, last.message
        assert f'{dropped} frames dropped (falling behind) earlier' in last.message, last.message
    assert sup.logs['graph'].count('frames arrive faster than this node processes them') == 1, sup.logs['graph']
    assert 'registration.max_width' in sup.logs['graph']


def test_max_rate_takes_every_other_frame_by_stamp(ros_env):
    """live.max_rate_hz at half the demo's frame rate (4 fps): every other frame is taken, by its
    stamp, however fast the bag is played; the others are counted as skipped, none dropped, and the
    frames taken make one mosaic."""
    graph = srmosaic('node', 'mosaic', '--ros-args', '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100',
                     '-p', 'live.preview_period_s:=0.3', '-p', 'live.max_rate_hz:=2.0', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diagnostics, 30), 'no diagnostics'
        play_into(listener, DEMO, 30, delay_s=15, env=ros_env, rate=8.0)  # reliable, a queue for all: none lost
        assert listener.diag_value('frames_skipped_by_rate') == '30' and listener.diag_value('dropped_frames') == '0'
        assert listener.diag_value('frames_in_mosaic') == '30' and listener.diag_value('segments') == '1'
    refused = srmosaic('node', 'mosaic', '--ros-args', '-p', 'live.max_rate_hz:=-1.0', env=ros_env)
    out, _ = refused.communicate(timeout=60)
    assert refused.returncode == 2 and 'live.max_rate_hz' in out, out


def test_max_rate_schedule_is_even_tolerates_jitter_and_restarts_after_a_gap():
    """The rule of live.max_rate_hz on its own: frames due one interval apart on the stamps' clock."""
    import random

    from srmosaic_ros.live.frame_intake import RateLimiter

    def taken(fps: float, hz: float, stamps_s: list[float] | None = None, jitter_s: float = 0.0) -> list[int]:
        rng = random.Random(0)
        rate = RateLimiter(hz)
        stamps_s = stamps_s or [k / fps for k in range(300)]
        return [k for k, t in enumerate(stamps_s) if rate.due(int((t + rng.uniform(-jitter_s, jitter_s)) * 1e9))]

    assert taken(30, 15) == list(range(0, 300, 2))
    assert taken(30, 15, jitter_s=0.008) == list(range(0, 300, 2))   # stamps 8 ms off either way
    assert len(taken(30, 20)) == 200 and len(taken(30, 20, jitter_s=0.008)) == 200
    assert len(taken(30, 30, jitter_s=0.003)) == 300 and len(taken(30, 45)) == 300
    # a 2 s gap in the input: the schedule starts again at the next frame, no burst after it
    stamps = [k / 30 for k in range(30)] + [3.0 + k / 30 for k in range(30)]
    got = taken(30, 10, stamps)
    first, second = [k for k in got if k < 30], [k - 30 for k in got if k >= 30]
    assert first == second == list(range(0, 30, 3)), got


LIVE_HD_CHECK = """
import json, sys, rclpy
from srmosaic_ros.nodes.mosaic_node import MosaicNode
rclpy.init(args=['--ros-args', '--params-file', sys.argv[1]])
node = MosaicNode()
print(json.dumps({'registration_width': node.config.registration.max_width, 'mosaic_width': node.config.mosaic.max_width,
                  'track_frames': node.config.registration.track_frames, 'queue': node.intake.frames.maxlen,
                  'keyframe_interval': node.config.mosaic.keyframe_interval,
                  'paint_stride': node.config.mosaic.paint_stride, 'paint_shift_px': node.config.mosaic.paint_shift_px}))
node.finish()
node.destroy_node()
rclpy.shutdown()
"""


def test_live_hd_parameter_file_configures_the_mosaic_node(ros_env):
    """params/live_hd.yaml, as a user gives it to the node, reaches its pipeline and its queue."""
    run = subprocess.run([sys.executable, '-c', LIVE_HD_CHECK, str(REPO / 'params' / 'live_hd.yaml')], env=ros_env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got == {'registration_width': 640, 'mosaic_width': 640, 'track_frames': 30, 'queue': 16, 'keyframe_interval': 30,
                   'paint_stride': 5, 'paint_shift_px': 32.0}


def test_an_oblique_camera_without_attitude_is_said_live(ros_env, tmp_path):
    """GPS and intrinsics, no Imu, a camera 70 deg below the horizon on the default nadir mount
    (test_mount_from_frames.py's line): the mosaic node keeps its frames off the map, and its
    diagnostics WARN with the mount the frames show, to set when it is restarted (it cannot read its
    stream again as `process` does)."""
    import dataclasses

    from diagnostic_msgs.msg import DiagnosticStatus

    from srmosaic_ros.sim import SimConfig, simulate
    from srmosaic_ros.sim.record import write_flight

    line = {'trajectory': 'line', 'frames': 40, 'rate_hz': 2.0, 'altitude_m': 80.0, 'hfov_deg': 40.0, 'width': 160,
            'height': 120, 'gimbal_elevation_deg': -70.0, 'seed': 4}
    bag = write_flight(dataclasses.replace(simulate(SimConfig(**line)), imus=[]), tmp_path / 'bag')
    graph = srmosaic('node', 'mosaic', '--ros-args', '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100',
                     '-p', 'live.preview_period_s:=0.3', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diagnostics, 30), 'no diagnostics'
        play_into(listener, bag, 40, delay_s=5, env=ros_env, rate=8.0)
        assert listener.diag_value('pose_placement') == 'refused'
        elevation = float(listener.diag_value('frames_mount_elevation_deg'))
        assert -72.5 < elevation < -67.5, elevation
        status = [st for st in listener.diagnostics[-1].status if st.name == MOSAIC][0]
        assert status.level == DiagnosticStatus.WARN
        assert f'georef.gimbal_elevation_deg: {elevation:g}' in status.message, status.message
        # the filter's skip counts, as the standalone georef node gives them: no Imu orientation at the start
        assert listener.diag_value('filter skipped: no_attitude') == '1'
    assert 'not placed by the filter' in sup.logs['graph']
