"""The one place that resolves `device: auto|cpu|cuda` (and the dtype) for tensor work."""
from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ['resolve_device', 'DEFAULT_DTYPE', 'cores_left_for_torch']

DEFAULT_DTYPE = torch.float32


def resolve_device(name: str = 'auto') -> torch.device:
    """'auto' -> cuda when available else cpu; 'cuda' without a GPU is an error, not a silent fallback."""
    if name == 'auto':
        return torch.device('cuda' if torch.cuda.is_available() else 'cpu')
    if name == 'cpu':
        return torch.device('cpu')
    if name == 'cuda' or name.startswith('cuda:'):
        if not torch.cuda.is_available():
            msg = "device 'cuda' was requested but torch sees no CUDA GPU; use device: auto or cpu."
            raise ValueError(msg)
        return torch.device(name)
    msg = f"device must be 'auto', 'cpu' or 'cuda', got {name!r}."
    raise ValueError(msg)


@contextmanager
def cores_left_for_torch(busy: int) -> Iterator[int]:
    """Within the block, torch's CPU threads leave ``busy`` cores to other threads of the process
    (the painter: two threads each wanting both cores of a 2-core machine run slower than one core
    each); at least one thread, and no more than torch had. Yields the thread count."""
    before = torch.get_num_threads()
    threads = max(1, min(before, (os.cpu_count() or 1) - busy))
    torch.set_num_threads(threads)
    try:
        yield threads
    finally:
        torch.set_num_threads(before)
