"""Frame-to-frame registration: features, matching, robust homography estimation.

The torch registrar imports torch (slow to import, hundreds of MB): every name loads on first use
(PEP 562), so that ``import srmosaic_ros.core.registration.validity`` stays light.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..lazy import lazy_attributes

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

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, globals())  # PEP 562
