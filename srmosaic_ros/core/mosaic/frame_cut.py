"""The seams' graph cut of one paint (``seams: cut``): the frame against the winners under it.

Both compositors that keep a winner per pixel (multiband's max-weight composite, best view) compare,
on blocks of ``s`` x ``s`` pixels of the paint's box (:func:`.seam_cut.block_size`), the frame's score
with the winners' and the frame's colour with theirs, and let :func:`.seam_cut.cut_nodes` move the
seams to where they agree. What differs is the score: a log view quality (best view) or the log of
a feather weight (multiband); each compositor forms its own and calls :func:`cut_masks`.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .seam_cut import block_means, cut_nodes, expand
from .tile_store import TileKey

__all__ = ['PaintJob', 'cut_masks', 'gather_winners']

#: one tile a paint writes: its key, its slices of the paint's box, its own slices
PaintJob = tuple[TileKey, tuple[slice, slice], tuple[slice, slice]]


def gather_winners(jobs: list[PaintJob], tiles: list[Any], shape: tuple[int, int], channels: int,
                   empty: float, floor: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(best, best_w): the winners' colour float32 (bh, bw, C) and score float32 (bh, bw) over the
    paint's box of ``shape`` (bh, bw), copied from the tiles of ``jobs``; ``empty`` outside them, and
    scores raised to ``floor`` (None: as stored)."""
    bh, bw = shape
    best = np.zeros((bh, bw, channels), np.float32)
    best_w = np.full((bh, bw), empty, np.float32)
    for (_, box, loc), tile in zip(jobs, tiles):
        best[box] = tile.best[loc]
        if floor is not None:
            np.maximum(tile.best_w[loc], np.float32(floor), out=best_w[box])
        else:
            best_w[box] = tile.best_w[loc]
    return best, best_w


def cut_masks(score: np.ndarray, winners: np.ndarray, img_w: np.ndarray, best: np.ndarray, s: int,
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """(free, take) bool (bh, bw) over the paint's box of the frame's colour ``img_w`` (bh, bw, C):
    where the cut decides and where the frame leads there, from the block scores of the frame
    (``score``) and of the winners (``winners``), and the winners' colour ``best``; None where the
    scores decide everywhere."""
    bh, bw = img_w.shape[:2]
    diff = block_means(img_w, s) - block_means(best, s)
    free, take = cut_nodes(score, winners, diff.reshape(*score.shape, -1), s)
    if not free.any():
        return None
    return expand(free, s, (bh, bw)), expand(take, s, (bh, bw))
