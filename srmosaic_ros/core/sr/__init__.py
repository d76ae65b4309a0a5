"""Super-resolution mosaicking (chapter 5): operators, Huber prior, SD / CG / LM solvers, tile reconstruction.

Entry point: :func:`reconstruct_tile` (settings in :class:`SRConfig`, output :class:`SRResult`).
"""
from __future__ import annotations

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

__all__ = [
    'Blur', 'BlurDecimate', 'Compose', 'Crop', 'Decimate', 'LinearOperator', 'Mask', 'Warp', 'gaussian_psf',
    'hr_H_lr', 'lr_H_hr',
    'FrameStack', 'ObservationOperator', 'build_frame_stack',
    'HuberPrior', 'adaptive_lambda', 'clique_differences', 'clique_differences_adjoint', 'huber',
    'SRConfig', 'SRError', 'SRFramesDisagree', 'SRResult', 'lr_mosaic', 'reconstruct_tile', 'robust_frame_weights',
    'IterationRecord', 'LambdaRule', 'Problem', 'SolveResult', 'solve',
]
