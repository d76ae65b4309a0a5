"""The threads a paint writes its tiles on (``TiledCanvas(threads=...)``)."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

__all__ = ['PaintPool']


class PaintPool:
    """Runs a paint's per-tile work on ``threads`` threads (1: on the caller's).

    Tiles are independent, and OpenCV and numpy release the GIL on their arrays. The threads (and
    their scratch arrays, :mod:`.scratch`) are started by the first paint that uses them and kept from
    paint to paint; a pickled pool holds none (started again by the next paint).
    """

    def __init__(self, threads: int) -> None:
        self.threads = threads
        self._pool: ThreadPoolExecutor | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state['_pool'] = None
        return state

    def run(self, work: Callable[[Any, Any], None], jobs: Sequence[Any], tiles: Sequence[Any]) -> None:
        """``work(job, tile)`` for each pair of ``jobs`` and ``tiles``, on the threads when more than one
        would have work."""
        if min(self.threads, len(jobs)) > 1:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix='paint')
            for _ in self._pool.map(work, jobs, tiles):
                pass
        else:
            for job, tile in zip(jobs, tiles):
                work(job, tile)

    def close(self) -> None:
        """Stop the threads (a later :meth:`run` starts them again)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
