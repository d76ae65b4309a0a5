"""What the live-graph tests share: starting `srmosaic` commands, a listener of the graph's outputs,
checks of SR tiles against the truth, supervised processes and bag playback into a graph.

Each test uses its own ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (conftest.ros_env).
Waits are event-driven (a condition polled with a generous timeout), so a loaded machine is slower, not red.
"""
from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
from ros_graph import GraphListener, supervised_processes

from repo_paths import REPO

ROOT = REPO
DEMO = ROOT / 'bags' / 'demo'

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


def translation(dx: float, dy: float) -> np.ndarray:
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
            ref = reference_render(world, world_H_plane @ place.plane_H_tile() @ translation(dx, dy),
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


def children_of(pid: int) -> list[int]:
    out: list[int] = []
    for task in os.listdir(f'/proc/{pid}/task'):
        with contextlib.suppress(OSError), open(f'/proc/{pid}/task/{task}/children') as handle:
            out += [int(c) for c in handle.read().split()]
    return out


def cmdline_of(pid: int) -> str:
    try:
        with open(f'/proc/{pid}/cmdline') as handle:
            return handle.read().replace('\0', ' ')
    except OSError:
        return ''


def is_running(pid: int) -> bool:
    """The process exists and has not exited (a zombie not reaped by a container's PID 1 has)."""
    try:
        with open(f'/proc/{pid}/stat') as handle:
            return handle.read().rsplit(') ', 1)[1][0] != 'Z'
    except OSError:
        return False
