"""builtin_interfaces/Time <-> integer nanoseconds, and std_msgs/Header helpers."""
from __future__ import annotations

from typing import Any

from srmosaic_ros.errors import MessageError

from ._flavor import new_message

__all__ = ['stamp_to_ns', 'ns_to_stamp', 'header_to_ns_frame', 'make_header']

_NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


def stamp_to_ns(stamp: Any) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time (``sec``, ``nanosec``) of either flavour.

    ROS 1 times deserialised by rosbags use the same field names; genpy's ``secs``/``nsecs``
    are accepted too.
    """
    try:
        sec = stamp.sec if hasattr(stamp, 'sec') else stamp.secs
        nanosec = stamp.nanosec if hasattr(stamp, 'nanosec') else stamp.nsecs
    except AttributeError:
        msg = (
            f'stamp of type {type(stamp).__name__} has no sec/nanosec fields; '
            'pass a builtin_interfaces/Time (e.g. msg.header.stamp).'
        )
        raise MessageError(msg) from None
    return int(sec) * _NS_PER_S + int(nanosec)


def ns_to_stamp(ns: int, flavor: str = 'rclpy') -> Any:
    """builtin_interfaces/Time of ``flavor`` for integer nanoseconds ``ns`` (nanosec in [0, 1e9))."""
    sec, nanosec = divmod(int(ns), _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        msg = (
            f'stamp {ns} ns is {sec} s, outside the int32 range of builtin_interfaces/Time.sec; '
            'pass nanoseconds since the Unix epoch (not, e.g., microseconds * 1e6).'
        )
        raise MessageError(msg)
    return new_message(flavor, 'builtin_interfaces/msg/Time', sec=sec, nanosec=nanosec)


def header_to_ns_frame(msg: Any) -> tuple[int, str]:
    """(stamp_ns, frame_id) of a message with a std_msgs/Header."""
    header = msg.header
    return stamp_to_ns(header.stamp), str(header.frame_id)


def make_header(stamp_ns: int, frame_id: str, flavor: str) -> Any:
    """std_msgs/Header of ``flavor``."""
    return new_message(
        flavor, 'std_msgs/msg/Header', stamp=ns_to_stamp(stamp_ns, flavor), frame_id=str(frame_id)
    )
