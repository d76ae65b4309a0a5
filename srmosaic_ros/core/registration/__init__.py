"""Frame-to-frame registration: features, matching, robust homography estimation.

The torch registrar imports torch (slow to import, hundreds of MB): every name loads on first use
(PEP 562), so that ``import srmosaic_ros.core.registration.validity`` stays light.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .factory import FallbackFeatures, FallbackRegistrar, make_registrar
    from .registrar import BACKENDS, Features, Registrar, Registration, RegistrationConfig
    from .torch_registrar import TorchRegistrar, TorchRegistrarOptions
    from .validity import check_homography

_LAZY = {
    'BACKENDS': 'registrar',
    'Features': 'registrar',
    'Registrar': 'registrar',
    'Registration': 'registrar',
    'RegistrationConfig': 'registrar',
    'TorchRegistrar': 'torch_registrar',
    'TorchRegistrarOptions': 'torch_registrar',
    'FallbackFeatures': 'factory',
    'FallbackRegistrar': 'factory',
    'make_registrar': 'factory',
    'check_homography': 'validity',
}

__all__ = ['BACKENDS', 'Features', 'Registrar', 'Registration', 'RegistrationConfig', 'TorchRegistrar', 'TorchRegistrarOptions',
           'FallbackFeatures', 'FallbackRegistrar', 'check_homography', 'make_registrar']


def __getattr__(name: str) -> Any:  # PEP 562 lazy attributes
    if name in _LAZY:
        return getattr(importlib.import_module(f'.{_LAZY[name]}', __name__), name)
    msg = f'module {__name__!r} has no attribute {name!r}'
    raise AttributeError(msg)


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
