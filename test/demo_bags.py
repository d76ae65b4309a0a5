"""The bundled demo flight (bags/demo) rewritten with rosbags into an mcap bag, with a change to
some of its messages: the bad inputs of the reliability tests, built from the real thing."""
from __future__ import annotations

import collections
from collections.abc import Callable
from pathlib import Path
from typing import Any

DEMO = Path(__file__).resolve().parent.parent / 'bags' / 'demo'


def rewrite_demo(dst: Path, tamper: Callable[[str, int, Any], None] | None = None) -> Path:
    """``dst`` (an mcap bag) holding the demo's messages; ``tamper(kind, index, msg)`` may change
    each deserialised message in place first: kind 'image', 'fix', 'imu' or 'camera_info', index
    its count within that kind."""
    from rosbags.rosbag2 import Reader

    from msg_adapters._flavor import rosbags_typestore
    from srmosaic_ros.io.bags import BagWriter

    store = rosbags_typestore()
    seen: collections.Counter[str] = collections.Counter()
    with Reader(DEMO) as reader, BagWriter(dst, storage='mcap') as writer:
        for connection, log_ns, raw in reader.messages():
            msg = store.deserialize_cdr(raw, connection.msgtype)
            kind = {'NavSatFix': 'fix', 'Imu': 'imu', 'CameraInfo': 'camera_info'}.get(
                connection.msgtype.rsplit('/', 1)[-1], 'image' if 'image' in connection.topic else '')
            if tamper is not None and kind:
                tamper(kind, seen[kind], msg)
            seen[kind] += 1
            writer.write(connection.topic, msg, log_ns)
    return dst
