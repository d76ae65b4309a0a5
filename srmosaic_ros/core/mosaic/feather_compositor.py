"""Feather compositing (section 4.2.5): every tile accumulates the frames' weighted colour and weight.

Each frame i offers its warped colour ``I_H^i`` and feather weight ``W_H^i`` to the tiles it covers:
``acc += W_H^i I_H^i``, ``wsum += W_H^i``; rendering divides the two (:func:`.blend.feather_divide`).
Every blend keeps these sums (the feather composite is what keyframes register to), so the other
compositors extend this one.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .blend import feather_weight
from .canvas_settings import FeatherSettings
from .frame_cut import PaintJob
from .paint_ops import add_into, times_weight
from .tile_store import TileLayout

__all__ = ['FeatherCompositor']


class FeatherCompositor:
    """Feather blending: the weight of a frame's pixels and what a tile keeps of them.

    ``feather``: the weight's profile and power. The canvas asks, per paint: :meth:`rates_resolution`
    and :meth:`weight` (the frame's weight, frame-sized), :meth:`cut` (the seams' cut over the paint's
    box, None without one), then :meth:`offer` per tile.
    """

    blend = 'feather'

    def __init__(self, feather: FeatherSettings) -> None:
        self.feather = feather

    @property
    def seam_cut(self) -> bool:
        """Whether a graph cut moves the seams (:mod:`.frame_cut`)."""
        return False

    def layout(self, tile_size: int, channels: int) -> TileLayout:
        """The arrays of one tile: ``acc`` and ``wsum``."""
        return TileLayout(tile_size, channels, False, False, 0)

    def rates_resolution(self, m: np.ndarray, w: int, h: int) -> bool:
        """Whether the weight of a w x h frame at ``m`` needs its resolution factor (and so its depth map)."""
        return False

    def weight(self, h: int, w: int, valid: np.ndarray | None, m: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
        """float32 (h, w) weight of the frame's pixels: the feather weight W(x, y) (zero where ``valid``,
        bool (h, w), is False); ``m`` and ``depth`` (:func:`.best_view.depth_map`, None: not rated)
        are the view-quality compositor's."""
        return feather_weight(h, w, profile=self.feather.profile, power=self.feather.power, mask=valid)

    def cut(self, jobs: list[PaintJob], tiles: list[Any], img_w: np.ndarray, w_w: np.ndarray, index: int,
            channels: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The seams' cut over the paint's box (feather blending has no seams: None)."""
        return None

    def offer(self, tile: Any, loc: tuple[slice, slice], colour: np.ndarray, weight: np.ndarray, index: int,
              cut: tuple[np.ndarray, np.ndarray] | None) -> None:
        """Add frame ``index``'s warped colour (h, w, C) and weight (h, w) to ``tile`` at ``loc``:
        ``acc += W I``, ``wsum += W``; ``cut`` (free, take) bool (h, w) is the seams' cut there."""
        add_into(tile.acc[loc], times_weight(colour, weight))  # per tile: the product stays in cache
        add_into(tile.wsum[loc], weight)
