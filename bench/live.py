"""Live graph benchmark: frames per second through DDS and end-to-end latency.

Starts `srmosaic launch` (registration + mosaic node) in a child process, publishes 640x480 frames
rendered by the simulator at a fixed rate on /camera/image_raw (raw sensor_msgs/Image, header stamp
= publish time), and listens to /srmosaic/registration. Prints frames offered / processed /
dropped, processed frames per second, and latency from image publish to the registration result
(median and p95).

    .venv/bin/python bench/live.py [--fps 25] [--seconds 20] [--compressed]
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--fps', type=float, default=25.0)
    ap.add_argument('--seconds', type=float, default=20.0)
    ap.add_argument('--frames', type=int, default=100, help='distinct simulated frames (looped)')
    ap.add_argument('--compressed', action='store_true', help='publish JPEG CompressedImage instead of raw')
    args = ap.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(200 + os.getpid() % 30))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

    from srmosaic_ros.sim import SimConfig, simulate

    print(f'rendering {args.frames} frames ...', flush=True)
    flight = simulate(SimConfig(frames=args.frames, rate_hz=args.fps, speed_m_s=10.0 * args.fps / 4.0 / 2.0))
    images = [f.image for f in flight.frames]

    graph = subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.cli', 'launch', '--ros-args',
                              '-p', 'live.preview_period_s:=1.0'], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import CompressedImage, Image
    from std_msgs.msg import Float64MultiArray

    from msg_adapters import numpy_to_compressed, numpy_to_image

    rclpy.init()
    node = rclpy.create_node('srmosaic_bench_live')
    topic, mtype = ('/camera/image_raw/compressed', CompressedImage) if args.compressed else ('/camera/image_raw', Image)
    pub = node.create_publisher(mtype, topic, 10)
    latencies: list[float] = []
    done_at: list[float] = []

    def on_reg(msg: Float64MultiArray) -> None:
        stamp_ns = int(msg.data[0]) * 1_000_000_000 + int(msg.data[1])
        now = time.time_ns()
        latencies.append((now - stamp_ns) * 1e-6)
        done_at.append(time.monotonic())

    node.create_subscription(Float64MultiArray, '/srmosaic/registration', on_reg, 1000)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = False

    def spin() -> None:
        while not stop:
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(1.0)
    print(f'publishing {args.fps} frames/s for {args.seconds} s on {topic} ...', flush=True)
    period = 1.0 / args.fps
    t0 = time.monotonic()
    offered = 0
    while time.monotonic() - t0 < args.seconds:
        img = images[offered % len(images)]
        stamp = time.time_ns()
        msg = (numpy_to_compressed(img, stamp_ns=stamp) if args.compressed
               else numpy_to_image(img, 'rgb8', stamp_ns=stamp))
        pub.publish(msg)
        offered += 1
        next_t = t0 + offered * period
        time.sleep(max(0.0, next_t - time.monotonic()))
    time.sleep(3.0)
    stop = True
    spinner.join()
    graph.send_signal(signal.SIGINT)
    graph.wait(timeout=60)
    node.destroy_node()
    rclpy.try_shutdown()
    processed = len(latencies)
    span = (done_at[-1] - done_at[0]) if len(done_at) > 1 else float('nan')
    lat = np.array(latencies) if latencies else np.array([np.nan])
    print(f'offered {offered} frames at {args.fps} fps; processed {processed}; dropped {offered - processed} '
          f'({100.0 * (offered - processed) / max(offered, 1):.1f}%)')
    print(f'processed frames per second: {(processed - 1) / span:.2f}')
    print(f'latency publish -> registration: median {np.median(lat):.1f} ms, p95 {np.percentile(lat, 95):.1f} ms')
    return 0


if __name__ == '__main__':
    sys.exit(main())
