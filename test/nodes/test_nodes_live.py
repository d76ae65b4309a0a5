"""The live graph over real DDS on loopback: `srmosaic launch` + `srmosaic play`, observed by a subscriber.

Each test uses its own ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST. Waits are
event-driven (a condition polled with a generous timeout), so a loaded machine is slower, not red.
"""
from __future__ import annotations

import collections
import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from ros_graph import GraphListener, supervised_processes

from srmosaic_ros.io.mosaic_files import read_frames_csv
from repo_paths import REPO

ROOT = REPO
DEMO = ROOT / 'bags' / 'demo'
pytestmark = pytest.mark.ros

MOSAIC = 'srmosaic: registration and mosaic'  # diagnostic status names of the nodes
SR = 'srmosaic: super-resolution'
GEOREF = 'srmosaic: georeferencing'


def srmosaic(*args: str, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.cli', *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


class Listener(GraphListener):
    """An rclpy node in this process that records what the graph publishes."""

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CompressedImage, Image, NavSatFix
        from std_msgs.msg import Float64MultiArray, String

        super().__init__('srmosaic_test_listener')
        self.tiles = self.subscribe(Image, '/srmosaic/sr_tile', 50)
        self.previews = self.subscribe(Image, '/srmosaic/mosaic_preview', 10)
        self.compressed = self.subscribe(CompressedImage, '/srmosaic/mosaic_preview/compressed', 10)
        self.diagnostics = self.subscribe(DiagnosticArray, '/srmosaic/diagnostics', 10)
        self.registrations = self.subscribe(Float64MultiArray, '/srmosaic/registration', 100)
        self.poses = self.subscribe(PoseWithCovarianceStamped, '/srmosaic/pose', 100)
        self.fixes = self.subscribe(NavSatFix, '/srmosaic/fix', 100)
        self.rasters = self.subscribe(String, '/srmosaic/raster', QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.start()

    def diag_value(self, key: str, name: str = MOSAIC) -> str | None:
        """`key` in the newest diagnostics of the node whose status is called `name`."""
        for msg in reversed(list(self.diagnostics)):
            for status in msg.status:
                if status.name == name:
                    return {kv.key: kv.value for kv in status.values}.get(key)
        return None

    def publisher(self, msg_type, topic: str):
        return self.node.create_publisher(msg_type, topic, 10)


def _translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def check_sr_tile_against_truth(tile_msg, registration_msgs) -> dict:
    """An SR tile of the demo flight against the simulator's world: placement and pixels.

    The tile's placement (header.frame_id) and the registrations of the same run give, through a
    frame k the tile was made from (its newest, header.stamp), tile HR pixel -> segment plane ->
    frame k -> world image pixel (the simulator's true world_px_H_frame). The world rendered there
    is the ground truth of the tile. (Through another frame the check would also measure that
    frame's placement error: the first frames of a segment sit up to 1.5 px from the later ones.)
    Returns the mean absolute error (0..255) at the stated placement and the shift (HR pixels)
    of the truth rendering that fits the tile best.
    """
    import cv2

    from msg_adapters import image_to_numpy
    from srmosaic_ros.nodes.common import decode_registration
    from srmosaic_ros.sim.render import reference_render
    from srmosaic_ros.sim.truth import load_truth
    from srmosaic_ros.live.sr import SRTilePlacement

    place = SRTilePlacement.parse(tile_msg.header.frame_id)
    s = place.factor
    tile = image_to_numpy(tile_msg).astype(np.float64)
    assert tile_msg.encoding == 'rgb8' and tile.shape == (place.height * s, place.width * s, 3)
    truth = load_truth(DEMO / 'ground_truth.json')
    true_H = {f.stamp_ns: f.world_px_H_frame for f in truth.frames}
    regs = [r for r in map(decode_registration, registration_msgs) if r.ok and r.segment == place.segment]
    centre = place.plane_H_tile() @ np.array([(tile.shape[1] - 1) / 2, (tile.shape[0] - 1) / 2, 1.0])

    def off_centre(r) -> float:
        p = np.linalg.solve(r.seg_H_frame, centre)
        return float(np.hypot(p[0] / p[2] - 319.5, p[1] / p[2] - 239.5))

    stamp = tile_msg.header.stamp.sec * 1_000_000_000 + tile_msg.header.stamp.nanosec
    best = next((r for r in regs if r.stamp_ns == stamp), None) or min(regs, key=off_centre)
    world_H_plane = true_H[best.stamp_ns] @ np.linalg.inv(best.seg_H_frame)
    world = np.ascontiguousarray(cv2.imread(str(ROOT / truth.world_path), cv2.IMREAD_COLOR)[:, :, ::-1])
    m = 8  # the border sees fewer frames
    errors = {}
    for dx in range(-2, 3):
        for dy in range(-2, 3):
            ref = reference_render(world, world_H_plane @ place.plane_H_tile() @ _translation(dx, dy),
                                   (tile.shape[1], tile.shape[0]), 0.5)
            errors[dx, dy] = float(np.abs(ref[m:-m, m:-m] - tile[m:-m, m:-m]).mean())
    return {'mae': errors[0, 0], 'best_shift': min(errors, key=errors.get), 'errors': errors, 'placement': place}


def sr_tile_map_error_m(tile_msg, registration_msgs, raster_text: str) -> dict:
    """How far from the true ground position /srmosaic/raster puts an SR tile's centre (m), with
    drift control's canvas similarity taken out (the default) and kept (the raster as painted)."""
    from pyproj import Transformer

    from srmosaic_ros.core.georef.geodetic import LocalTangentPlane
    from srmosaic_ros.core.metrics import apply_homography
    from srmosaic_ros.live.raster import LiveRaster
    from srmosaic_ros.nodes.common import decode_registration
    from srmosaic_ros.sim.truth import load_truth
    from srmosaic_ros.live.sr import SRTilePlacement

    raster = LiveRaster.parse(raster_text)
    place = SRTilePlacement.parse(tile_msg.header.frame_id)
    s = place.factor
    centre = np.array([(place.width * s - 1) / 2, (place.height * s - 1) / 2])
    plane = apply_homography(place.plane_H_tile(), centre[None])
    truth = load_truth(DEMO / 'ground_truth.json')
    true_H = {f.stamp_ns: f.world_px_H_frame for f in truth.frames}
    stamp = tile_msg.header.stamp.sec * 1_000_000_000 + tile_msg.header.stamp.nanosec
    reg = next(r for r in map(decode_registration, registration_msgs) if r.stamp_ns == stamp)
    world = apply_homography(true_H[stamp] @ np.linalg.inv(reg.seg_H_frame), plane)
    enu = apply_homography(truth.enu_H_world_px, world)
    lat, lon, _ = LocalTangentPlane(*truth.origin).geodetic_from_enu(np.c_[enu, np.zeros(1)])
    e_true = np.c_[Transformer.from_crs(4326, raster.epsg, always_xy=True).transform(lon, lat)][0]
    out = {}
    for name, removed in (('removed', True), ('kept', False)):
        gt = raster.tile_geotransform(place, canvas_frame_removed=removed)
        u, v = centre + 0.5   # pixel corners in GDAL's convention
        est = np.array([gt[0] + gt[1] * u + gt[2] * v, gt[3] + gt[4] * u + gt[5] * v])
        out[name] = float(np.linalg.norm(est - e_true))
    return out


def check_recorded_tiles(folder: Path, tiles: list, raster_text: str) -> None:
    """`srmosaic record-tiles`: every SR tile placement as a GeoTIFF (the latest tile's pixels) on the
    map where /srmosaic/raster puts it; the preview as a GeoTIFF too."""
    import rasterio

    from msg_adapters import image_to_numpy
    from srmosaic_ros.live.raster import ImagePlacement, LiveRaster

    raster = LiveRaster.parse(raster_text)
    latest = {t.header.frame_id: t for t in tiles}
    files = sorted((folder / 'sr_tiles').glob('*.tif'))
    assert len(files) == len(latest), (files, list(latest))
    for frame_id, tile in latest.items():
        place = ImagePlacement.parse(frame_id)
        with rasterio.open(folder / 'sr_tiles' / f'seg{place.segment}_x{place.x0}_y{place.y0}.tif') as ds:
            assert ds.crs.to_epsg() == raster.epsg
            np.testing.assert_array_equal(np.moveaxis(ds.read(), 0, -1), image_to_numpy(tile))
            want = raster.image_geotransform(frame_id, tile.width, tile.height)
            # written with the raster known then, moved since to the newest estimate (they were metres
            # apart), to 2 cm at 1000 px (smaller moves leave the files alone)
            np.testing.assert_allclose(ds.transform.to_gdal(), want, rtol=0, atol=0.05)
    with rasterio.open(folder / 'preview.tif') as ds:
        assert ds.crs.to_epsg() == raster.epsg and ds.width > 100


class _Supervision:
    """What :func:`supervised` gives the test: the Listener, and each process's output once stopped."""

    def __init__(self, procs: dict[str, subprocess.Popen]) -> None:
        self.procs = procs
        self.listener = Listener()
        self.logs: dict[str, str] = {}


@contextlib.contextmanager
def supervised(**procs: subprocess.Popen) -> Iterator[_Supervision]:
    """Run a test against started srmosaic processes: a failed assertion carries their output, and
    at the end each one is stopped (its output in ``.logs``) and must have exited cleanly."""
    sup = _Supervision(procs)
    with supervised_processes(procs, sup.listener.close) as logs:
        sup.logs = logs
        yield sup
    for name, proc in procs.items():
        assert proc.returncode == 0, sup.logs[name]


def play_into(listener: Listener, bag: Path, frames: int, *, delay_s: int, env: dict[str, str], rate: float = 2.0) -> None:
    """`srmosaic play` the bag at ``rate``, then wait until the mosaic node says it processed ``frames``."""
    player = srmosaic('play', str(bag), '--rate', str(rate), '--delay', str(delay_s), env=env)
    out, _ = player.communicate(timeout=120)
    assert player.returncode == 0, out
    assert listener.wait_for(lambda: listener.diag_value('frames_processed') == str(frames), 240), \
        (f'graph did not process the {frames} frames: received {listener.diag_value("frames_received")}, '
         f'processed {listener.diag_value("frames_processed")}')
    time.sleep(1.0)


def test_live_graph_matches_offline_process(ros_env, tmp_path):
    live_dir = tmp_path / 'live'
    # Reliable inputs: the comparison with the offline run needs every frame (best effort may drop
    # some on a loaded machine, which the node would count and survive, but the mosaics would differ).
    graph = srmosaic('launch', '--ros-args', '-p', f'live.output_dir:={live_dir}', '-p', 'live.queue_size:=100',
                     '-p', 'live.preview_period_s:=0.5', '-p', 'live.reliable_inputs:=true', env=ros_env)
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


def test_split_graph_in_separate_processes(ros_env, tmp_path):
    """mosaic | georef | sr, each in its own process (a launch description), the filter standalone."""
    description = tmp_path / 'split.yaml'
    description.write_text(
        'processes:\n'
        '  - {name: onboard, nodes: [mosaic], parameters: {live.queue_size: 100}}\n'
        '  - {name: georef, nodes: [georef]}\n'
        '  - {name: ground, nodes: [sr]}\n')
    graph = srmosaic('launch', str(description), '--ros-args', '-p', 'live.georef_standalone:=true',
                     '-p', 'live.reliable_inputs:=true', '-p', 'live.preview_period_s:=0.5',
                     '-p', 'live.sr_period_s:=0.5', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        names = (MOSAIC, GEOREF, SR)
        assert listener.wait_for(lambda: all(listener.diag_value('frames_received' if n != GEOREF else 'frames_fused', n)
                                             is not None for n in names), 60), 'a node of the split graph is missing'
        # No need for the whole bag here: stop as soon as every stage has delivered.
        player = srmosaic('play', str(DEMO), '--rate', '1.0', '--delay', '15', env=ros_env)
        try:
            assert listener.wait_for(lambda: len(listener.poses) >= 10 and listener.tiles and listener.previews,
                                     240), (f"{listener.diag_value('frames_processed')} frames processed, "
                                            f'{len(listener.poses)} poses, {len(listener.tiles)} SR tiles')
        finally:
            if player.poll() is None:
                player.send_signal(signal.SIGINT)
            player.communicate(timeout=60)
        assert listener.previews and listener.compressed
        # The standalone filter: one pose per fused frame, near the simulated flight.
        assert listener.wait_for(lambda: listener.compressed, 10)
        assert all(abs(p.pose.pose.position.z - 100.0) < 10.0 for p in listener.poses)
        assert all(abs(f.latitude - 30.17) < 0.01 for f in listener.fixes)
        assert {p.header.frame_id for p in listener.poses} == {'srmosaic_enu'}
        fit = check_sr_tile_against_truth(listener.tiles[0], listener.registrations)
        print('split graph SR tile', fit['placement'], 'mae', round(fit['mae'], 2), 'best shift', fit['best_shift'])
        assert max(abs(v) for v in fit['best_shift']) <= 1, fit
        assert fit['mae'] < 6.0, fit



@pytest.mark.skipif(not Path('/proc/self/task').is_dir(), reason='reads child processes from /proc (Linux)')
def test_standalone_filter_stopped_by_the_scheduler_fuses_as_if_it_had_run(ros_env, tmp_path):
    """The standalone georef process stopped for 1.5 s mid-flight (SIGSTOP: a loaded machine) finds
    its queues full when it resumes: every frame still gets its pose near the simulated flight, with
    no gyro gap, no gated fix or Imu and no frame out of order. It used to fuse frames before the Imu
    backlog (drained behind the fixes) had reached them, and to feed telemetry so far ahead of the
    registrations (which come mosaic.revisit_spread_frames frames late) that the filter bridged a
    camera dropout that was not one: poses 40 m off, or none. Its fixes are then those of the filter
    inside the mosaic node (the default graph, not stopped) to the millimetre."""
    from msg_adapters import stamp_to_ns

    description = tmp_path / 'split.yaml'
    description.write_text('processes:\n  - {name: onboard, nodes: [mosaic]}\n  - {name: georef, nodes: [georef]}\n')
    graph = srmosaic('launch', str(description), '--ros-args', '-p', 'live.georef_standalone:=true',
                     '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diag_value('frames_fused', GEOREF) is not None, 60), 'no georef node'
        georef = next(c for c in _children(graph.pid) if ' node georef ' in _cmdline(c) + ' ')
        player = srmosaic('play', str(DEMO), '--rate', '1.0', '--delay', '15', env=ros_env)
        try:
            assert listener.wait_for(lambda: listener.poses, 120), 'no pose'
            time.sleep(0.2)
            os.kill(georef, signal.SIGSTOP)
            time.sleep(1.5)
            os.kill(georef, signal.SIGCONT)
            out, _ = player.communicate(timeout=120)
            assert player.returncode == 0, out
            # the first 30 registrations (the others are painted after IDLE_PAINT_S of paused input)
            assert listener.wait_for(lambda: len(listener.poses) >= 30, 60), f'{len(listener.poses)} poses'
        finally:
            if player.poll() is None:
                player.kill()
                player.communicate()
        assert all(abs(p.pose.pose.position.z - 100.0) < 10.0 for p in listener.poses), \
            [round(p.pose.pose.position.z, 1) for p in listener.poses]
        assert listener.wait_for(lambda: listener.diag_value('poses_published', GEOREF) not in (None, '0'), 10)
        skipped = {kv.key: kv.value for msg in listener.diagnostics for status in msg.status
                   if status.name == GEOREF for kv in status.values if kv.key.startswith('filter skipped')}
        assert not skipped, skipped
    standalone = {stamp_to_ns(f.header.stamp): f for f in listener.fixes}
    graph = srmosaic('launch', '--ros-args', '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diag_value('frames_received') is not None, 60), 'no mosaic node'
        player = srmosaic('play', str(DEMO), '--rate', '2.0', '--delay', '15', env=ros_env)
        out, _ = player.communicate(timeout=120)
        assert player.returncode == 0, out
        assert listener.wait_for(lambda: len(listener.fixes) >= 30, 60), f'{len(listener.fixes)} fixes'
        in_node_skipped = {kv.key: kv.value for msg in listener.diagnostics for status in msg.status
                           for kv in status.values if kv.key.startswith('filter skipped')}
    in_node = {stamp_to_ns(f.header.stamp): f for f in listener.fixes}
    common = sorted(set(standalone) & set(in_node))
    assert len(common) >= 30, (len(standalone), len(in_node))
    apart = {t: math.hypot((a.latitude - b.latitude) * 111_320.0,
                           (a.longitude - b.longitude) * 111_320.0 * math.cos(math.radians(a.latitude)),
                           a.altitude - b.altitude) for t, a, b in ((t, standalone[t], in_node[t]) for t in common)}
    worst = max(apart.values())
    # it failed now and then under load (2026-12-07, also before that day's changes): say which frames
    # moved, and which run moved them (each one's distance from the simulated truth there, m)
    truth = {f['stamp_ns']: f for f in json.loads((DEMO / 'ground_truth.json').read_text())['frames']}

    def off(fix) -> float | None:
        t = truth.get(stamp_to_ns(fix.header.stamp))
        return None if t is None else round(math.hypot(
            (fix.latitude - t['latitude_deg']) * 111_320.0,
            (fix.longitude - t['longitude_deg']) * 111_320.0 * math.cos(math.radians(fix.latitude))), 2)
    assert worst < 0.01, (worst, {t: (round(d, 3), 'standalone', off(standalone[t]), 'in-node', off(in_node[t]))
                                  for t, d in apart.items() if d >= 0.01}, 'in-node filter', in_node_skipped)


def _children(pid: int) -> list[int]:
    out: list[int] = []
    for task in os.listdir(f'/proc/{pid}/task'):
        with contextlib.suppress(OSError), open(f'/proc/{pid}/task/{task}/children') as handle:
            out += [int(c) for c in handle.read().split()]
    return out


def _cmdline(pid: int) -> str:
    try:
        with open(f'/proc/{pid}/cmdline') as handle:
            return handle.read().replace('\0', ' ')
    except OSError:
        return ''


def _running(pid: int) -> bool:
    """The process exists and has not exited (a zombie not reaped by a container's PID 1 has)."""
    try:
        with open(f'/proc/{pid}/stat') as handle:
            return handle.read().rsplit(') ', 1)[1][0] != 'Z'
    except OSError:
        return False


@pytest.mark.skipif(not Path('/proc/self/task').is_dir(), reason='reads child processes from /proc (Linux)')
def test_a_launch_child_killed_is_named_and_leaves_no_sr_worker(ros_env, tmp_path):
    """kill -9 of the process running the SR node: the launcher names it and stops the other one,
    and the SR worker process (spawned by the node) ends with it; it used to idle on for minutes."""
    description = tmp_path / 'two.yaml'
    description.write_text('processes:\n  - {name: onboard, nodes: [mosaic]}\n  - {name: ground, nodes: [sr]}\n')
    graph = srmosaic('launch', str(description), env=ros_env)
    try:
        deadline, sr_child, workers = time.monotonic() + 90, None, []
        while time.monotonic() < deadline and not workers:
            sr_child = next((c for c in _children(graph.pid) if ' node sr ' in _cmdline(c) + ' '), None)
            if sr_child is not None:
                workers = [w for w in _children(sr_child) if 'spawn_main' in _cmdline(w)]
            time.sleep(0.5)
        assert sr_child is not None and workers, 'no SR node with its worker process'
        time.sleep(2.0)  # the worker past its start
        os.kill(sr_child, signal.SIGKILL)
        out, _ = graph.communicate(timeout=90)
    finally:
        if graph.poll() is None:
            graph.kill()
            graph.communicate()
    assert graph.returncode != 0
    assert 'srmosaic launch: ground was killed by SIGKILL; stopping the others' in out, out
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(_running(w) for w in workers):
        time.sleep(0.2)
    assert not any(_running(w) for w in workers), 'the SR worker outlived its node'


def test_a_second_ctrl_c_kills_the_launch_children_still_running(ros_env, tmp_path):
    """Ctrl-C to `srmosaic launch` stops the children cleanly and waits for them (they write their
    outputs); a child that does not finish (here: stopped by SIGSTOP) kept the launcher waiting for
    ever. Now the launcher says whom it waits for, and a second Ctrl-C kills them, named (status 1)."""
    description = tmp_path / 'one.yaml'
    description.write_text('processes:\n  - {name: ground, nodes: [georef]}\n')
    graph = srmosaic('launch', str(description), env=ros_env)
    child = None
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and child is None:
            child = next((c for c in _children(graph.pid) if ' node georef' in _cmdline(c)), None)
            time.sleep(0.3)
        assert child is not None, 'no georef child'
        time.sleep(3.0)  # past its start
        os.kill(child, signal.SIGSTOP)  # a child that never finishes its shutdown
        graph.send_signal(signal.SIGINT)
        time.sleep(2.0)
        assert graph.poll() is None, 'the launcher did not wait for its child'
        graph.send_signal(signal.SIGINT)
        out, _ = graph.communicate(timeout=30)
    finally:
        if child is not None and _running(child):
            os.kill(child, signal.SIGKILL)
        if graph.poll() is None:
            graph.kill()
            graph.communicate()
    assert 'srmosaic launch: stopping; waiting for ground to finish' in out, out
    assert 'srmosaic launch: killed ground' in out, out
    assert graph.returncode == 1, out
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and _running(child):
        time.sleep(0.2)
    assert not _running(child)


def sr_node_inputs(listener: Listener) -> tuple[Any, Any]:
    """Once the SR node is up: publishers of its camera images and of registrations (discovered)."""
    from sensor_msgs.msg import Image
    from std_msgs.msg import Float64MultiArray

    assert listener.wait_for(lambda: listener.diag_value('frames_received', SR) is not None, 60), 'no SR node'
    images = listener.publisher(Image, '/camera/image_raw')
    regs = listener.publisher(Float64MultiArray, '/srmosaic/registration')
    time.sleep(1.0)  # discovery of the two publishers
    return images, regs


def test_sr_node_says_when_registrations_come_after_their_images_were_dropped(ros_env):
    """The SR node alone with room for 3 images waiting for their registration: 6 images, then the
    registration of the first (dropped for room) and of the last: the first is counted as a rejection
    (diagnostics WARN, naming it), the way out is logged once, and the last still makes a frame."""
    from diagnostic_msgs.msg import DiagnosticStatus

    from msg_adapters import numpy_to_image
    from srmosaic_ros.nodes.common import encode_registration

    node = srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'live.sr_worker:=thread',
                    '-p', 'live.sr_images_pending:=3', '-p', 'live.reliable_inputs:=true', env=ros_env)
    kind = 'rejected: registration after its image was dropped'
    with supervised(node=node) as sup:
        listener = sup.listener
        images, regs = sr_node_inputs(listener)
        stamps = [1_000_000_000 * (k + 1) for k in range(6)]
        for k, stamp in enumerate(stamps):
            images.publish(numpy_to_image(np.full((48, 64, 3), 20 * k, np.uint8), 'rgb8', stamp_ns=stamp, frame_id='camera'))
        assert listener.wait_for(lambda: listener.diag_value('frames_received', SR) == '6', 20), \
            listener.diag_value('frames_received', SR)
        for stamp in (stamps[0], stamps[-1]):
            regs.publish(encode_registration(stamp, True, 100, 0.1, 0, np.eye(3), np.eye(3), True, None))
        assert listener.wait_for(lambda: listener.diag_value(kind, SR) == '1', 20), listener.diag_value(kind, SR)
        assert listener.wait_for(lambda: listener.diag_value('frames_kept', SR) == '1', 20)
        warned = [st for msg in list(listener.diagnostics) for st in msg.status
                  if st.name == SR and st.level == DiagnosticStatus.WARN and 'registration after its image' in st.message]
        assert warned, 'diagnostics never said it'
    assert sup.logs['node'].count('raise it to the camera frames') == 1, sup.logs['node']


def test_sr_node_refreshes_a_tile_when_more_frames_cover_it(ros_env):
    """The SR node alone, fed frames and registrations over DDS by this test: an aircraft hovering
    over one spot. Each tile is published once 3 frames cover it, then again (same placement) once
    twice as many do (live.sr_refresh_growth 2), and counted as refreshed."""

    from imagery import view
    from msg_adapters import image_to_numpy, numpy_to_image
    from srmosaic_ros.nodes.common import encode_registration
    from srmosaic_ros.live.sr import SRTilePlacement

    # stamp_tolerance_s 0 (the gate off): the test's stamps advance 1 s a frame whatever its waits take
    # on a loaded machine, which the gate would rightly call a clock off the receive times
    node = srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'live.sr_worker:=thread',
                    '-p', 'sr_tiles.tile_size:=64', '-p', 'sr_tiles.max_frames:=12', '-p', 'sr.iterations:=5',
                    '-p', 'stamp_tolerance_s:=0.0', env=ros_env)
    with supervised(node=node) as sup:
        listener = sup.listener
        images, regs = sr_node_inputs(listener)
        origin = np.array([300.0, 200.0])

        def state() -> str:
            return ', '.join(f'{k} {listener.diag_value(k, SR)}' for k in (
                'frames_received', 'frames_kept', 'registrations_without_image', 'tiles_published', 'tiles_refreshed'))

        for k in range(12):
            shift = np.array([10.0, 10.0]) + [0.37 * k % 2.0, 0.61 * k % 2.0]  # sub-pixel hovering
            plane_H_frame = _translation(*shift)
            frame = view(_translation(*(origin + shift)), 200, 140, noise=2.0, seed=k)
            stamp = 1_000_000_000 * (k + 1)
            images.publish(numpy_to_image(frame, 'rgb8', stamp_ns=stamp, frame_id='camera'))
            time.sleep(0.05)
            regs.publish(encode_registration(stamp, True, 100, 0.1, 0, plane_H_frame, np.eye(3), True, None))
            time.sleep(0.6)
            # The node's pace, not the test's: on a loaded machine a round may end after more frames
            # came, and a tile first published from 7 would never see the 14 that refresh it.
            if k == 2:
                assert listener.wait_for(lambda: int(listener.diag_value('tiles_published', SR) or 0) >= 2, 60), \
                    state()
            if k == 5:
                assert listener.wait_for(lambda: int(listener.diag_value('tiles_refreshed', SR) or 0) >= 2, 60), \
                    state()
        placements = collections.Counter(t.header.frame_id for t in listener.tiles)
        assert set(placements) == {'srmosaic_segment_0;x0=64;y0=64;width=64;height=64;factor=2',
                                   'srmosaic_segment_0;x0=128;y0=64;width=64;height=64;factor=2'}, placements
        assert all(n >= 2 for n in placements.values()), placements
        # every publication of a tile shows the ground at its stated placement (within a fraction of
        # what a 1 px misplacement costs), and the refreshed ones, made from more frames, no worse
        maes = collections.defaultdict(list)
        for tile in listener.tiles:
            place = SRTilePlacement.parse(tile.header.frame_id)
            world_H_tile = _translation(*origin) @ place.plane_H_tile()
            got = image_to_numpy(tile).astype(float)
            mae = np.abs(got - view(world_H_tile, 128, 128))[8:-8, 8:-8].mean()
            misplaced = np.abs(got - view(world_H_tile @ _translation(2.0, 0.0), 128, 128))[8:-8, 8:-8].mean()
            assert mae < 2.2 and mae < 0.75 * misplaced, (tile.header.frame_id, mae, misplaced)
            maes[tile.header.frame_id].append(mae)
        # (within 5 %: which frames a publication holds depends on DDS timing, and 5 solver
        # iterations leave a few hundredths of a grey level to chance; seen: 1.48 -> 1.53 under load)
        assert all(m[-1] <= 1.05 * m[0] for m in maes.values()), dict(maes)



@pytest.mark.skipif(not Path('/proc/self/task').is_dir(), reason='reads child processes from /proc (Linux)')
def test_ctrl_c_abandons_the_sr_tile_in_progress(ros_env):
    """SIGINT while the SR worker process is inside a tile that would take a minute (tol 0, 10000
    iterations): the node ends within seconds, cleanly, says the tile was abandoned, and leaves no
    worker. It used to wait 60 s for the tile and then, at exit, for the worker (75 s on a loaded
    machine, past the launcher's and the tests' patience)."""
    from sensor_msgs.msg import Image
    from std_msgs.msg import Float64MultiArray

    from imagery import view
    from msg_adapters import numpy_to_image
    from srmosaic_ros.nodes.common import encode_registration

    node = srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'sr_tiles.tile_size:=64',
                    '-p', 'sr.iterations:=10000', '-p', 'sr.tol:=0.0', '-p', 'sr.self_check:=0', env=ros_env)
    listener = Listener()
    try:
        assert listener.wait_for(lambda: listener.diag_value('frames_received', SR) is not None or node.poll() is not None,
                                 60) and node.poll() is None, f'no SR node: {node.communicate()[0] if node.poll() is not None else ""}'
        images = listener.publisher(Image, '/camera/image_raw')
        regs = listener.publisher(Float64MultiArray, '/srmosaic/registration')
        time.sleep(1.0)  # discovery of the two publishers
        for k in range(4):
            shift = np.array([10.0, 10.0]) + [0.37 * k % 2.0, 0.61 * k % 2.0]
            stamp = 1_000_000_000 * (k + 1)
            images.publish(numpy_to_image(view(_translation(*(np.array([300.0, 200.0]) + shift)), 200, 140, seed=k),
                                          'rgb8', stamp_ns=stamp, frame_id='camera'))
            time.sleep(0.05)
            regs.publish(encode_registration(stamp, True, 100, 0.1, 0, _translation(*shift), np.eye(3), True, None))
        workers = [w for w in _children(node.pid) if 'spawn_main' in _cmdline(w)]
        assert workers, 'no SR worker process'

        def busy_s() -> float:  # CPU seconds the workers have used (utime + stime)
            total = 0
            for w in workers:
                with contextlib.suppress(OSError), open(f'/proc/{w}/stat') as handle:
                    total += sum(int(v) for v in handle.read().rsplit(') ', 1)[1].split()[11:13])
            return total / os.sysconf('SC_CLK_TCK')

        start = busy_s()
        assert listener.wait_for(lambda: busy_s() > start + 3.0, 120), 'the worker never got to work on a tile'
        t0 = time.monotonic()
        node.send_signal(signal.SIGINT)
        out, _ = node.communicate(timeout=60)
        took = time.monotonic() - t0
    finally:
        if node.poll() is None:
            node.kill()
            node.communicate()
        listener.close()
    assert node.returncode == 0, out
    assert took < 20, (took, out)
    assert 'the tile in progress was abandoned' in out, out
    assert not listener.tiles
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(_running(w) for w in workers):
        time.sleep(0.2)
    assert not any(_running(w) for w in workers), 'the SR worker outlived its node'


def test_sr_node_removes_lens_distortion_like_the_mosaic_node(ros_env):
    """Frames through a wide barrel lens (k1 = -0.35: 5 px at 60 px from the centre) with their
    CameraInfo: the registrations refer to the undistorted pinhole frames (as the mosaic node's
    do), so the SR node must undistort the images the same way; its tiles then show the ground at
    their placement. With undistort:=false the same tiles are measurably worse."""
    import cv2
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Float64MultiArray

    from imagery import view
    from msg_adapters import image_to_numpy, intrinsics_to_camera_info, numpy_to_image
    from srmosaic_ros.core.types import CameraIntrinsics
    from srmosaic_ros.core.undistort import pinhole_of
    from srmosaic_ros.nodes.common import encode_registration
    from srmosaic_ros.live.sr import SRTilePlacement

    lens = CameraIntrinsics(200, 140, 120.0, 120.0, 99.5, 69.5, 'plumb_bob', (-0.35, 0.1, 0.0, 0.0, 0.0))
    pinhole, _, _ = pinhole_of(lens)
    margin = 40
    grid = np.stack(np.meshgrid(np.arange(200.0), np.arange(140.0)), -1).reshape(-1, 1, 2)
    src = (cv2.undistortPoints(grid, lens.K, np.array(lens.distortion), P=pinhole.K).reshape(140, 200, 2)
           + margin).astype(np.float32)
    origin = np.array([300.0, 200.0])

    def run(undistort: bool, info: CameraIntrinsics = lens) -> float:
        node = srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'live.sr_worker:=thread',
                        '-p', 'sr_tiles.tile_size:=64', '-p', 'sr_tiles.max_frames:=8', '-p', 'sr.iterations:=5',
                        '-p', 'live.sr_refresh_growth:=0.0', '-p', f'undistort:={str(undistort).lower()}', env=ros_env)
        with supervised(node=node) as sup:
            listener = sup.listener
            assert listener.wait_for(lambda: listener.diag_value('frames_received', SR) is not None, 60), 'no SR node'
            infos = listener.publisher(CameraInfo, '/camera/camera_info')
            images = listener.publisher(Image, '/camera/image_raw')
            regs = listener.publisher(Float64MultiArray, '/srmosaic/registration')
            time.sleep(1.0)
            for k in range(6):
                shift = np.array([10.0, 10.0]) + [0.37 * k % 2.0, 0.61 * k % 2.0]
                big = view(_translation(*(origin + shift - margin)), 200 + 2 * margin, 140 + 2 * margin, noise=1.0,
                           seed=k)
                frame = cv2.remap(big, src[..., 0], src[..., 1], cv2.INTER_CUBIC)   # what the lens shows
                stamp = 1_000_000_000 * (k + 1)
                infos.publish(intrinsics_to_camera_info(info, stamp_ns=stamp, frame_id='camera'))
                time.sleep(0.05)
                images.publish(numpy_to_image(frame, 'rgb8', stamp_ns=stamp, frame_id='camera'))
                time.sleep(0.05)
                regs.publish(encode_registration(stamp, True, 100, 0.1, 0, _translation(*shift), np.eye(3), True,
                                                 None))
                time.sleep(0.4)
            assert listener.wait_for(lambda: len(listener.tiles) >= 2, 30), 'no tiles'
            maes = []
            for tile in listener.tiles:
                place = SRTilePlacement.parse(tile.header.frame_id)
                truth = view(_translation(*origin) @ place.plane_H_tile(), 128, 128)
                maes.append(np.abs(image_to_numpy(tile).astype(float) - truth)[8:-8, 8:-8].mean())
            if info is not lens:
                assert listener.diag_value('camera_info_scaled', SR), 'the scaled camera info is not counted'
        return float(np.mean(maes))

    fixed, raw = run(True), run(False)
    # the CameraInfo of the same lens at twice the size (a camera mode the images are not in): scaled
    # to the images as the mosaic node does (the images used to be refused, and no tile came)
    scaled = run(True, lens.scaled_to(400, 280))
    print(f"tile MAE against the truth: undistorted {fixed:.2f}, raw {raw:.2f}, info scaled {scaled:.2f} grey levels")
    assert fixed < 2.5 and raw > 1.5 * fixed, (fixed, raw)
    assert scaled < 1.1 * fixed + 0.1, (scaled, fixed)


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
    import types

    from srmosaic_ros.nodes.mosaic_node import MosaicNode

    def taken(fps: float, hz: float, stamps_s: list[float] | None = None, jitter_s: float = 0.0) -> list[int]:
        rng = random.Random(0)
        node = types.SimpleNamespace(_rate_interval_ns=int(1e9 / hz), _next_due_ns=None)
        stamps_s = stamps_s or [k / fps for k in range(300)]
        return [k for k, t in enumerate(stamps_s) if MosaicNode._due(node, int((t + rng.uniform(-jitter_s, jitter_s)) * 1e9))]

    assert taken(30, 15) == list(range(0, 300, 2))
    assert taken(30, 15, jitter_s=0.008) == list(range(0, 300, 2))   # stamps 8 ms off either way
    assert len(taken(30, 20)) == 200 and len(taken(30, 20, jitter_s=0.008)) == 200
    assert len(taken(30, 30, jitter_s=0.003)) == 300 and len(taken(30, 45)) == 300
    # a 2 s gap in the input: the schedule starts again at the next frame, no burst after it
    stamps = [k / 30 for k in range(30)] + [3.0 + k / 30 for k in range(30)]
    got = taken(30, 10, stamps)
    first, second = [k for k in got if k < 30], [k - 30 for k in got if k >= 30]
    assert first == second == list(range(0, 30, 3)), got


@pytest.mark.parametrize(('override', 'name'), [('registration.ratio:=3.0', 'ratio'),
                                                 ('live.sr_frames_kept:=0', 'sr_frames_kept'),
                                                 ('live.sr_worker:=fork', 'sr_worker'),
                                                 ('live.sr_refresh_growth:=0.5', 'sr_refresh_growth'),
                                                 # an output folder that cannot be written: at start, not at shutdown
                                                 ('live.output_dir:=/proc/srmosaic-out', 'live.output_dir /proc'),
                                                 # a params file beat -p: these were silently ignored
                                                 ('registration.max_features:=lots', "'registration.max_features' to 'lots'"),
                                                 ('georef.enabled:="false"', "'georef.enabled' to 'false' of type 'STRING'")])
def test_invalid_parameter_refused_at_start(ros_env, override, name):
    graph = srmosaic('launch', '--ros-args', '-p', override, env=ros_env)
    out, _ = graph.communicate(timeout=60)
    assert graph.returncode == 2, out
    assert name in out


def test_sr_placement_and_live_planning_without_ros():
    """The ROS-free side of the SR node: placement text, the bounded frame store, tile planning."""
    from srmosaic_ros.core.sr.scheduler import SRTileConfig
    from srmosaic_ros.errors import SrMosaicError
    from srmosaic_ros.live.sr import LiveFrameStore, SRTilePlacement, plan_live_tiles

    place = SRTilePlacement(2, -128, 256, 128, 64, 3)
    assert SRTilePlacement.parse(place.frame_id()) == place
    np.testing.assert_allclose(place.plane_H_tile() @ [0, 0, 1], [-128 + 0.5 / 3 - 0.5, 256 + 0.5 / 3 - 0.5, 1])
    with pytest.raises(SrMosaicError, match='not an SR tile placement'):
        SRTilePlacement.parse('srmosaic_mosaic')

    store = LiveFrameStore(pending=3, kept=5)
    for k in range(4):
        store.add_image(k, f'image {k}')
    assert store.pending == 3  # the oldest went
    assert not store.add_registration(0, 0, np.eye(3)) and store.missed == 1
    assert store.missed_dropped == 1  # dropped for room: the store is too small for the registrations' delay
    assert not store.add_registration(9, 0, np.eye(3)) and (store.missed, store.missed_dropped) == (2, 1)  # never came
    assert not store.add_registration(1, -1, None)  # not painted: dropped
    for k in range(2, 10):
        store.add_image(k, f'image {k}')
        store.add_registration(k, 0, _translation(-300.0 + 10 * k, -200.0))  # negative plane coordinates
    assert [f.stamp_ns for f in store.registered()] == [5, 6, 7, 8, 9]
    frames = store.registered()
    cfg = SRTileConfig(tile_size=64, min_frames=3, max_frames=4)
    plans = plan_live_tiles(frames, {f.stamp_ns: (320, 240) for f in frames}, cfg)
    assert plans
    for plan, used in plans:
        assert plan.x0 % 64 == 0 and plan.y0 % 64 == 0 and 3 <= len(used) <= 4
        for f in used:  # every chosen frame sees the whole tile
            corners = np.array([[plan.x0, plan.y0, 1], [plan.x0 + 63, plan.y0 + 63, 1]], float)
            p = np.linalg.solve(f.seg_H_frame, corners.T)
            assert np.all(p[0] >= 0) and np.all(p[0] <= 319) and np.all(p[1] >= 0) and np.all(p[1] <= 239)
    done = {(0, p.x0, p.y0) for p, _ in plans}
    assert plan_live_tiles(frames, {f.stamp_ns: (320, 240) for f in frames}, cfg, done) == []
    store.add_image(20, 'other scene')
    store.add_registration(20, 1, np.eye(3))  # a new segment: the older one's frames go
    assert [f.stamp_ns for f in store.registered()] == [20]


def test_sr_worker_process_gives_the_in_process_tile():
    """live.sr_worker process: a tile reconstructed in a spawned worker process (the SR node's
    default) is the tile reconstructed in this process; an SRError crosses the process boundary."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from srmosaic_ros.core.sr import SRConfig
    from srmosaic_ros.core.sr.scheduler import TilePlan
    from srmosaic_ros.live.sr import (SRError, init_sr_worker_process, reconstruct_live_tile,
                                      reconstruct_live_tile_image)

    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.uniform(0, 255, (80, 100)).astype(np.float32), (0, 0), 1.5)
    images = [np.clip(np.roll(base, (k, 2 * k), (0, 1)) + rng.normal(0, 2, base.shape), 0, 255).astype(np.uint8)
              for k in range(3)]
    hs = [_translation(10.0 - 2 * k, 20.0 - k) for k in range(3)]  # the rolls undone: one picture
    plan = TilePlan(32, 32, 32, 32, (0, 1, 2), 3)
    config = SRConfig(iterations=3)
    here, place_here, _ = reconstruct_live_tile(plan, images, hs, 2, config, 4)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('spawn'), initializer=init_sr_worker_process,
                             initargs=(1,)) as pool:
        assert pool.submit(os.getpid).result() != os.getpid()
        there, place_there, stop = pool.submit(reconstruct_live_tile_image, plan, images, hs, 2, config, 4).result()
        far = TilePlan(5000, 5000, 32, 32, (0, 1, 2), 3)
        with pytest.raises(SRError):
            pool.submit(reconstruct_live_tile_image, far, images, hs, 2, config, 4).result()
    assert place_there == place_here and isinstance(stop, str) and stop
    assert there.shape == here.shape == (64, 64)
    assert np.abs(there.astype(int) - here.astype(int)).max() <= 1


def test_command_line_overrides_beat_the_parameter_files(tmp_path):
    """rcl lets a --params-file beat a -p override; the launcher moves -p into a file given last."""
    import rclpy
    from rclpy.node import Node

    from srmosaic_ros.nodes.launcher import overrides_last, ros_args

    args = ['srmosaic', *ros_args([]), *overrides_last(['--ros-args', '-p', 'registration.max_features:=500',
                                                        '-r', '/fix:=/gps'], tmp_path)]
    assert args[-2] == '--params-file' and '-r' in args and '-p' not in args[4:]
    context = rclpy.Context()
    rclpy.init(args=args, context=context)
    try:
        node = Node('srmosaic_mosaic', context=context)
        assert node.declare_parameter('registration.max_features', 1000).value == 500
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


LIVE_HD_CHECK = """
import json, sys, rclpy
from srmosaic_ros.nodes.mosaic_node import MosaicNode
rclpy.init(args=['--ros-args', '--params-file', sys.argv[1]])
node = MosaicNode()
print(json.dumps({'registration_width': node.config.registration.max_width, 'mosaic_width': node.config.mosaic.max_width,
                  'track_frames': node.config.registration.track_frames, 'queue': node._queue.maxlen,
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
