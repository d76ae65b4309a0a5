"""Run one or several nodes in this process until Ctrl-C (SIGINT) or SIGTERM, then shut down cleanly."""
from __future__ import annotations

import signal
import sys
from collections.abc import Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from ..errors import ConfigError, SrMosaicError

__all__ = ['init_rclpy', 'run_nodes']


def init_rclpy(args: list[str] | None, **kwargs: Any) -> None:
    """rclpy.init, with rcl's refusal of the command line (a parameter file it cannot parse, a
    malformed remapping) as a ConfigError of one line rather than an RCLError traceback."""
    from rclpy.impl.implementation_singleton import rclpy_implementation

    try:
        rclpy.init(args=args, **kwargs)
    except rclpy_implementation.RCLError as exc:
        first = str(exc).splitlines()[0].removeprefix('failed to initialize rcl: ')
        msg = f'ROS arguments refused: {first}'
        raise ConfigError(msg) from None


class _Stop(BaseException):
    """A second SIGINT / SIGTERM: raised in the main thread wherever it is (a callback that does not
    return). A BaseException, as KeyboardInterrupt is, so that a callback's `except Exception` (the
    nodes keep spinning past a bad input) does not swallow it."""


class _StopRequest:
    """Signal handler for SIGINT and SIGTERM. The first signal only sets ``requested``: spinning stops
    once the callback running returns (within SPIN_TIMEOUT_S when none runs). Raising there instead
    lands the exception wherever the main thread is, also inside rclpy's C++ while it builds a message
    in Python, where pybind11 turns it into a RuntimeError and the node exits with a traceback
    (status 1) instead of shutting down. A second signal raises _Stop."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise _Stop
        self.requested = True


#: Longest wait in rcl before the spin loop looks at a stop request again (s).
SPIN_TIMEOUT_S = 0.5


def run_nodes(node_classes: Sequence[type], args: list[str] | None = None) -> int:
    """Create the nodes (sharing the command line's --ros-args), spin them, finish them on exit.

    Returns the exit status: 0 after a clean shutdown, 2 when a node refused its parameters.
    Nodes with a `finish()` method get it called after spinning stops (drain queues, write files).
    """
    # Our own handlers: SIGINT and SIGTERM stop spinning; rclpy's would shut the context down
    # before the nodes could finish.
    init_rclpy(args, signal_handler_options=SignalHandlerOptions.NO)
    stop = _StopRequest()
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    nodes = []
    status = 0
    try:
        for cls in node_classes:
            nodes.append(cls())
        # One executor thread: every callback only converts and enqueues (the work runs in each
        # node's worker thread). rclpy's MultiThreadedExecutor spends a whole core polling its
        # futures at video rates and starves the workers.
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        # spin_once with a timeout returns to Python twice a second even when no node has a timer
        # (an idle georef node, an unconfigured lifecycle node), so that the handlers above run:
        # executor.spin() would wait in rcl, where Python signal handlers never run.
        while rclpy.ok() and not stop.requested:
            executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
    except (_Stop, KeyboardInterrupt, ExternalShutdownException):
        pass
    except SrMosaicError as exc:
        print(f'srmosaic: error: {exc}', file=sys.stderr)
        status = 2
    except Exception as exc:  # rclpy refuses a parameter outside its declared range, for instance
        if type(exc).__name__ in {'InvalidParameterValueException', 'ParameterException',
                                  'InvalidParameterTypeException', 'ParameterUninitializedException'}:
            print(f'srmosaic: error: invalid parameter: {exc}', file=sys.stderr)
            status = 2
        elif not stop.requested:  # else a second signal's _Stop, turned into another error by C++ code
            raise
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        for node in nodes:
            finish = getattr(node, 'finish', None)
            if finish is not None:
                try:
                    finish()
                except Exception as exc:  # noqa: BLE001 - report, then go on shutting the others down
                    print(f'srmosaic: {node.get_name()} failed to finish: {exc}', file=sys.stderr)
                    status = status or 1
            node.destroy_node()
        rclpy.try_shutdown()
    return status
