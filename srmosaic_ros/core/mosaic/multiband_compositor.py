"""Multi-band compositing: the feather sums plus the max-weight composite of eq. 4.7.

A tile keeps, besides the feather sums, the colour ``best``, weight ``best_w`` and index ``best_id``
of the frame of largest warped feather weight (eq. 4.7, :func:`.blend.update_max_weight`); rendering
blends that composite over the feather one band by band (Table 2, eqs 4.8 to 4.10,
:func:`.blend.multiband_blend`). With ``seams: cut`` a graph cut (:mod:`.frame_cut`) moves the seams
to where the frames agree.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .blend import update_max_weight
from .canvas_settings import FeatherSettings, MultibandSettings
from .feather_compositor import FeatherCompositor
from .frame_cut import PaintJob, cut_masks, gather_winners
from .seam_cut import block_means, block_size
from .tile_store import TileLayout

__all__ = ['MultibandCompositor']


class MultibandCompositor(FeatherCompositor):
    """Feather sums and the max-weight composite (eq. 4.7) of multi-band blending."""

    blend = 'multiband'

    def __init__(self, feather: FeatherSettings, settings: MultibandSettings) -> None:
        super().__init__(feather)
        self.settings = settings

    @property
    def seam_cut(self) -> bool:
        return self.settings.seams == 'cut'

    def layout(self, tile_size: int, channels: int) -> TileLayout:
        """``acc``, ``wsum`` and the max-weight composite ``best``, ``best_w``, ``best_id``."""
        return TileLayout(tile_size, channels, True, False, 0)

    def cut(self, jobs: list[PaintJob], tiles: list[Any], img_w: np.ndarray, w_w: np.ndarray, index: int,
            channels: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The seams' cut (:func:`.frame_cut.cut_masks`) with the log of the mean feather weight as the
        score of the frame and of the winners; a block with a pixel no frame won is never free."""
        s = block_size(*w_w.shape)
        best, best_w = gather_winners(jobs, tiles, w_w.shape, channels, 0.0, None)  # weights, 0: none
        score = np.log(np.maximum(block_means(w_w, s), np.float32(1e-30)))
        winners = np.log(np.maximum(block_means(best_w, s), np.float32(1e-30)))
        winners[block_means(best_w <= 0, s) > 0] = -1e30
        return cut_masks(score, winners, img_w, best, s)

    def offer(self, tile: Any, loc: tuple[slice, slice], colour: np.ndarray, weight: np.ndarray, index: int,
              cut: tuple[np.ndarray, np.ndarray] | None) -> None:
        """The feather sums, then the max-weight composite: the frame wins where its weight is the
        largest (or where the cut gives it the pixel)."""
        super().offer(tile, loc, colour, weight, index, cut)
        update_max_weight(tile, loc, colour, weight, index, cut=cut)
