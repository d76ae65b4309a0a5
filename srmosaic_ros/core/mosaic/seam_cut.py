"""Seams where frames agree: a graph cut between a new frame and the best-view winners under it.

Best view (best_view.py) gives each mosaic pixel to the frame of highest score; its seams lie where
the scores cross, whatever is there: a seam through a building cuts a roof that the two views see
displaced by parallax, one through a car doubles or halves it. Here the new frame's region is
chosen by a minimum cut (Boykov-Kolmogorov max-flow, PyMaxflow) of the labelling L (1: the new
frame shows the pixel, 0: the winner stays) minimising

    E(L) = sum_p kappa |d_p| [L_p != sign of d_p] + sum_{p~q} [L_p != L_q] (e_p + e_q + eps)

where d_p = score_new - score_winner (the log view quality of best_view.py, so the cut departs from
the best view only where it costs), and e_p the largest channel of |the mean of new - winner| over
the node (the signed mean, so that noise averages out and a misregistration's or a moving object's
difference does not): a seam costs its length in disagreement. The nodes are blocks of s x s
pixels of the paint's box (at most MAX_NODES: s = 7 px for a 640 x 480 frame on a mosaic of its
own sampling; the blending across seams spreads them over more anyway), data costs scaled by a
block's area s^2 and edge costs by its side s; a block's score is the log of its mean view quality,
its winners' the mean of theirs. Blocks where one view is more than SEAM_SLACK better (a factor of
2 in view quality), or with a pixel no frame painted yet, keep the scores' decision pixel by pixel;
the cut moves the seam inside that corridor only, and never gives the frame a pixel it does not see.

Each frame is cut against the mosaic as it is (incremental, per paint), as a live mosaic must. The
data weight KAPPA is small on purpose: a stronger pull toward the scores' seam kept the cars and
trails the cut is for (bench/parallax.py); the price is that where frames agree at block scale but
one is blurrier (the view score does not see blur), the older view may stay (docs/results.md, "Seams", and
docs/guide/compositing.md, for the figures and why `mosaic.seams` is 'score' by default).
"""
from __future__ import annotations

import math

import cv2
import maxflow
import numpy as np

__all__ = ['SEAM_SLACK', 'block_means', 'block_size', 'combine', 'cut_nodes', 'expand']

#: Largest score difference (log view quality) the cut may overrule: a view twice as good wins anyway.
SEAM_SLACK = math.log(2.0)
#: Data weight per pixel and unit score difference, against seam costs per pixel of length (intensity).
KAPPA = 0.01
#: Cost of a seam per pixel of length where the frames agree exactly (prefers short seams).
EPS = 0.01
#: Nodes of the graph at most (sets the block size s).
MAX_NODES = 8_000
_BIG = 1e9


def block_size(height: int, width: int) -> int:
    """Side s (px) of the graph's blocks over a (height, width) box: at most MAX_NODES blocks."""
    return max(1, math.ceil(math.sqrt(height * width / MAX_NODES)))


def cut_nodes(score: np.ndarray, best_w: np.ndarray, diff: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray]:
    """The cut on blocks: (free, take) bool (H, W), where the cut decides (free) and, there, where
    the new frame leads (take); elsewhere the scores decide.

    score, best_w: the new frame's and the winners' scores over each s x s block (H, W) (log of
    the mean view quality; a block with no winner somewhere: far below any score, e.g. -1e30, so
    that it is never free); diff: the mean of new - winner colour over each block (H, W, C).
    """
    delta = score - best_w
    free = np.abs(delta) < SEAM_SLACK
    if not free.any():
        return free, free
    e = np.abs(diff).max(axis=-1)  # the signed block mean: noise averages out, a misregistration does not
    lead = delta > 0
    # only the free nodes and a ring of fixed ones around them enter the graph
    rows, cols = np.flatnonzero(free.any(axis=1)), np.flatnonzero(free.any(axis=0))
    r0, r1 = max(int(rows[0]) - 1, 0), min(int(rows[-1]) + 2, free.shape[0])
    c0, c1 = max(int(cols[0]) - 1, 0), min(int(cols[-1]) + 2, free.shape[1])
    win = (slice(r0, r1), slice(c0, c1))
    nf, ne, nd, nl = free[win], e[win], np.where(free[win], delta[win], 0.0), lead[win]
    g = maxflow.Graph[float]()
    ids = g.add_grid_nodes(nf.shape)
    right = np.zeros(nf.shape)
    right[:, :-1] = s * (ne[:, :-1] + ne[:, 1:] + EPS)
    down = np.zeros(nf.shape)
    down[:-1] = s * (ne[:-1] + ne[1:] + EPS)
    g.add_grid_edges(ids, weights=right, structure=np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]]), symmetric=True)
    g.add_grid_edges(ids, weights=down, structure=np.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]]), symmetric=True)
    # label 1 (the new frame) is the sink side: a node there cuts its source edge, the cost of L = 1
    area = KAPPA * s * s
    cost1 = np.where(nf, area * np.maximum(-nd, 0.0), np.where(nl, 0.0, _BIG))
    cost0 = np.where(nf, area * np.maximum(nd, 0.0), np.where(nl, _BIG, 0.0))
    g.add_grid_tedges(ids, cost1, cost0)
    g.maxflow()
    take = np.zeros(free.shape, bool)
    take[win] = g.get_grid_segments(ids)
    return free, take & free


def block_means(a: np.ndarray, s: int) -> np.ndarray:
    """(h // s, w // s[, C]) float32 means of the s x s blocks of a (h, w[, C]) array (the last
    partial row and column of blocks left out)."""
    a = np.ascontiguousarray(a, dtype=np.float32)
    h, w = a.shape[:2]
    if s == 1:
        return a
    crop = a[:h // s * s, :w // s * s]
    return cv2.resize(crop, (w // s, h // s), interpolation=cv2.INTER_AREA)  # exact block means at an integer factor


def expand(nodes: np.ndarray, s: int, shape: tuple[int, int]) -> np.ndarray:
    """bool ``shape``: each node's value over its s x s block (False beyond the last whole block)."""
    out = np.zeros(shape, bool)
    big = cv2.resize(nodes.view(np.uint8), (nodes.shape[1] * s, nodes.shape[0] * s), interpolation=cv2.INTER_NEAREST)
    out[:big.shape[0], :big.shape[1]] = big.view(bool)
    return out


def combine(by_score: np.ndarray, seen: np.ndarray, free: np.ndarray, take: np.ndarray) -> np.ndarray:
    """Where the frame leads: the cut's decision where it is free and the frame sees the pixel, the
    scores' (``by_score``) elsewhere; all bool of one shape."""
    return np.where(free, take & seen, by_score)
