"""Best-view compositing: each mosaic pixel from the frame that sees it best, blended across seams only.

The reference's max-weight masks (eq. 4.7) give each mosaic pixel to the frame of largest feather
weight. Here the weight is a view quality with three factors, and the composite keeps, per mosaic
pixel, the winning frame's colour and the runner-up's:

    q_i(p) = f_i(p) * r_i(p)             f: the feather profile (closeness to the frame centre, 4.2.5)
    r_i(p) = min(1, 1 / s_i(p))          s: linear stretch of frame pixels on the mosaic, sqrt(det J)
    score_i(p) = log q_i(p) + i / n      i: the frame's paint count, n: ``recency_frames``

``r`` prefers frames that see the ground at a finer resolution (an oblique frame's far field, a
zoomed-out frame lose to closer views); the recency term makes a frame ``n`` frames newer win over
an e-fold better older one, so that where views are about as good the newer shows the ground. It
counts frames, not seconds: the overlap of consecutive frames is what a frame's rate sets (90
frames: 3 s of 30 fps video, where the newest frame keeps its own neighbourhood; for stills
seconds apart, 1/90 per still, the view quality alone decides). Scores are log-domain so that old
scores never need decaying. (Keyframes register to the canvas's feather composite, which under a
revisit still shows the first pass.)

Consensus (``agree``): frames that agree with the winner around a pixel (the signed difference
averaged over 5 x 5 pixels, so that noise averages out and a misregistration's does not, within
``agree`` on every channel, intensity) are averaged into it, weighted by their quality, whether they lead or not;
only a frame that disagrees (misregistration, parallax, something that moved) replaces it. Frames
of one scene that line up (a turret staring at a point) are thus averaged and their noise and
compression go down as in a feather blend, while the frames that disagree stay out of each other.

Seams lie where the winner changes: where the scores cross, or, with ``seams: cut``, where a graph
cut moved them to let the frames meet where they agree (seam_cut.py; the frame then leads where the
cut says, among views within a factor of 2 in quality). Rendering (Table 2, as in
:func:`.blend.multiband_blend`) replaces the reference's feather composite by the two-frame
composite ``T = (best + second) / 2`` (``best`` where no second frame covers the pixel): the output
is the winner's pixel away from seams, and across a seam every band switches from one frame to the
other over about 2**l pixels. Only the two frames that meet at a seam are mixed, never the average
of every frame that saw the ground, so a misregistered or moving-camera frame cannot blur the rest
of the mosaic.

Far field and sky (``max_stretch``): a frame whose view reaches the horizon maps the pixels near it
onto huge mosaic areas (the stretch grows as depth**-1.5, depth being the homography's third row
over the frame, linear in u, v), so frame pixels more than ``max_stretch`` times (linearly) coarser
than the frame's finest are left out: the kept part is the frame cut by a straight line, depth >=
depth_max * max_stretch**(-2/3).

All arrays are numpy float32 unless said; frame pixel centres at integer (u, v).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ..homography import corner_depths
from .blend import copy_where
from .scratch import scratch
from .seam_cut import combine

__all__ = ['clip_depth', 'clipped_polygon', 'depth_map', 'magnified_somewhere', 'resolution_factor', 'transition_image',
           'update_best']


def depth_map(m: np.ndarray, h: int, w: int) -> np.ndarray:
    """(h, w) float32: the projective depth ``m[2] @ (u, v, 1)`` of every frame pixel."""
    u = np.arange(w, dtype=np.float32) * np.float32(m[2, 0])
    v = np.arange(h, dtype=np.float32) * np.float32(m[2, 1]) + np.float32(m[2, 2])
    return np.add.outer(v, u)


#: Side (mosaic px) of the box over which a frame's agreement with the winner is judged.
AGREE_BOX = 5


def clip_depth(m: np.ndarray, w: int, h: int, max_stretch: float) -> float | None:
    """The least depth of the frame pixels kept under ``max_stretch`` (module docstring), or None when
    every pixel of the (w, h) frame is kept (or ``max_stretch`` is 0: no clipping).

    ``m``: (3, 3) mosaic_H_frame whose depth is positive somewhere over the frame.
    """
    if not max_stretch > 0:
        return None
    depth = corner_depths(m, w, h)
    d_min = float(depth.max()) * max_stretch ** (-2.0 / 3.0)
    return None if depth.min() >= d_min else d_min


def clipped_polygon(m: np.ndarray, corners: np.ndarray, d_min: float | None) -> np.ndarray:
    """(K, 2) frame points: the polygon ``corners`` (4, 2) cut to depth >= ``d_min`` (Sutherland-Hodgman
    against one half-plane); ``corners`` unchanged when ``d_min`` is None. K is 0 when nothing is left."""
    if d_min is None:
        return corners
    depth = corners @ m[2, :2] + m[2, 2]
    out: list[np.ndarray] = []
    n = len(corners)
    for i in range(n):
        a, b = corners[i], corners[(i + 1) % n]
        da, db = depth[i] - d_min, depth[(i + 1) % n] - d_min
        if da >= 0:
            out.append(a)
        if (da >= 0) != (db >= 0):
            out.append(a + (b - a) * (da / (da - db)))
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def resolution_factor(m: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(h, w) float32 ``r = min(1, 1 / s)``, s = sqrt(|det m| / depth**3) the linear stretch of each frame
    pixel on the mosaic (det J of the homography); 0 where depth <= 0. ``depth``: :func:`depth_map`."""
    det = abs(float(np.linalg.det(m)))
    if not det > 0:
        return np.ones_like(depth)
    # OpenCV's vectorised power on one array, not a numpy chain of six passes over the frame
    r = cv2.max(depth, 0.0)
    cv2.pow(r, 1.5, dst=r)
    cv2.multiply(r, 1.0 / math.sqrt(det), dst=r)
    return cv2.min(r, 1.0, dst=r)


def magnified_somewhere(m: np.ndarray, w: int, h: int) -> bool:
    """Whether :func:`resolution_factor` is below 1 anywhere over a (w, h) frame through mosaic_H_frame
    ``m``: some pixel lands larger than a mosaic pixel. Depth is linear over the frame, so its least
    value is at a corner; False (the factor is 1 everywhere: nothing to compute) only with a margin
    that float32 rounding cannot cross."""
    det = abs(float(np.linalg.det(m)))
    if not det > 0:
        return False  # resolution_factor is 1 everywhere then
    corners = np.array([[-0.5, -0.5, 1.0], [w - 0.5, -0.5, 1.0], [w - 0.5, h - 0.5, 1.0], [-0.5, h - 0.5, 1.0]])
    d = max(float((corners @ m[2]).min()), 0.0)
    return d ** 3 / det < 1.001


def _disagreement(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(h, w) the largest channel of |the AGREE_BOX^2 mean of a - b|, a, b (h, w, C)."""
    return _box_mean_abs_max(np.ascontiguousarray(a - b, dtype=np.float32))


def _box_mean_abs_max(delta: np.ndarray) -> np.ndarray:
    """(h, w) the largest channel of |the AGREE_BOX^2 mean of delta| (h, w, C) float32."""
    mean = np.abs(cv2.boxFilter(delta, -1, (AGREE_BOX, AGREE_BOX), borderType=cv2.BORDER_REPLICATE).reshape(delta.shape))
    if mean.shape[-1] == 1:
        return mean[..., 0]
    return cv2.reduce(mean.reshape(-1, mean.shape[-1]), 1, cv2.REDUCE_MAX).reshape(mean.shape[:2])


def update_best(tile: object, loc: tuple[slice, slice], colour: np.ndarray, q: np.ndarray, index: int,
                recency_frames: int, agree: float, moving: float = 0.0,
                cut: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Offer a frame's warped pixels to a best-view tile.

    tile: a :class:`.tile_store.Tile` of the best-view layout; loc: the tile slices written;
    colour (h, w, C) and q (h, w) the frame's warped colour and quality there (q 0: not seen);
    index: the frame's label and paint count; recency_frames: n of the score (0: no recency term);
    agree: the consensus threshold (intensity; 0: none). Where the frame's pixels are within ``agree``
    of the winner's (the largest channel of the difference averaged over AGREE_BOX^2 pixels), it joins
    the winner's consensus (its quality-weighted mean) and
    takes the lead label if its score is higher; where it disagrees and scores higher, it replaces
    the winner (which becomes the runner-up); where it disagrees and scores lower, it becomes the
    runner-up if it beats that one. moving: the vote against each pixel's background (0: none; the
    tile must have a ``hist``, TileLayout.history > 0; :func:`_moving_vote`): a frame that saw
    something move at a pixel is kept out of it whatever its score; a winner (runner-up) that saw
    something move where the frame agrees with the background is replaced by the frame. cut: the
    seams' graph cut (:mod:`.seam_cut`), (free, take) bool (h, w): where free, the frame leads
    where it sees the pixel and take says so, not where its score is higher; the scores stay the
    frames' own.
    """
    with np.errstate(divide='ignore'):  # log 0 = -inf: not seen, beaten by every score and beating none
        score = np.log(q, out=scratch('score', q.shape))  # lives until this update returns
    score += np.float32(index / recency_frames if recency_frames > 0 else 0.0)
    lead = None if cut is None else combine(score > tile.best_w[loc], q > 0, *cut)  # type: ignore[attr-defined]
    best, best_w, best_id, best_q = tile.best[loc], tile.best_w[loc], tile.best_id[loc], tile.best_q[loc]  # type: ignore[attr-defined]
    second, second_w = tile.second[loc], tile.second_w[loc]  # type: ignore[attr-defined]
    if not (agree > 0 or moving > 0):
        _update_scores_only(score, colour, q, index, best, best_w, best_id, best_q, second, second_w, lead)
        return
    seen = q > 0
    fresh = best_id < 0
    none = np.zeros(q.shape, bool)
    d_cb = _disagreement(colour, best) if agree > 0 else None
    best_moved, frame_moved, second_moved = none, none, none
    if moving > 0 and getattr(tile, 'hist', None) is not None:
        best_moved, frame_moved, second_moved = _moving_vote(tile, loc, colour, q, fresh, np.float32(moving))
    lead = (((score > best_w) if lead is None else lead) & ~frame_moved) | best_moved
    # consensus: the 5 x 5 mean of the signed difference, where noise averages out and a misregistration's does not
    joins = seen & ~fresh & (d_cb <= np.float32(agree)) & ~best_moved if (agree > 0 and d_cb is not None) else none
    take = lead & ~joins
    runner = seen & ~lead & ~joins & ~frame_moved & ((score > second_w) | second_moved)
    if joins.any():
        total = best_q + np.where(joins, q, np.float32(0.0))
        frac = np.where(joins, q / np.maximum(total, np.float32(1e-30)), np.float32(0.0))
        best += (colour - best) * frac[..., None]
        copy_where(best_q, total, joins)
    if take.any():
        replaced = take & ~fresh & ~best_moved  # a winner that saw something move is not kept as runner-up
        copy_where(second, best, replaced)
        copy_where(second_w, best_w, replaced)
        copy_where(best, colour, take)
        copy_where(best_q, q, take)
    if lead.any():
        copy_where(best_w, score, lead)
        copy_where(best_id, np.full(lead.shape, index, np.int32), lead)
    if runner.any():
        copy_where(second, colour, runner)
        copy_where(second_w, score, runner)


#: Samples a pixel's history must hold before its median is trusted as the background.
MIN_BACKGROUND_SAMPLES = 3


def _known_disagreement(a: np.ndarray, background: np.ndarray, known: np.ndarray) -> np.ndarray:
    """(h, w) :func:`_disagreement` of a (h, w, C) against ``background`` (h, w, C) where ``known``
    (h, w) bool: the other pixels add no difference to the box means."""
    mask = known.view(np.uint8)
    delta = np.zeros(background.shape, np.float32)
    out = cv2.subtract(a, background, dst=delta, mask=mask)  # zero where not known
    if out is not delta:  # a layout OpenCV could not write in place
        np.subtract(a, background, out=delta, where=known[..., None])
    # a change of exposure or white balance shifts the whole view: the median difference (every
    # 4th known pixel across and down, per channel) is taken out, what moved is what differs beyond it
    step = known[::4, ::4]
    if step.any():
        offset = np.median(delta[::4, ::4][step], axis=0)
        cv2.subtract(delta, tuple(float(v) for v in offset), dst=delta, mask=mask)
    return _box_mean_abs_max(delta)


def _median(hist: np.ndarray) -> np.ndarray:
    """The median over the first axis of K (odd) uint8 samples (K, ...): min/max networks for 3 and 5
    (OpenCV's saturating min and max, several times numpy's partition), else numpy's partition."""
    k = hist.shape[0]
    if k == 3:
        a, b, c = hist
        return cv2.max(cv2.min(a, b), cv2.min(cv2.max(a, b), c))
    if k == 5:  # median of 5 = median3(e, max(min(a, b), min(c, d)), min(max(a, b), max(c, d)))
        a, b, c, d, e = hist
        f, g = cv2.max(cv2.min(a, b), cv2.min(c, d)), cv2.min(cv2.max(a, b), cv2.max(c, d))
        return cv2.max(cv2.min(f, g), cv2.min(cv2.max(f, g), e))
    return np.partition(hist, k // 2, axis=0)[k // 2]


def _moving_vote(tile: object, loc: tuple[slice, slice], colour: np.ndarray, q: np.ndarray, fresh: np.ndarray,
                 thr: np.float32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(best_moved, frame_moved, second_moved) bool (h, w) against each pixel's background; then the
    frame's sample is taken into the history and the pixels it kept out counted (``moved``).

    The background is the median, channel by channel, of the pixel's last K colour samples before
    this frame (the tile's ``hist``): a car covers a ground point in fewer than half of them, so the
    median is the ground under it (robust, unlike the feather mean, to which every car that passed
    adds its colour); for the third view of a pixel, the median of the two before and this one's.
    Where the history holds at least MIN_BACKGROUND_SAMPLES - 1 samples (the background is
    known): the frame differs from the background by more than ``thr`` (the largest channel of the
    difference averaged over AGREE_BOX^2 pixels, as for ``agree``; unknown pixels add nothing to
    the means, or a frame's rim would be flagged where nothing moved): it saw something move there
    (frame_moved); the winner (runner-up) differs while the frame agrees: the winner (runner-up)
    did (best_moved, second_moved). The box mean halves a car's difference at its outline:
    frame_moved and best_moved are grown by the box.
    """
    hist, hist_n = tile.hist[:, loc[0], loc[1]], tile.hist_n[loc]  # type: ignore[attr-defined]
    k = hist.shape[0]
    seen = q > 0
    h, w, c = colour.shape
    if c == 1:  # OpenCV takes (h, w, 1) views as (h, w)
        hist = hist.reshape(k, h, w)
    background = _median(hist).astype(np.float32).reshape(h, w, c)
    background *= np.float32(1.0 / 255.0)
    third = seen & (hist_n == MIN_BACKGROUND_SAMPLES - 1)
    if third.any():  # the third view of a pixel: the median of the two before it and this frame's
        scale = np.float32(1.0 / 255.0)
        a, b = (hist[i].astype(np.float32).reshape(h, w, c) * scale for i in (0, 1))
        med3 = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), colour))
        copy_where(background, med3, third)
    known = seen & (hist_n >= MIN_BACKGROUND_SAMPLES - 1)
    kernel = np.ones((AGREE_BOX, AGREE_BOX), np.uint8)
    frame_moved = known & (_known_disagreement(colour, background, known) > thr)
    frame_moved = known & cv2.dilate(frame_moved.view(np.uint8), kernel).astype(bool)
    agrees = known & ~frame_moved
    best_moved = agrees & ~fresh & (_known_disagreement(tile.best[loc], background, known) > thr)  # type: ignore[attr-defined]
    best_moved = agrees & ~fresh & cv2.dilate(best_moved.view(np.uint8), kernel).astype(bool)
    second_moved = agrees & np.isfinite(tile.second_w[loc]) & (  # type: ignore[attr-defined]
        _known_disagreement(tile.second[loc], background, known) > thr)  # type: ignore[attr-defined]
    # the sample: into the ring slot n mod K of every pixel the frame sees
    sample = cv2.convertScaleAbs(colour.reshape(h, w * c), alpha=255.0).reshape(hist.shape[1:])  # rounded, saturated
    slot = hist_n % np.uint8(k)
    for i in range(k):
        copy_where(hist[i], sample, seen & (slot == i))
    np.add(hist_n, np.uint8(1), out=hist_n, where=seen)  # at most 254 before: 255 is set back below
    full = hist_n == 255
    if full.any():  # saturated: back by K every time, so the ring goes on turning
        hist_n[full] = 255 - k
    if frame_moved.any():
        moved = tile.moved[loc]  # type: ignore[attr-defined]
        np.add(moved, np.uint8(1), out=moved, where=frame_moved & (moved < 255))
    return best_moved, frame_moved, second_moved


def _update_scores_only(score: np.ndarray, colour: np.ndarray, q: np.ndarray, index: int, best: np.ndarray,
                        best_w: np.ndarray, best_id: np.ndarray, best_q: np.ndarray, second: np.ndarray,
                        second_w: np.ndarray, lead: np.ndarray | None = None) -> None:
    """update_best without consensus or moving vote: the frame leads where it scores higher (the
    winner becomes the runner-up) and is the runner-up where it beats that one only. The same
    updates as the general path, without its masks (the scores of unseen pixels are -inf)."""
    lead = score > best_w if lead is None else lead
    if lead.any():
        replaced = lead & (best_id >= 0)
        copy_where(second, best, replaced)
        copy_where(second_w, best_w, replaced)
        copy_where(best, colour, lead)
        copy_where(best_q, q, lead)
        copy_where(best_w, score, lead)
        copy_where(best_id, np.full(lead.shape, index, np.int32), lead)
    runner = score > second_w
    runner &= ~lead
    if runner.any():
        copy_where(second, colour, runner)
        copy_where(second_w, score, runner)


def transition_image(best: np.ndarray, second: np.ndarray, second_w: np.ndarray) -> np.ndarray:
    """(h, w, C) the two-frame composite ``T``: the mean of winner and runner-up, the winner alone where
    no second frame saw the pixel (``second_w`` -inf)."""
    two = np.isfinite(second_w)[..., None]
    out = np.add(best, second, dtype=np.float32)
    out *= np.float32(0.5)
    return np.where(two, out, best)
