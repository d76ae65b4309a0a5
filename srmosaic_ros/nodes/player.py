"""`srmosaic play BAG` (or `ros2 run srmosaic_ros player BAG`): publish a bag's messages on their
topics, in real time or faster.

The replacement of `ros2 bag play` for this environment. Messages are published as the serialized
bytes stored in the bag (ROS 1 bags are converted to CDR), on publishers of the recorded types,
paced by their log times divided by `--rate`. The recorded names are published relative, under
the player's namespace: `--ros-args -r __ns:=/uav1` plays /camera/image_raw on /uav1/camera/image_raw.
"""
from __future__ import annotations

import importlib
import time
from pathlib import Path

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy, DurabilityPolicy

from ..errors import BagError
from ..io.bags import inspect_bag, iter_raw
from .runner import init_rclpy

__all__ = ['play_bag']


def _message_class(msgtype: str) -> type:
    """'sensor_msgs/msg/Image' -> sensor_msgs.msg.Image (the rclpy class)."""
    pkg, _, name = msgtype.split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError):
        msg = f'message type {msgtype} is not available to rclpy here; exclude its topic with --topics.'
        raise BagError(msg) from None


def _wait_for_subscribers(node: Node, publishers: dict, timeout_s: float, counts: dict[str, int] | None = None) -> None:
    """Wait until every publisher has its topic's count of subscribers in ``counts`` (1 for a topic
    not named) or timeout_s passed, so the first messages are not lost: where several nodes read a
    topic and start one after another, the first to subscribe is not enough."""
    need = {t: (counts or {}).get(t, 1) for t in publishers}
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if all(p.get_subscription_count() >= need[t] for t, p in publishers.items()):
            time.sleep(0.5)  # matching completes on the subscriber side too
            return
        time.sleep(0.05)
    waiting = [t for t, p in publishers.items() if p.get_subscription_count() < need[t]]
    if waiting:
        node.get_logger().info(f'fewer subscribers than asked yet on {waiting}; playing anyway')


def play_bag(path: Path, *, rate: float = 1.0, topics: list[str] | None = None, start_delay_s: float = 1.0,
             loop: bool = False, remap: dict[str, str] | None = None, args: list[str] | None = None,
             subscribers: dict[str, int] | None = None) -> int:
    """Publish the bag; returns the number of messages published. Ctrl-C stops it cleanly.

    subscribers: bag topic -> subscribers to wait for (up to ``start_delay_s``) before playing; 1
    for the others."""
    if rate <= 0:
        msg = f'--rate must be > 0, got {rate}.'
        raise BagError(msg)
    info = inspect_bag(path)
    selected = [t for t in info.topics if topics is None or t in topics]
    if topics is not None and (missing := sorted(set(topics) - set(info.topics))):
        msg = f"topics {missing} are not in {path}; it has: {', '.join(sorted(info.topics))}."
        raise BagError(msg)
    remap = remap or {}
    init_rclpy(args)
    node = Node('srmosaic_player')
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    publishers = {t: node.create_publisher(_message_class(info.topics[t].msgtype), remap.get(t, t).lstrip('/'), qos)
                  for t in selected}
    count = 0
    try:
        _wait_for_subscribers(node, publishers, start_delay_s, subscribers)
        while True:
            t_wall0 = time.monotonic()
            t_bag0 = None
            for topic, _msgtype, log_ns, raw in iter_raw(path, topics=selected):
                if t_bag0 is None:
                    t_bag0 = log_ns
                due = t_wall0 + (log_ns - t_bag0) * 1e-9 / rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                publishers[topic].publish(raw)
                count += 1
            if not loop:
                break
        time.sleep(0.5)  # let the last messages leave before the publishers go
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return count
