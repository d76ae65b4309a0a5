"""Mosaic: the growing tiled canvas, blending (feather, multi-band) and segments of chained frames."""
from __future__ import annotations

from .blend import FEATHER_PROFILES, feather_weight, multiband_blend
from .canvas import CanvasError, PaintResult, TileKey, TiledCanvas
from .config import BLEND_MODES, MosaicConfig

__all__ = [
    'BLEND_MODES',
    'FEATHER_PROFILES',
    'CanvasError',
    'MosaicConfig',
    'PaintResult',
    'TileKey',
    'TiledCanvas',
    'feather_weight',
    'multiband_blend',
]
