"""RoundThread: a background thread that runs one round of work when asked and idle (no ROS).

    rounds = RoundThread(do_round, name='srmosaic-sr-worker', niceness=10, on_error=log)
    rounds.start()
    if not rounds.request():       # a timer asks; False: a round is still running (skipped)
        count_skip()
    rounds.stop()                  # the round in progress completes (up to the join timeout)

The SR node's worker: a round plans, reconstructs and publishes tiles; the executor never waits for
one. ``niceness``: the thread's own (Linux applies it to the calling thread only; best effort), so
that background work in the mosaic node's process does not take the CPU from registration.
"""
from __future__ import annotations

import os
import threading
from collections.abc import Callable

__all__ = ['RoundThread']


class RoundThread:
    """Runs ``do_round()`` in a thread of its own whenever :meth:`request` finds it idle (module
    docstring). An exception of a round goes to ``on_error`` and the thread goes on."""

    def __init__(self, do_round: Callable[[], None], *, name: str, niceness: int,
                 on_error: Callable[[BaseException], None]) -> None:
        self._do_round = do_round
        self._niceness = int(niceness)
        self._on_error = on_error
        self._wake = threading.Condition()
        self._requested = False
        self._busy = False
        self.stopping = False  # read by a round to end early
        self._thread = threading.Thread(target=self._work, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def request(self) -> bool:
        """Ask for a round; False (nothing asked) while one is running."""
        with self._wake:
            if self._busy:
                return False
            self._requested = True
            self._wake.notify()
            return True

    def stop(self) -> None:
        """Ask the thread to end (a round in progress sees ``stopping``)."""
        with self._wake:
            self.stopping = True
            self._wake.notify()

    def join(self, timeout_s: float) -> None:
        self._thread.join(timeout=timeout_s)

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    def _work(self) -> None:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self._niceness)
        except (AttributeError, OSError):
            pass
        while True:
            with self._wake:
                while not self._requested and not self.stopping:
                    self._wake.wait(0.5)
                if self.stopping:
                    return
                self._requested = False
                self._busy = True
            try:
                self._do_round()
            except Exception as exc:  # noqa: BLE001 - the worker must outlive any one round
                self._on_error(exc)
            finally:
                with self._wake:
                    self._busy = False
