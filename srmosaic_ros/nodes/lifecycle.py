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

from rclpy.lifecycle import LifecycleState, TransitionCallbackReturn
from rclpy.lifecycle import Node as LifecycleNode

from ..errors import SrMosaicError

__all__ = ['ManagedNode', 'autostart', 'configure_with', 'release']


def _entities(node: Any) -> list[tuple[Callable[[Any], Any], Any]]:
    return ([(node.destroy_publisher, e) for e in node.publishers]
            + [(node.destroy_subscription, e) for e in node.subscriptions]
            + [(node.destroy_timer, e) for e in node.timers]
            + [(node.destroy_service, e) for e in node.services])


def configure_with(node: Any, build: Callable[[], None]) -> TransitionCallbackReturn:
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
    """Destroy the publishers, subscriptions, timers and services that configure made."""
    for destroy, entity in items:
        destroy(entity)


def autostart(node: Any) -> None:
    """With live.autostart: configure and activate now; a refused configure raises its error."""
    if not node.get_parameter('live.autostart').value:
        return
    node.trigger_configure()
    if node.configure_error is not None:
        raise node.configure_error
    node.trigger_activate()


class ManagedNode(LifecycleNode):
    """The transitions shared by the package's managed nodes.

    A subclass builds in ``_configure`` (run through :func:`configure_with`), frees in ``finish``
    (cleanup, shutdown, the end of the process), reads ``self.active`` in its input callbacks, and
    keeps the timer whose period ``live.preview_period_s`` changes live in ``self._periodic``; it
    calls :func:`autostart` at the end of its constructor.
    """

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.active = False
        self.configured = False
        self._periodic: Any = None
        self._entities: list[tuple[Callable[[Any], Any], Any]] = []  # (destroy, entity) made by configure
        self.configure_error: Exception | None = None

    def _configure(self) -> None:
        raise NotImplementedError

    def finish(self) -> None:
        raise NotImplementedError

    def _set_period(self, period_s: float) -> None:
        if self._periodic is not None:
            self._periodic.timer_period_ns = int(period_s * 1e9)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return configure_with(self, self._configure)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = True
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.finish()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.finish()
        return TransitionCallbackReturn.SUCCESS
