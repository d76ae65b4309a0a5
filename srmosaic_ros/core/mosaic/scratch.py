"""Per-thread scratch arrays reused from one painted frame to the next.

Painting a frame makes several temporaries the size of the frame's footprint (the warped colour and
weight, their product: tens of MB at 1080p). Fresh arrays of that size come from the system each
time (glibc hands large blocks back between frames), and their first write costs page faults that
add up to several ms per frame on top of the arithmetic; the same few arrays reused do not.

``scratch(name, shape)`` returns a C-contiguous float32 view of ``shape`` into the calling thread's
buffer ``name``, grown to fit and shrunk when four times too large (so a one-off large frame does
not hold its memory for good). Its contents are undefined, and the next call with the same name on
the same thread overwrites it: a caller uses it only until it returns, never hands it out. One set
of buffers per thread, so canvases painted from several threads never share one.
"""
from __future__ import annotations

import math
import threading

import numpy as np

__all__ = ['release', 'scratch']

_local = threading.local()


def _buffers() -> dict[str, np.ndarray]:
    bufs = getattr(_local, 'buffers', None)
    if bufs is None:
        bufs = _local.buffers = {}
    return bufs


def scratch(name: str, shape: tuple[int, ...]) -> np.ndarray:
    """float32 array of ``shape`` (C order, contents undefined) held by this thread under ``name``."""
    size = math.prod(shape)
    bufs = _buffers()
    buf = bufs.get(name)
    if buf is None or buf.size < size or buf.size > 4 * max(size, 1 << 16):
        buf = bufs[name] = np.empty(max(size, 1), np.float32)
    return buf[:size].reshape(shape)


def release() -> None:
    """Drop this thread's buffers (their memory returns once no view of them is left)."""
    _buffers().clear()
