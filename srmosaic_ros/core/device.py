"""The one place that resolves `device: auto|cpu|cuda` (and the dtype) for tensor work."""
from __future__ import annotations

import torch

__all__ = ['resolve_device', 'DEFAULT_DTYPE']

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
