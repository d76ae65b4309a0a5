"""Managed (lifecycle) nodes: what configure made, freed again at cleanup; autostart.

A node built on rclpy.lifecycle builds in on_configure through `configure_with`, which records the
publishers, subscriptions and timers the build created so that cleanup can `release` them, and
turns a refused parameter (SrMosaicError) into a failed transition with the reason logged. With the
parameter live.autostart (default true) `autostart` drives configure and activate at construction,
so `ros2 run` and `srmosaic launch` get a running node, and a refused configure raises as a plain
node's constructor would; with false the node waits unconfigured for a lifecycle manager
(`ros2 lifecycle set /srmosaic_mosaic configure`, or the change_state service).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.lifecycle import TransitionCallbackReturn

from ..errors import SrMosaicError

__all__ = ['autostart', 'configure_with', 'release']


def _entities(node: Any) -> list[tuple[Callable[[Any], Any], Any]]:  # noqa: ANN401
    return ([(node.destroy_publisher, e) for e in node.publishers]
            + [(node.destroy_subscription, e) for e in node.subscriptions]
            + [(node.destroy_timer, e) for e in node.timers])


def configure_with(node: Any, build: Callable[[], None]) -> TransitionCallbackReturn:  # noqa: ANN401
    """Run `build` (on_configure's work); node._entities gets what it created. SUCCESS, or FAILURE
    with the error kept in node.configure_error (and what it had created freed)."""
    before = {id(e) for _, e in _entities(node)}
    node.configure_error = None
    try:
        build()
    except SrMosaicError as exc:
        node.configure_error = exc
        node.get_logger().error(f'configure refused: {exc}')
        release([item for item in _entities(node) if id(item[1]) not in before])
        return TransitionCallbackReturn.FAILURE
    node._entities = [item for item in _entities(node) if id(item[1]) not in before]
    return TransitionCallbackReturn.SUCCESS


def release(items: list[tuple[Callable[[Any], Any], Any]]) -> None:
    """Destroy the publishers, subscriptions and timers that configure made."""
    for destroy, entity in items:
        destroy(entity)


def autostart(node: Any) -> None:  # noqa: ANN401
    """With live.autostart: configure and activate now; a refused configure raises its error."""
    if not node.get_parameter('live.autostart').value:
        return
    node.trigger_configure()
    if node.configure_error is not None:
        raise node.configure_error
    node.trigger_activate()
