"""Live graph benchmark: frames per second through DDS and end-to-end latency, per graph layout.

For each graph layout it starts `srmosaic launch` in a child process, publishes 640x480 frames (--width, --height)
rendered by the simulator at a fixed rate on /camera/image_raw (raw sensor_msgs/Image, header stamp
= publish time; `--compressed`: JPEG on .../compressed), with the simulated /fix and /imu/data
re-stamped on the same clock, and /camera/camera_info with every image, so that the mosaic node
georeferences the mosaic (poses, homography updates, drift control) as in a real graph
(`--telemetry none` leaves them out: frames then wait for
SYNC_HOLD_FRAMES newer frames before processing, which adds that many frame periods of latency),
and listens to /srmosaic/registration (one message per processed frame), /srmosaic/pose and
/srmosaic/sr_tile. Prints, per layout: frames offered / processed / dropped, processed frames per
second, latency from image publish to the frame's fused pose on /srmosaic/pose (registered and
placed: what a live consumer gets first) and to its registration result (published when the frame is
painted, mosaic.revisit_spread_frames frames later by design), median and p95, poses and SR tiles,
and the bytes per second of every output topic and of the camera images (what a link between an
onboard mosaic node and a ground station would carry; docs/results.md, "Live graph").

Layouts (`--graph`, repeatable; default all three):
  mosaic    the mosaic node alone (registration + mosaic + georeferencing filter), one process
  combined  `srmosaic launch`: mosaic, georef (idle) and sr nodes in one process
  split     mosaic | georef (live.georef_standalone) | sr, three processes (launch description)

    .venv/bin/python bench/live.py [--fps 25] [--seconds 20] [--graph split] [--compressed] [--width 1280 --height 720]
        [--params-file params/live_hd.yaml] [--flight-cache /tmp/flight.pkl] [--plot latency.png]

`--map` (BENCH_MAP_CLIENT=0: without the client): each layout runs twice in the same invocation, without and with the live web map: a
`srmosaic map-server` process beside the graph (the mosaic node then sends its changed tiles on
/srmosaic/map_tile) and a client in this process that reads /status.json and the XYZ tiles under the
aircraft every half second, as an open page does; prints the ratio of the mosaic node's frame rate
and processing time with the map to without (the goal: within 5 %). Offer more frames than the node
processes (--fps) so that the frame rate is the node's own.

The mosaic node's own diagnostics are printed too: frames it received (the rest were lost by
best-effort DDS before reaching it), frames its bounded queue dropped, and its median processing
time per frame. BENCH_PREVIEW_PERIOD_S (default 1.0) sets live.preview_period_s; BENCH_ROS_PARAMS adds
space-separated `name:=value` parameters to every node. Unless --no-fastdds-profile,
every process uses params/fastdds_large_images.xml (see docs/guide/live.md, "Raw images on one host").
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import math
import os
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

LAYOUTS = ('mosaic', 'combined', 'split')
#: The graph's output topics whose bytes per second are measured (message type, topic).
OUTPUTS = (('sensor_msgs/Image', '/srmosaic/mosaic_preview'),
           ('sensor_msgs/CompressedImage', '/srmosaic/mosaic_preview/compressed'),
           ('std_msgs/Float64MultiArray', '/srmosaic/registration'),
           ('geometry_msgs/PoseWithCovarianceStamped', '/srmosaic/pose'), ('sensor_msgs/NavSatFix', '/srmosaic/fix'),
           ('nav_msgs/Odometry', '/srmosaic/odom'),
           ('std_msgs/String', '/srmosaic/raster'), ('sensor_msgs/Image', '/srmosaic/sr_tile'),
           ('diagnostic_msgs/DiagnosticArray', '/srmosaic/diagnostics'))


def _message_type(name: str) -> type:
    package, cls = name.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), cls)


def graph_command(layout: str, workdir: Path, params_file: Path | None = None) -> list[str]:
    base = [sys.executable, '-m', 'srmosaic_ros.cli']
    ros = ['--ros-args']
    if params_file is not None:  # before the -p below, which override it (rcl: the last one wins)
        ros += ['--params-file', str(params_file)]
    ros += ['-p', f'live.preview_period_s:={float(os.environ.get("BENCH_PREVIEW_PERIOD_S", "1.0"))}']
    for assignment in os.environ.get('BENCH_ROS_PARAMS', '').split():   # e.g. "live.queue_size:=4"
        ros += ['-p', assignment]
    if layout == 'mosaic':
        return [*base, 'node', 'mosaic', *ros]
    if layout == 'combined':
        return [*base, 'launch', *ros]
    description = workdir / 'split.yaml'
    description.write_text('processes:\n  - {name: onboard, nodes: [mosaic]}\n  - {name: georef, nodes: [georef]}\n'
                           '  - {name: ground, nodes: [sr]}\n')
    return [*base, 'launch', str(description), *ros, '-p', 'live.georef_standalone:=true']


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _browse(url: str, stop: threading.Event, served: dict[str, int]) -> None:
    """What an open page asks of the map server: the status and the tiles under the aircraft, twice a second."""
    import json
    import urllib.error
    import urllib.request

    import morecantile

    tms = morecantile.tms.get('WebMercatorQuad')
    while not stop.wait(0.5):
        try:
            with urllib.request.urlopen(url + 'status.json', timeout=5) as r:
                status = json.loads(r.read())
            served['status'] += 1
            pose = status.get('pose')
            if not pose or not status.get('maxzoom'):
                continue
            centre = tms.tile(pose['lon'], pose['lat'], status['maxzoom'])
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    try:
                        with urllib.request.urlopen(url + f'tiles/{centre.z}/{centre.x + dx}/{centre.y + dy}.png', timeout=5) as r:
                            served['tile_bytes'] += len(r.read())
                            served['tiles'] += 1
                    except urllib.error.HTTPError:
                        served['empty'] += 1
        except (urllib.error.URLError, OSError, ValueError):
            served['errors'] += 1


def run_layout(layout: str, args: argparse.Namespace, flight, domain: int, *, with_map: bool = False) -> dict:
    import rclpy
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu, NavSatFix
    from std_msgs.msg import Float64MultiArray

    from srmosaic_ros.nodes.mosaic_node import IDLE_PAINT_S

    from msg_adapters import fix_to_navsat, intrinsics_to_camera_info, numpy_to_compressed, numpy_to_image, sample_to_imu

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    workdir = Path(tempfile.mkdtemp(prefix='srmosaic_bench_live_'))
    graph = subprocess.Popen(graph_command(layout, workdir, args.params_file), env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    map_server = browser = None
    browse_stop = threading.Event()
    served = {'status': 0, 'tiles': 0, 'tile_bytes': 0, 'empty': 0, 'errors': 0}
    if with_map:  # the live web map beside the graph, in its own process, and a page's requests
        port = _free_port()
        # BENCH_MAP_SERVER=0: no map server, only this process's subscription to the tiles (their cost in the node)
        command = [sys.executable, '-m', 'srmosaic_ros.cli', 'map-server', '--port', str(port)]
        map_server = None if os.environ.get('BENCH_MAP_SERVER', '1') == '0' else subprocess.Popen(command,
                                      env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if os.environ.get('BENCH_MAP_CLIENT', '1') != '0':  # 0: the map server alone, no page asking it
            browser = threading.Thread(target=_browse, args=(f'http://127.0.0.1:{port}/', browse_stop, served), daemon=True)
            browser.start()
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('srmosaic_bench_live', context=context)
    topic, mtype = ('/camera/image_raw/compressed', CompressedImage) if args.compressed else ('/camera/image_raw', Image)
    pub = node.create_publisher(mtype, topic, qos_profile_sensor_data)
    pub_fix = node.create_publisher(NavSatFix, '/fix', qos_profile_sensor_data)
    pub_imu = node.create_publisher(Imu, '/imu/data', qos_profile_sensor_data)
    pub_info = node.create_publisher(CameraInfo, '/camera/camera_info', qos_profile_sensor_data)
    latencies: list[float] = []
    pose_latencies: dict[int, float] = {}  # frame stamp -> ms from publish to its first fused pose
    done_at: list[float] = []
    pose_done_at: list[float] = []  # the rate is taken from the poses when there are (registrations come 30 frames late, the last at once)
    counts = {'poses': 0, 'tiles': 0}

    seen: set[int] = set()

    def on_reg(msg: Float64MultiArray) -> None:
        stamp_ns = int(msg.data[0]) * 1_000_000_000 + int(msg.data[1])
        if stamp_ns in seen:
            # A frame that failed and later started a new segment (with --frames shorter than the
            # run, the flight loops back to its first frame) is published again, painted: count it once.
            return
        seen.add(stamp_ns)
        latencies.append((time.time_ns() - stamp_ns) * 1e-6)
        done_at.append(time.monotonic())

    node.create_subscription(Float64MultiArray, '/srmosaic/registration', on_reg, 1000)
    from diagnostic_msgs.msg import DiagnosticArray

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if 'registration and mosaic' in status.name:
                for kv in status.values:
                    if kv.key in ('frames_received', 'dropped_frames', 'frames_skipped_by_rate', 'processing_ms_median'):
                        counts[kv.key] = kv.value

    node.create_subscription(DiagnosticArray, '/srmosaic/diagnostics', on_diag, 100)

    def on_pose(msg: PoseWithCovarianceStamped) -> None:
        counts['poses'] += 1
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if stamp_ns not in pose_latencies:
            pose_latencies[stamp_ns] = (time.time_ns() - stamp_ns) * 1e-6
            pose_done_at.append(time.monotonic())

    node.create_subscription(PoseWithCovarianceStamped, '/srmosaic/pose', on_pose, 1000)
    node.create_subscription(Image, '/srmosaic/sr_tile', lambda _m: counts.__setitem__('tiles', counts['tiles'] + 1),
                             100)
    # What would cross an onboard -> ground link: the serialized bytes of every output topic
    # (raw subscriptions: the CDR as DDS carries it, without deserializing).
    link: dict[str, list[int]] = {}
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    outputs = OUTPUTS + ((('sensor_msgs/CompressedImage', '/srmosaic/map_tile'),) if with_map else ())
    for mtype_out, name in outputs:  # (the tiles only with the map: a subscriber makes the node send them)
        link[name] = [0, 0]
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        node.create_subscription(_message_type(mtype_out), name,
                                 lambda b, n=name: (link[n].__setitem__(0, link[n][0] + 1),
                                                    link[n].__setitem__(1, link[n][1] + len(b))), qos, raw=True)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stop = False

    def spin() -> None:
        while not stop:
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    deadline = time.monotonic() + 90
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(2.0)
    # Telemetry of the simulated flight, on the frames' clock: (offset from frame 0 in ns, message maker).
    t_first = flight.frames[0].stamp_ns
    loop_ns = flight.frames[-1].stamp_ns - t_first + int(1e9 / args.fps)
    telemetry = [] if args.telemetry == 'none' else sorted(
        [(f.stamp_ns - t_first, 'fix', f) for f in flight.fixes] + [(m.stamp_ns - t_first, 'imu', m) for m in flight.imus],
        key=lambda t: t[0])
    # Every distinct frame is serialized once; each publish patches the header stamp into the
    # CDR bytes (a camera driver in C++ does not pay rclpy's ~30 ms per 640x480 RGB frame, which
    # would otherwise take most of one of this machine's two cores from the graph under test).
    serialized = [serialize_message(numpy_to_compressed(f.image, stamp_ns=0) if args.compressed
                                    else numpy_to_image(f.image, 'rgb8', stamp_ns=0)) for f in flight.frames]
    period = 1.0 / args.fps
    t0_wall = time.monotonic()
    t0_ns = time.time_ns()
    offered = 0
    published_ns: list[int] = []  # each image's header stamp (its publish time)
    image_bytes = 0
    ti = 0
    loops = 0
    while time.monotonic() - t0_wall < args.seconds:
        k = offered % len(flight.frames)
        if k == 0 and offered:
            loops += 1
            ti = 0
        stamp = t0_ns + loops * loop_ns + flight.frames[k].stamp_ns - t_first
        while ti < len(telemetry) and t0_ns + loops * loop_ns + telemetry[ti][0] <= stamp + int(period * 1e9):
            off, kind, item = telemetry[ti]
            t_ns = t0_ns + loops * loop_ns + off
            if kind == 'fix':
                pub_fix.publish(fix_to_navsat(dataclasses.replace(item, stamp_ns=t_ns)))
            else:
                pub_imu.publish(sample_to_imu(dataclasses.replace(item, stamp_ns=t_ns)))
            ti += 1
        now_ns = time.time_ns()
        if args.telemetry != 'none':  # as a camera driver does: CameraInfo with every image
            pub_info.publish(intrinsics_to_camera_info(flight.camera, stamp_ns=now_ns))
        pub.publish(_stamped(serialized[k], now_ns))
        published_ns.append(now_ns)
        image_bytes += len(serialized[k])
        offered += 1
        time.sleep(max(0.0, t0_wall + offered * period - time.monotonic()))
    published_s = time.monotonic() - t0_wall
    # The last mosaic.revisit_spread_frames frames are painted (and their registration published) once
    # the input has paused IDLE_PAINT_S: wait for them, they are processed frames.
    time.sleep(IDLE_PAINT_S + 3.0)
    stop = True
    spinner.join()
    browse_stop.set()
    if browser is not None:
        browser.join(timeout=10)
    if map_server is not None:
        map_server.send_signal(signal.SIGINT)
        try:
            map_server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            map_server.kill()
    graph.send_signal(signal.SIGINT)
    try:
        graph.wait(timeout=60)
    except subprocess.TimeoutExpired:
        graph.kill()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    processed = len(latencies)
    link_rates = {name: (n, b) for name, (n, b) in link.items()}  # messages, bytes over the run
    link_rates[topic + ' (in)'] = (offered, image_bytes)
    rate_at = pose_done_at if len(pose_done_at) > 1 else done_at
    span = (rate_at[-1] - rate_at[0]) if len(rate_at) > 1 else float('nan')
    lat = np.array(latencies) if latencies else np.array([np.nan])
    pose_lat = np.array(list(pose_latencies.values())) if pose_latencies else np.array([np.nan])
    return {'layout': layout + ('+map' if with_map else ''), 'offered': offered, 'served': served, 'processed': processed, 't0_ns': t0_ns,
            'pose_latencies': pose_latencies, 'published_stamps': published_ns,
            'pose_lat_median_ms': float(np.median(pose_lat)), 'pose_lat_p95_ms': float(np.percentile(pose_lat, 95)),
            'fps': (len(rate_at) - 1) / span if len(rate_at) > 1 else float('nan'),
            'lat_median_ms': float(np.median(lat)), 'lat_p95_ms': float(np.percentile(lat, 95)), 'link': link_rates,
            'seconds': published_s,
            **counts}


def rendered_flight(config, cache: Path | None):
    """The simulated flight of ``config``; with ``cache``, read from that pickle when it holds this
    config's flight, else rendered and written there (unless the file holds another flight: that
    one, minutes to render, is kept)."""
    import pickle

    from srmosaic_ros.sim import simulate

    keep = False
    if cache is not None and cache.is_file():
        with cache.open('rb') as fh:
            cached_config, flight = pickle.load(fh)  # the bench's own file
        if cached_config == config:
            return flight
        print(f'{cache} holds another flight (kept): rendering this one without caching it; give another '
              '--flight-cache to cache it', flush=True)
        keep = True
    print(f'rendering {config.frames} frames ...', flush=True)
    flight = simulate(config)
    if cache is not None and not keep:
        with cache.open('wb') as fh:
            pickle.dump((config, flight), fh, protocol=pickle.HIGHEST_PROTOCOL)
    return flight


def _stamped(cdr: bytes, stamp_ns: int) -> bytes:
    """Serialized Image / CompressedImage with header.stamp set (CDR: 4-byte encapsulation header,
    then stamp.sec int32 and stamp.nanosec uint32, little-endian)."""
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return cdr[:4] + struct.pack('<iI', sec, nsec) + cdr[12:]


def plot_latency(results: list[dict], path: Path) -> None:
    """One panel per layout: latency (ms) from publish to the frame's first pose against its publish
    time (s into the run); frames that never got a pose as red ticks below the axis."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), 1, figsize=(10, 3.2 * len(results)), squeeze=False)
    for ax, r in zip(axes[:, 0], results):
        t0 = r['t0_ns']
        got = r['pose_latencies']
        t = np.array([(s - t0) * 1e-9 for s in got])
        ax.plot(t, list(got.values()), '.', ms=2, label='latency to the pose')
        lost = [(s - t0) * 1e-9 for s in r['published_stamps'] if s not in got]
        if lost:
            ax.plot(lost, np.zeros(len(lost)), '|', color='red', ms=10, label=f'{len(lost)} frames without a pose')
        ax.set_title(f"{r['layout']}: {r['processed']} of {r['offered']} frames processed, pose latency median "
                     f"{r['pose_lat_median_ms']:.0f} ms, p95 {r['pose_lat_p95_ms']:.0f} ms")
        ax.set_xlabel('published at (s into the run)')
        ax.set_ylabel('ms')
        ax.legend(loc='upper left', fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def add_flight_arguments(ap: argparse.ArgumentParser) -> None:
    """The simulated flight's options (this bench's and bench/live_replay.py's)."""
    ap.add_argument('--fps', type=float, default=25.0)
    ap.add_argument('--seconds', type=float, default=20.0)
    ap.add_argument('--frames', type=int, default=0,
                    help='distinct simulated frames, looped when the run is longer (default 0: the whole run, '
                         'fps x seconds: no loop; each loop jumps the aircraft back to its start)')
    ap.add_argument('--trajectory', choices=('auto', 'line', 'lawnmower'), default='auto',
                    help='auto (default): a line when it fits the 400 m world (up to 250 m), else a lawnmower of '
                         '4 legs of 150 m, 50 m apart (side overlap: the return legs revisit ground)')
    ap.add_argument('--speed', type=float, default=12.5,
                    help='ground speed, m/s (default 12.5: 0.5 m, about 4 px, per frame at 25 fps and 100 m)')
    ap.add_argument('--width', type=int, default=640, help='frame width, px (default 640)')
    ap.add_argument('--height', type=int, default=480, help='frame height, px (default 480)')
    ap.add_argument('--flight-cache', type=Path, default=None,
                    help='pickle of the rendered flight: written when missing, read when present (a 60 s '
                         '720p30 flight: 5 GB on disk, 4 minutes of rendering saved per run); it must have been '
                         'rendered with the same flight options (else it is rendered again)')


def flight_from_arguments(args: argparse.Namespace):
    """The simulated flight of add_flight_arguments' options (rendered, or read from --flight-cache)."""
    from srmosaic_ros.sim import SimConfig

    if args.frames <= 0:
        args.frames = int(math.ceil(args.fps * args.seconds)) + 1
    trajectory = args.trajectory
    if trajectory == 'auto':
        trajectory = 'line' if args.speed * args.frames / args.fps <= 250.0 else 'lawnmower'
    shape = {'trajectory': 'lawnmower', 'legs': 4, 'leg_length_m': 150.0, 'leg_spacing_m': 50.0} if trajectory == 'lawnmower' else {}
    return rendered_flight(SimConfig(frames=args.frames, rate_hz=args.fps, speed_m_s=args.speed, width=args.width,
                                     height=args.height, **shape), args.flight_cache)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_flight_arguments(ap)
    ap.add_argument('--compressed', action='store_true', help='publish JPEG CompressedImage instead of raw')
    ap.add_argument('--graph', action='append', choices=LAYOUTS, help='layouts to run (default: all)')
    ap.add_argument('--telemetry', choices=('sim', 'none'), default='sim')
    ap.add_argument('--params-file', type=Path, default=None,
                    help='a parameter file for every node (e.g. params/live_hd.yaml), as `--ros-args --params-file`')
    ap.add_argument('--plot', type=Path, default=None,
                    help='PNG: per layout, each frame\'s latency from publish to its pose against the time it was '
                         'published, frames never posed marked below (where in the flight the node fell behind)')
    ap.add_argument('--map', action='store_true',
                    help='run each layout without and with the live web map (map-server and a page\'s requests); '
                         'print the frame-rate ratio')
    ap.add_argument('--repeat', type=int, default=1,
                    help='run the layouts this many times, one after the other (with --map: pairs without and with the '
                         'map, so that a host whose load drifts is seen in the spread of the ratios)')
    ap.add_argument('--no-fastdds-profile', action='store_true',
                    help='leave Fast DDS at its defaults (512 KiB shared-memory segments: raw frames go over '
                         'fragmented UDP and about half are lost at 25 fps) instead of params/fastdds_large_images.xml')
    args = ap.parse_args()
    if not args.no_fastdds_profile:
        # Before rclpy loads Fast DDS in this process; the graph's child processes inherit it.
        profile = str(Path(__file__).resolve().parent.parent / 'params' / 'fastdds_large_images.xml')
        os.environ.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', profile)
        os.environ.setdefault('FASTDDS_DEFAULT_PROFILES_FILE', profile)

    if args.params_file is not None and not args.params_file.is_file():
        ap.error(f'--params-file {args.params_file}: no such file')
    flight = flight_from_arguments(args)
    results = []
    runs = [(layout, with_map) for _ in range(args.repeat) for layout in (args.graph or LAYOUTS)
            for with_map in (((True, False) if os.environ.get('BENCH_MAP_FIRST') == '1' else (False, True)) if args.map else (False,))]
    for i, (layout, with_map) in enumerate(runs):
        print(f"{layout}{' with the map' if with_map else ''}: publishing {args.fps} frames/s for {args.seconds} s ...",
              flush=True)
        r = run_layout(layout, args, flight, 200 + (os.getpid() + i) % 30, with_map=with_map)
        results.append(r)
        if with_map:
            sv = r['served']
            print(f"  map server: {sv['status']} status.json, {sv['tiles']} tiles ({sv['tile_bytes'] / 1e3:.0f} kB), "
                  f"{sv['empty']} empty (404), {sv['errors']} failed requests", flush=True)
        print(f"{layout}: offered {r['offered']}, processed {r['processed']}, not processed {r['offered'] - r['processed']} "
              f"({100.0 * (r['offered'] - r['processed']) / max(r['offered'], 1):.1f}%); "
              f"{r['fps']:.2f} frames/s; latency publish -> registration median {r['lat_median_ms']:.0f} ms, "
              f"p95 {r['lat_p95_ms']:.0f} ms (to its pose: {r['pose_lat_median_ms']:.0f} / {r['pose_lat_p95_ms']:.0f} ms); "
              f"{r['poses']} poses, {r['tiles']} SR tiles; mosaic node diagnostics: "
              f"received {r.get('frames_received', '?')}, dropped by its queue {r.get('dropped_frames', '?')}, "
              f"skipped by live.max_rate_hz {r.get('frames_skipped_by_rate', '?')}, "
              f"processing median {r.get('processing_ms_median', '?')} ms", flush=True)
    for r in results:
        print(f"\n{r['layout']}: bytes on each topic over the {r['seconds']:.1f} s of the run (what an onboard -> "
              'ground link would carry)')
        for name, (n, size) in r['link'].items():
            print(f"  {name:<42} {n:>6} msgs {size / max(n, 1) / 1e3:>9.1f} kB/msg {size / r['seconds'] / 1e3:>10.1f} kB/s")
    if args.plot is not None:
        plot_latency(results, args.plot)
        print(f'latency plot -> {args.plot}')
    # latency to the pose (what a live consumer gets first) and to the registration (published when
    # the frame is painted, mosaic.revisit_spread_frames frames later by design); proc_med_ms, the
    # mosaic node's own processing median per frame, says how fast the host was during the run (the
    # same code: 13-15 ms at 720p with live_hd on a quiet hour of the 2-core machine, 25-28 on a busy one)
    print('\nlayout     offered processed   fps pose_med_ms pose_p95_ms reg_med_ms reg_p95_ms poses tiles proc_med_ms')
    for r in results:
        print(f"{r['layout']:<10} {r['offered']:>7} {r['processed']:>9} {r['fps']:>5.2f} {r['pose_lat_median_ms']:>11.0f} "
              f"{r['pose_lat_p95_ms']:>11.0f} {r['lat_median_ms']:>10.0f} {r['lat_p95_ms']:>10.0f} {r['poses']:>5} "
              f"{r['tiles']:>5} {r.get('processing_ms_median', 'n/a'):>11}")
    if args.map:
        print('\nwith the live map / without (same run): frames per second, mosaic node processing median per frame')
        pairs = zip(results[::2], results[1::2], strict=True)  # each pair: without, then with the map (BENCH_MAP_FIRST=1: swapped)
        for a, b in ((b, a) if a['layout'].endswith('+map') else (a, b) for a, b in pairs):
            proc = float(b.get('processing_ms_median', 'nan')) / float(a.get('processing_ms_median', 'nan'))
            print(f"{a['layout']:<10} fps {b['fps']:.2f} / {a['fps']:.2f} = {b['fps'] / a['fps']:.3f}; "
                  f"processing {proc:.3f}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
