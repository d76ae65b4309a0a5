"""One background thread running jobs in the order they were submitted.

The pipeline paints frame k into the mosaic here while it describes and registers frame k + 1 in
the caller's thread: numpy, OpenCV and torch release the GIL in their array work, so on two cores
the stages overlap. The queue is bounded (``depth`` jobs waiting), so a slow painter holds the
caller back instead of letting frames pile up in memory. A job's exception is raised in the caller
at its next submit() or wait(); jobs after a failed one are dropped.
"""
from __future__ import annotations

import queue
import threading
from collections.abc import Callable

__all__ = ['SerialWorker']


class SerialWorker:
    """Runs callables in submission order on one daemon thread (see the module docstring)."""

    def __init__(self, depth: int = 2, name: str = 'srmosaic-worker') -> None:
        self._queue: queue.Queue[Callable[[], None] | None] = queue.Queue(maxsize=max(depth, 1))
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            job = self._queue.get()
            try:
                if job is None:
                    return
                if self._error is None:
                    job()
            except BaseException as exc:  # noqa: BLE001 - raised in the caller (submit / wait)
                self._error = exc
            finally:
                self._queue.task_done()

    def _raise(self) -> None:
        if self._error is not None:
            exc, self._error = self._error, None
            raise exc

    def submit(self, job: Callable[[], None]) -> None:
        """Queue ``job`` (blocks while ``depth`` jobs wait); raises an earlier job's exception."""
        self._raise()
        self._queue.put(job)

    def wait(self) -> None:
        """Return when every submitted job has run; raises the first exception of one."""
        self._queue.join()
        self._raise()

    def close(self) -> None:
        """Run what is queued, then stop the thread."""
        self._queue.join()
        self._queue.put(None)
        self._thread.join()
