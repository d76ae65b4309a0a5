"""Frame-to-frame registration: features, matching, robust homography estimation."""
from __future__ import annotations

from .factory import FallbackFeatures, FallbackRegistrar, make_registrar
from .registrar import BACKENDS, Features, Registrar, Registration, RegistrationConfig
from .torch_registrar import TorchRegistrar, TorchRegistrarOptions
from .validity import check_homography

__all__ = ['BACKENDS', 'Features', 'Registrar', 'Registration', 'RegistrationConfig', 'TorchRegistrar', 'TorchRegistrarOptions',
           'FallbackFeatures', 'FallbackRegistrar', 'check_homography', 'make_registrar']
