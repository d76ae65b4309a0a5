"""Super-resolution mosaicking (chapter 5): operators, Huber prior, SD / CG / LM solvers, tile reconstruction.

Entry point: :func:`reconstruct_tile` (settings in :class:`SRConfig`, output :class:`SRResult`).

The solvers import torch (slow to import, hundreds of MB): every name loads on first use (PEP 562),
so that ``import srmosaic_ros.core.sr.sr_config`` stays light.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..lazy import lazy_attributes

if TYPE_CHECKING:
    from .observation import FrameStack, ObservationOperator, build_frame_stack
    from .operators import (
        Blur,
        BlurDecimate,
        Compose,
        Crop,
        Decimate,
        LinearOperator,
        Mask,
        Warp,
        gaussian_psf,
        hr_H_lr,
        lr_H_hr,
    )
    from .prior import HuberPrior, adaptive_lambda, clique_differences, clique_differences_adjoint, huber
    from .reconstruct import SRConfig, SRError, SRFramesDisagree, SRResult, lr_mosaic, reconstruct_tile, robust_frame_weights
    from .solvers import IterationRecord, LambdaRule, Problem, SolveResult, solve

_LAZY = {
    'FrameStack': 'observation',
    'ObservationOperator': 'observation',
    'build_frame_stack': 'observation',
    'Blur': 'operators',
    'BlurDecimate': 'operators',
    'Compose': 'operators',
    'Crop': 'operators',
    'Decimate': 'operators',
    'LinearOperator': 'operators',
    'Mask': 'operators',
    'Warp': 'operators',
    'gaussian_psf': 'operators',
    'hr_H_lr': 'operators',
    'lr_H_hr': 'operators',
    'HuberPrior': 'prior',
    'adaptive_lambda': 'prior',
    'clique_differences': 'prior',
    'clique_differences_adjoint': 'prior',
    'huber': 'prior',
    'SRConfig': 'reconstruct',
    'SRError': 'reconstruct',
    'SRFramesDisagree': 'reconstruct',
    'SRResult': 'reconstruct',
    'lr_mosaic': 'reconstruct',
    'reconstruct_tile': 'reconstruct',
    'robust_frame_weights': 'reconstruct',
    'IterationRecord': 'solvers',
    'LambdaRule': 'solvers',
    'Problem': 'solvers',
    'SolveResult': 'solvers',
    'solve': 'solvers',
}

__all__ = [
    'Blur', 'BlurDecimate', 'Compose', 'Crop', 'Decimate', 'LinearOperator', 'Mask', 'Warp', 'gaussian_psf',
    'hr_H_lr', 'lr_H_hr',
    'FrameStack', 'ObservationOperator', 'build_frame_stack',
    'HuberPrior', 'adaptive_lambda', 'clique_differences', 'clique_differences_adjoint', 'huber',
    'SRConfig', 'SRError', 'SRFramesDisagree', 'SRResult', 'lr_mosaic', 'reconstruct_tile', 'robust_frame_weights',
    'IterationRecord', 'LambdaRule', 'Problem', 'SolveResult', 'solve',
]

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, globals())  # PEP 562
