"""Exposure compensation: one gain per frame (and colour channel) so that overlapping frames agree.

Stills are exposed one by one (auto exposure, auto white balance), and a mosaic composited by best
view shows each still's exposure as a patch with a step at every seam. As in Brown and Lowe (IJCV
2007, sec. 6) the gains g make the overlaps agree,

    g_i I_ij = g_j I_ji   for every overlapping pair (i, j),

with I_ij frame i over its overlap with frame j. Here, in logarithms x = log g,
x_i - x_j = log(I_ji / I_ij), the right side the median of the log ratio over the overlap (a car or
a roof's parallax does not move it), each pair weighted by its overlap's size, solved by robust
(Huber) least squares with a weak prior x = 0, then shifted so that the median frame keeps its
exposure. Brown and Lowe's prior (sigma_g 0.1 against sigma_N 10 grey levels, which OpenCV's
compensators use) pulls every gain towards 1 as hard as the data, so a large step is only partly
undone, and its mean level lets a few dark frames darken all the others; the level is all a prior
has to set. The ratios need no detail: frames are compared as thumbnails warped onto a coarse
common raster.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ['EXPOSURE_MODES', 'MAX_GAIN', 'THUMB_SIDE_PX', 'exposure_gains']

#: 'channels': a gain per colour channel (exposure and white balance); 'gain': one per frame
#: (exposure); 'none': no compensation.
EXPOSURE_MODES = ('channels', 'gain', 'none')
#: The coarse raster's pixel: the median frame's footprint is about this many pixels across.
THUMB_SIDE_PX = 128
#: Pairs overlapping on fewer coarse pixels are not compared.
MIN_OVERLAP_PX = 64
#: Thumbnail levels outside (CLIPPED_LOW, CLIPPED_HIGH) are clipped: left out of the ratios.
CLIPPED_LOW, CLIPPED_HIGH = 3.0, 252.0
#: The prior's weight per frame, in units of the mean pair's weight: it sets the common level and
#: the gain of a frame that overlaps none (1), and moves no connected gain by more than a fraction
#: of a percent.
PRIOR_WEIGHT = 1e-3
#: Huber threshold of a pair's log ratio residual (about 5 %: more is a pair that disagrees, e.g.
#: moving objects or a misplaced frame, not an exposure).
HUBER_LOG = 0.05
IRLS_ITERATIONS = 5
#: Gains are clipped to [1 / MAX_GAIN, MAX_GAIN].
MAX_GAIN = 2.0


def exposure_gains(thumbs: list[np.ndarray | None], raster_H_thumb: list[np.ndarray | None],
                   mode: str = 'channels') -> np.ndarray:
    """Gains (n, C) float32 that multiply each frame's intensities (in the thumbnails' channel order).

    thumbs: per frame a uint8 (h, w, C) thumbnail (C = 3, or 1 for grey frames), or None for a
        frame left out (gain 1). raster_H_thumb: per frame the (3, 3) homography from thumbnail
        pixels to a common raster in any unit (a coarse version of the mosaic's), or None.
    mode: one of EXPOSURE_MODES ('gain': the same gain on every channel; 'none': all ones).

    In each set of frames connected by overlaps the median gain is 1; a frame that overlaps no
    other keeps gain 1. Gains stay within [1 / MAX_GAIN, MAX_GAIN]. Raises ValueError for an unknown
    mode or mismatched lists.
    """
    import scipy.sparse as sp  # here, not at the top: the configuration imports EXPOSURE_MODES without scipy
    from scipy.sparse.csgraph import connected_components

    if mode not in EXPOSURE_MODES:
        msg = f'exposure mode {mode!r} is not one of {", ".join(EXPOSURE_MODES)}.'
        raise ValueError(msg)
    if len(thumbs) != len(raster_H_thumb):
        msg = f'{len(thumbs)} thumbnails but {len(raster_H_thumb)} homographies.'
        raise ValueError(msg)
    n = len(thumbs)
    channels = next((1 if t.ndim == 2 else t.shape[2] for t in thumbs if t is not None), 3)
    gains = np.ones((n, channels), np.float32)
    if mode == 'none':
        return gains
    warped = _warp_to_coarse_raster(thumbs, raster_H_thumb)
    pairs, logs, weights = _overlap_log_ratios(warped, mode)
    if not pairs:
        return gains
    pairs_a = np.array(pairs)
    x = _solve_log_gains(n, pairs_a, np.array(logs), np.array(weights))
    # the common level: the median frame of each connected set keeps its exposure (most stills
    # keep their look, the odd ones are brought to them)
    _, label = connected_components(sp.coo_matrix((np.ones(len(pairs_a)), (pairs_a[:, 0], pairs_a[:, 1])), shape=(n, n)),
                                    directed=False)
    for c in np.unique(label):
        members = label == c
        x[members] -= np.median(x[members], axis=0)
    np.clip(x, -math.log(MAX_GAIN), math.log(MAX_GAIN), out=x)
    return np.exp(x).astype(np.float32) if mode == 'channels' else np.repeat(np.exp(x), channels, axis=1).astype(np.float32)


def _warp_to_coarse_raster(thumbs: list[np.ndarray | None],
                           raster_H_thumb: list[np.ndarray | None]) -> dict[int, tuple[int, int, np.ndarray, np.ndarray]]:
    """{frame: (x0, y0, log image (h, w, C) float32, valid (h, w) bool)} on a raster where the median
    frame is THUMB_SIDE_PX across; frames crossing the horizon or spread over a far field are left out."""
    used = [k for k in range(len(thumbs)) if thumbs[k] is not None and raster_H_thumb[k] is not None
            and np.all(np.isfinite(raster_H_thumb[k]))]
    if len(used) < 2:
        return {}
    sides = [math.sqrt(abs(np.linalg.det(raster_H_thumb[k][:2, :2] / raster_H_thumb[k][2, 2])))
             * max(thumbs[k].shape[:2]) for k in used]
    to_coarse = np.diag([THUMB_SIDE_PX / float(np.median(sides))] * 2 + [1.0])
    out = {}
    for k in used:
        t = thumbs[k] if thumbs[k].ndim == 3 else thumbs[k][:, :, None]
        h, w = t.shape[:2]
        H = to_coarse @ raster_H_thumb[k]
        quad = np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]]) @ H.T
        if np.any(quad[:, 2] <= 0):
            continue  # crosses the horizon on the raster
        xy = quad[:, :2] / quad[:, 2:]
        x0, y0 = np.floor(xy.min(axis=0)).astype(int)
        x1, y1 = np.ceil(xy.max(axis=0)).astype(int) + 1
        if (x1 - x0) * (y1 - y0) > 64 * THUMB_SIDE_PX ** 2:
            continue  # an oblique far field: not a footprint to compare
        shift = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1]]) @ H
        size = (int(x1 - x0), int(y1 - y0))
        image = cv2.warpPerspective(np.ascontiguousarray(t, np.float32), shift, size, flags=cv2.INTER_AREA
                                    if abs(np.linalg.det(shift[:2, :2])) < 1 else cv2.INTER_LINEAR)
        # eroded by a pixel: the warp's border pixels are mixed with the black outside; clipped
        # pixels (saturated or black) say nothing about the exposure
        inside = cv2.erode(cv2.warpPerspective(np.full((h, w), 255, np.uint8), shift, size, flags=cv2.INTER_NEAREST),
                           np.ones((3, 3), np.uint8)) > 0
        image = image.reshape(size[1], size[0], -1)
        valid = inside & np.all((image > CLIPPED_LOW) & (image < CLIPPED_HIGH), axis=2)
        out[k] = (int(x0), int(y0), np.log(np.maximum(image, np.float32(CLIPPED_LOW))), valid)
    return out


def _overlap_log_ratios(warped: dict[int, tuple[int, int, np.ndarray, np.ndarray]],
                        mode: str) -> tuple[list[tuple[int, int]], list[np.ndarray], list[float]]:
    """Per overlapping pair (i, j): log(I_ji / I_ij) per channel (one for 'gain': the channels' mean)
    as the median over the overlap's coarse pixels, and its weight (pixels)."""
    keys = sorted(warped)
    if len(keys) < 2:
        return [], [], []
    box = np.array([[warped[k][0], warped[k][1], warped[k][0] + warped[k][2].shape[1],
                     warped[k][1] + warped[k][2].shape[0]] for k in keys])
    pairs, logs, weights = [], [], []
    for a in range(len(keys)):
        hit = np.nonzero((box[a + 1:, 0] < box[a, 2]) & (box[a + 1:, 2] > box[a, 0])
                         & (box[a + 1:, 1] < box[a, 3]) & (box[a + 1:, 3] > box[a, 1]))[0] + a + 1
        for b in hit:
            i, j = keys[a], keys[b]
            x0, y0 = max(box[a, 0], box[b, 0]), max(box[a, 1], box[b, 1])
            x1, y1 = min(box[a, 2], box[b, 2]), min(box[a, 3], box[b, 3])
            if (x1 - x0) * (y1 - y0) < MIN_OVERLAP_PX:
                continue
            (xi, yi, im_i, ok_i), (xj, yj, im_j, ok_j) = warped[i], warped[j]
            both = ok_i[y0 - yi:y1 - yi, x0 - xi:x1 - xi] & ok_j[y0 - yj:y1 - yj, x0 - xj:x1 - xj]
            count = int(both.sum())
            if count < MIN_OVERLAP_PX:
                continue
            ratio = im_j[y0 - yj:y1 - yj, x0 - xj:x1 - xj][both] - im_i[y0 - yi:y1 - yi, x0 - xi:x1 - xi][both]
            if mode == 'gain':
                ratio = ratio.mean(axis=1, keepdims=True)  # the log of the channels' geometric mean
            # the median of the coarse pixels' log ratios: each coarse pixel averages many of the
            # frame's, and up to half the overlap may be something that moved or stands up
            pairs.append((i, j))
            logs.append(np.median(ratio, axis=0))
            weights.append(float(count))
    return pairs, logs, weights


def _solve_log_gains(n: int, pairs: np.ndarray, logs: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(n, C) x minimising sum_p w_p rho(x_i - x_j - d_p) + PRIOR_WEIGHT mean(w) sum_i x_i^2 (rho:
    Huber at HUBER_LOG), by iteratively reweighted least squares; pairs (P, 2), logs d (P, C), weights (P,)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    rows = np.arange(len(pairs))
    A = sp.csr_matrix((np.r_[np.ones(len(pairs)), -np.ones(len(pairs))], (np.r_[rows, rows], np.r_[pairs[:, 0], pairs[:, 1]])),
                      shape=(len(pairs), n))
    prior = PRIOR_WEIGHT * float(weights.mean())
    x = np.zeros((n, logs.shape[1]))
    robust = np.ones_like(logs)  # the first solve by least squares: x = 0 is no estimate to judge pairs by
    for _ in range(IRLS_ITERATIONS):
        for c in range(logs.shape[1]):
            w = weights * robust[:, c]
            normal = (A.T @ sp.diags(w) @ A + prior * sp.identity(n)).tocsc()
            x[:, c] = spla.spsolve(normal, A.T @ (w * logs[:, c]))
        r = A @ x - logs
        robust = np.minimum(1.0, HUBER_LOG / np.maximum(np.abs(r), 1e-12))  # Huber's IRLS weight per channel
    return x
