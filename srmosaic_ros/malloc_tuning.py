"""Give the heap's free memory back to the system during long runs (glibc).

Registering and painting frames with torch allocates and frees many buffers of 0.1 to 5 MB from
several threads. glibc raises its mmap threshold after the first large frees, so later buffers
come from the heap, whose free space fragments and is not returned: a long `process` run grows
with every frame. `malloc_trim(0)` every HEAP_TRIM_EVERY frames releases the free pages (resident
size flat, at a few ms per frame on average; bench/memory.py). Fixing the mmap threshold instead
(mallopt M_MMAP_THRESHOLD) low also bounds it but costs much throughput in page faults.

Page faults also slow the first frames of a run: until those first large frees, every buffer over
128 kB is mapped and unmapped again, and the heap is trimmed whenever 256 kB lie free at its top, so
a queue of frames held and freed is faulted in afresh each time round. `settle_allocator` sets at
start the thresholds glibc's own adjustment ends at (mapped above 32 MiB, trimmed above 64 MiB
free). Elsewhere than glibc a no-op.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys

__all__ = ['HEAP_TRIM_EVERY', 'HeapTrimmer', 'settle_allocator', 'trim_heap']

#: Frames between two malloc_trim calls.
HEAP_TRIM_EVERY = 50

#: glibc's mallopt parameters and the values settle_allocator sets: buffers up to 32 MiB (glibc's
#: largest dynamic mmap threshold on 64-bit) come from the heap, which keeps up to 64 MiB free at its
#: top (twice that, as glibc's own adjustment sets it).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 32 << 20
TRIM_THRESHOLD_BYTES = 64 << 20


@functools.lru_cache(maxsize=1)
def _libc():
    if not sys.platform.startswith('linux'):
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6')
    except OSError:
        return None


@functools.lru_cache(maxsize=1)
def settle_allocator() -> bool:
    """Set glibc's mmap and trim thresholds to where its dynamic adjustment settles (module
    docstring), once per process; True when both were set (False elsewhere than glibc)."""
    libc = _libc()
    mallopt = getattr(libc, 'mallopt', None)
    if mallopt is None:
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


def trim_heap() -> bool:
    """Release the heap's free pages to the system now; True when glibc's malloc_trim ran."""
    fn = getattr(_libc(), 'malloc_trim', None)
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
