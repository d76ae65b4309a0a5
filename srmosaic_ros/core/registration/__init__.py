"""Frame-to-frame registration: features, matching, robust homography estimation."""
from __future__ import annotations

from .registrar import Features, Registrar, Registration, RegistrationConfig
from .torch_registrar import TorchRegistrar, TorchRegistrarOptions
from .validity import check_homography

__all__ = ['Features', 'Registrar', 'Registration', 'RegistrationConfig', 'TorchRegistrar', 'TorchRegistrarOptions',
           'check_homography']
