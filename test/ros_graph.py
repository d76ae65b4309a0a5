"""A listener node for tests over real DDS: subscriptions recorded into lists, spun in a thread."""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any


class GraphListener:
    """An rclpy node in its own context: `subscribe` what to record, then `start` spinning."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = False
        self._thread = threading.Thread(target=self._spin, daemon=True)

    def subscribe(self, msg_type: type, topic: str, qos: Any = 100) -> list:  # noqa: ANN401
        """The list every message on `topic` is appended to."""
        received: list = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def start(self) -> None:
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop:
            self.executor.spin_once(timeout_sec=0.1)

    def wait_for(self, predicate: Callable[[], Any], timeout: float) -> bool:
        """Poll `predicate` until it holds (True) or `timeout` seconds pass (False)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.2)
        return False

    def close(self) -> None:
        self._stop = True
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)
