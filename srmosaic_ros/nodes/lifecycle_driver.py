"""`srmosaic launch` as the lifecycle manager of the managed nodes it starts.

A launch file's ``<lifecycle_node ... autostart="true">`` (launch_ros's element) asks the launcher
to bring that node up: ``srmosaic launch`` waits for each such node's change_state service, then
configures every one of them and only then activates them, in the file's order, so that no node
processes a frame before the whole graph is configured (a standalone georef node configured late
would miss the first registrations). A node already active (it was started with
live.autostart: true) is left as it is. A refused configure (a parameter the node cannot use:
the node logs why) ends the launch: the others are stopped and the launcher exits with status 2.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = ['LifecycleDriver']

_WAIT_S = 120.0  # for a node's services: a node imports torch and builds its pipeline first


@dataclass
class LifecycleDriver:
    """Configure, then activate, the nodes named by their full names ('/uav1/srmosaic_mosaic')
    from a thread of the launcher, over their ~/get_state and ~/change_state services."""

    names: list[str]
    log: Callable[[str], None] = print
    failure: str | None = None  # why the bring-up failed (the launcher stops the graph)
    done: threading.Event = field(default_factory=threading.Event)
    _stop: threading.Event = field(default_factory=threading.Event)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name='srmosaic-lifecycle', daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if hasattr(self, '_thread'):
            self._thread.join(timeout=10)

    def _run(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        context = rclpy.Context()
        # The launcher's own node: no --ros-args of the children (their remappings are theirs), and
        # no signal handlers of rclpy's (the launcher forwards SIGINT to its children itself).
        rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node('srmosaic_launch_lifecycle', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        try:
            self._bring_up(node, executor)
        except Exception as exc:  # noqa: BLE001 - any failure here ends the launch with its reason
            self.failure = f'lifecycle bring-up failed: {exc}'
        finally:
            self.done.set()
            node.destroy_node()
            rclpy.try_shutdown(context=context)

    def _call(self, executor, client, request, what: str):
        future = client.call_async(request)
        deadline = time.monotonic() + 60.0
        while not future.done():
            if self._stop.is_set():
                return None
            if time.monotonic() > deadline:
                msg = f'{what}: no answer in 60 s'
                raise TimeoutError(msg)
            executor.spin_once(timeout_sec=0.1)
        return future.result()

    def _bring_up(self, node, executor) -> None:
        from lifecycle_msgs.msg import State, Transition
        from lifecycle_msgs.srv import ChangeState, GetState

        clients = {name: (node.create_client(GetState, f'{name}/get_state'),
                          node.create_client(ChangeState, f'{name}/change_state')) for name in self.names}
        for name, (get_state, change_state) in clients.items():
            deadline = time.monotonic() + _WAIT_S
            while not (get_state.service_is_ready() and change_state.service_is_ready()):
                if self._stop.is_set():
                    return
                if time.monotonic() > deadline:
                    self.failure = (f'{name} did not offer its lifecycle services within {_WAIT_S:.0f} s '
                                    '(is it a managed node, with this name and namespace?)')
                    return
                executor.spin_once(timeout_sec=0.2)
        for step, (transition, start_state) in enumerate(
                ((Transition.TRANSITION_CONFIGURE, State.PRIMARY_STATE_UNCONFIGURED),
                 (Transition.TRANSITION_ACTIVATE, State.PRIMARY_STATE_INACTIVE))):
            verb = ('configure', 'activate')[step]
            for name, (get_state, change_state) in clients.items():
                state = self._call(executor, get_state, GetState.Request(), f'{name} get_state')
                if state is None:
                    return
                if state.current_state.id == State.PRIMARY_STATE_ACTIVE:
                    if step == 0:
                        self.log(f'{name} is already active (live.autostart); left as it is')
                    continue
                if state.current_state.id != start_state:
                    self.failure = f'{name} is {state.current_state.label}, cannot {verb} it'
                    return
                reply = self._call(executor, change_state,
                                   ChangeState.Request(transition=Transition(id=transition)), f'{name} {verb}')
                if reply is None:
                    return
                if not reply.success:
                    self.failure = f'{name} refused to {verb} (its log above says why)'
                    return
                self.log(f'{name}: {verb}d')
