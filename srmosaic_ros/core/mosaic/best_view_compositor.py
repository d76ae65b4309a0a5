"""Best-view compositing: each mosaic pixel from the frame that sees it best (:mod:`.best_view`).

A frame's weight is its view quality ``q = f * r`` (the feather profile times the resolution factor
``r = min(1, 1 / s)``, s the linear stretch of its pixels on the mosaic) and its score
``log q + i / n`` (n: ``recency_frames``); a tile keeps the winner's and the runner-up's colour and
score, with consensus (``agree``) and the vote on moving objects (``moving``) deciding which frames
are averaged in or kept out (:func:`.best_view.update_best`). With ``seams: cut`` a graph cut
(:mod:`.frame_cut`) moves the seams to where the frames agree.
"""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from .best_view import magnified_somewhere, resolution_factor, update_best
from .canvas_settings import BestViewSettings, FeatherSettings
from .feather_compositor import FeatherCompositor
from .frame_cut import PaintJob, cut_masks, gather_winners
from .seam_cut import block_means, block_size
from .tile_store import TileLayout

__all__ = ['BestViewCompositor']


class BestViewCompositor(FeatherCompositor):
    """Feather sums and the best-view composite, with consensus and the vote on moving objects."""

    blend = 'bestview'

    def __init__(self, feather: FeatherSettings, settings: BestViewSettings) -> None:
        super().__init__(feather)
        self.settings = settings

    @property
    def seam_cut(self) -> bool:
        return self.settings.seams == 'cut'

    @property
    def history(self) -> int:
        """Colour samples a tile keeps per pixel for the vote on moving objects (0: no vote)."""
        return self.settings.moving_history if self.settings.moving > 0 else 0

    def layout(self, tile_size: int, channels: int) -> TileLayout:
        """The best-view tile (:class:`.tile_store.TileLayout`), with the colour history of the vote."""
        return TileLayout(tile_size, channels, False, True, self.history)

    def rates_resolution(self, m: np.ndarray, w: int, h: int) -> bool:
        """The resolution factor is 1 everywhere (not computed) unless a frame pixel lands larger than
        a mosaic pixel somewhere."""
        return magnified_somewhere(m, w, h)

    def weight(self, h: int, w: int, valid: np.ndarray | None, m: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
        """The view quality q = f * r: the feather weight f times the resolution factor r where
        ``depth`` is given (:func:`.best_view.resolution_factor`)."""
        weight = super().weight(h, w, valid, m, depth)
        if depth is not None:
            r = resolution_factor(m, depth)
            weight = cv2.multiply(weight, r, dst=r)
        return weight

    def cut(self, jobs: list[PaintJob], tiles: list[Any], img_w: np.ndarray, w_w: np.ndarray, index: int,
            channels: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The seams' cut (:func:`.frame_cut.cut_masks`) with the scores of the composite: the frame's
        log mean quality plus its recency term i / n against the winners' log scores (a pixel no frame
        won is never free)."""
        s = block_size(*w_w.shape)
        best, best_w = gather_winners(jobs, tiles, w_w.shape, channels, -1e30, -1e30)  # log scores, -inf: none
        score = np.log(np.maximum(block_means(w_w, s), np.float32(1e-30)))
        recency = self.settings.recency_frames
        score += np.float32(index / recency if recency > 0 else 0.0)
        winners = block_means(best_w, s)
        return cut_masks(score, winners, img_w, best, s)

    def offer(self, tile: Any, loc: tuple[slice, slice], colour: np.ndarray, weight: np.ndarray, index: int,
              cut: tuple[np.ndarray, np.ndarray] | None) -> None:
        """The feather sums, then the best-view composite (:func:`.best_view.update_best`)."""
        super().offer(tile, loc, colour, weight, index, cut)
        s = self.settings
        update_best(tile, loc, colour, weight, index, s.recency_frames, s.agree, s.moving, cut=cut)
