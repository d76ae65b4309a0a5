"""Read ahead: the input's items produced by a background thread into a bounded queue.

Decoding video (PyAV/FFmpeg) and reading bags release the GIL for most of their work, so on two
cores the next frames are decoded while the pipeline registers and paints the current one. The
items arrive in the input's order, unchanged; an error of the reader is raised in the consumer at
the place of the item that failed; the queue bounds the frames held (``depth`` items).
"""
from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from typing import Any

__all__ = ['prefetched']

_END = object()


class _Failed:
    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


def prefetched(items: Iterable[Any], depth: int = 8) -> Iterator[Any]:
    """The items of ``items`` in order, read by a background thread at most ``depth`` ahead.

    Closing the generator early (the consumer stops or fails) stops the reader thread at its next
    item: nothing keeps reading a file nobody consumes."""
    if depth < 1:
        yield from items
        return
    q: queue.Queue[Any] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(value: Any) -> bool:
        while not stop.is_set():
            try:
                q.put(value, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in items:
                if not put(item):
                    return
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, raised there
            put(_Failed(exc))
            return
        put(_END)

    thread = threading.Thread(target=produce, name='srmosaic-read-ahead', daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is _END:
                return
            if isinstance(item, _Failed):
                raise item.exc
            yield item
    finally:
        stop.set()
        thread.join(timeout=5.0)
