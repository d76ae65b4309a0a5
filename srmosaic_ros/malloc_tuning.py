"""Give the heap's free memory back to the system during long runs (glibc).

Registering and painting frames with torch allocates and frees many buffers of 0.1 to 5 MB from
several threads. glibc raises its mmap threshold after the first large frees, so later buffers
come from the heap, whose free space fragments and is not returned: a long `process` run grows
with every frame. `malloc_trim(0)` every HEAP_TRIM_EVERY frames releases the free pages (resident
size flat, at a few ms per frame on average; bench/memory.py). Fixing the mmap threshold instead
(mallopt M_MMAP_THRESHOLD) also bounds it but costs much throughput in page faults. Elsewhere
than glibc a no-op.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys

__all__ = ['HEAP_TRIM_EVERY', 'HeapTrimmer', 'trim_heap']

#: Frames between two malloc_trim calls.
HEAP_TRIM_EVERY = 50


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    if not sys.platform.startswith('linux'):
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6').malloc_trim
    except (OSError, AttributeError):
        return None


def trim_heap() -> bool:
    """Release the heap's free pages to the system now; True when glibc's malloc_trim ran."""
    fn = _malloc_trim()
    if fn is None:
        return False
    fn(0)
    return True


class HeapTrimmer:
    """Calls trim_heap every `every` ticks (one tick per processed frame)."""

    def __init__(self, every: int = HEAP_TRIM_EVERY) -> None:
        if every < 1:
            msg = f'HeapTrimmer needs every >= 1, got {every}.'
            raise ValueError(msg)
        self.every = every
        self.ticks = 0
        self.trims = 0

    def tick(self) -> None:
        self.ticks += 1
        if self.ticks % self.every == 0 and trim_heap():
            self.trims += 1
