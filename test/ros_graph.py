"""Tests over real DDS: a listener node (subscriptions recorded into lists, spun in a thread) and
the supervision of the processes under test."""
from __future__ import annotations

import contextlib
import itertools
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any


#: Waits on a graph are sized for a loaded 2-core machine (another test, or another CPU-heavy process,
#: beside the graph): each timeout a test gives is multiplied by this. A passing wait returns as soon as
#: its condition holds, so the factor only lengthens the wait of a test that fails.
WAIT_SCALE = float(os.environ.get('SRMOSAIC_TEST_WAIT_SCALE', '3'))

_DOMAINS = itertools.count()


def ros_domain_id() -> int:
    """A ROS_DOMAIN_ID for one test, in the portable range 1-100: the xdist workers of one run take
    distinct residues (so concurrent tests never share a domain), successive tests of a worker take
    successive slots (so a graph a test left behind does not talk to the next), and the run's own
    offset keeps concurrent runs on the machine apart."""
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    worker = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0')[2:] or 0)
    run = os.environ.get('PYTEST_XDIST_TESTRUNUID')
    offset = int(run[:8], 16) if run else os.getpid()
    slots = 100 // workers
    return 1 + ((offset + next(_DOMAINS)) % slots) * workers + worker


def stop_process(proc: subprocess.Popen, timeout: float = 60) -> str:
    """SIGINT (a clean shutdown, as Ctrl-C) unless it has ended; its output."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=timeout)
    return out


@contextlib.contextmanager
def supervised_processes(procs: dict[str, subprocess.Popen], close: Callable[[], None]) -> Iterator[dict[str, str]]:
    """Run a test against started processes: a failed assertion carries their output; at the end each
    is stopped (its output in the dict yielded), then `close` runs (the listener)."""
    logs: dict[str, str] = {}
    try:
        yield logs
    except AssertionError as exc:
        outputs = ''.join(f'\n--- {name} output ---\n{stop_process(proc)}' for name, proc in procs.items())
        raise AssertionError(f'{exc}{outputs}') from None
    finally:
        for name, proc in procs.items():
            logs[name] = stop_process(proc) if proc.returncode is None else logs.get(name, '')
        close()


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

    def subscribe(self, msg_type: type, topic: str, qos: Any = 100) -> list:
        """The list every message on `topic` is appended to."""
        received: list = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def start(self) -> None:
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop:
            self.executor.spin_once(timeout_sec=0.1)

    def wait_for(self, predicate: Callable[[], Any], timeout: float, *, scaled: bool = True) -> bool:
        """Poll `predicate` until it holds (True) or `timeout` seconds pass (False), times WAIT_SCALE
        unless ``scaled`` is False (a wait that is a retry's period, not a bound on the graph)."""
        deadline = time.monotonic() + timeout * (WAIT_SCALE if scaled else 1.0)
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
