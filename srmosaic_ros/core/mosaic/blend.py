"""Blending helpers of the mosaic canvas: feather weights and multi-band (Laplacian pyramid) blending.

Pure numpy / OpenCV; every array is float32.

Feather weights
---------------
``feather_weight(h, w)`` is, by default, the dissertation's ``W(x, y) = w(x) w(y)`` (section
4.2.5: each factor linear from 1 at the centre to ~0 at the edge; with pixel centres at integers
``w(u) = min(u + 1, W - u) / max``). The ``'distance'`` profile is the distance to the frame
border, ``min(u + 1, v + 1, W - u, H - v) / max``; it is worse where two frames share an edge
(both weigh the same next to it, so the blend jumps to 50/50 there). With a validity mask the
weight also fades to 0 towards invalid pixels (``cv2.distanceTransform``).

Multi-band blending on an incremental canvas
--------------------------------------------
Burt and Adelson's multi-band blend (dissertation Table 2, eqs 4.8 to 4.10) needs every frame's
image at render time, which a growing canvas cannot keep. The canvas keeps two composites
instead, both updated frame by frame:

- ``F``, the feather composite: ``sum_i W_i I_i / sum_i W_i`` (smooth, no seams, but
  misregistration shows as ghosting of fine detail);
- ``S``, the max-weight composite of eq. 4.7: each mosaic pixel holds the pixel of the frame with
  the largest warped feather weight ``W_H^i`` (sharp, one frame per pixel, but hard seams), and
  the label map of which frame that was.

``multiband_blend`` then runs Table 2 with A = S and B = F: it forms the Laplacian pyramids
(``cv2.pyrDown`` / ``cv2.pyrUp``: the 5x5 Burt kernel of eqs 4.8, 4.9; ``L_l = G_l - expand(G_{l+1})``,
eq. 4.10) and blends level by level, ``LS_l = GR_l LA_l + (1 - GR_l) LB_l``. The region weights
``GR_l`` come from the distance ``d`` (mosaic pixels) to the nearest seam of the label map:
``GR_l = clip((d / 2**l - SEAM_NEAR) / SEAM_RAMP, 0, 1)``, so level ``l`` switches from the
feather composite at a seam to the max-weight composite over a transition about ``2**l`` pixels
wide, which is what blending with Gaussian-pyramid masks does (the transition width of band ``l``
grows as ``2**l``). The coarsest level always comes from ``F``. Consequences:

- where only one frame covers a pixel, ``S == F`` and the output is that frame;
- far from seams the output keeps the single best frame's fine detail (no ghosting) on top of
  the feather composite's low frequencies (brightness differences spread over the overlap);
- at seams, a brightness step is spread over about ``2**l`` pixels in band ``l``: no hard edge.

Since the pyramids are linear, this is computed as
``out = F + sum_{l < N} GR_l * L_l(S - F)`` (expanded and summed), which is also what makes
uncovered pixels harmless: ``S - F`` is zero there.

The canvas's per-tile arithmetic for both composites lives here too: ``feather_divide`` (F from the
tile sums), ``update_max_weight`` (S, eq. 4.7, frame by frame) and ``pyramid_region`` (the grid the
pyramids of a render run on).
"""
from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

from .seam_cut import combine

if TYPE_CHECKING:
    from .tile_store import Tile

__all__ = [
    'FEATHER_PROFILES',
    'MULTIBAND_MARGIN',
    'SEAM_NEAR',
    'SEAM_RAMP',
    'auto_bands',
    'copy_where',
    'feather_divide',
    'feather_weight',
    'multiband_blend',
    'pyramid_region',
    'seam_distance',
    'update_max_weight',
]

FEATHER_PROFILES = ('distance', 'separable')

#: At pyramid level l the max-weight composite is not used within SEAM_NEAR * 2**l pixels of a
#: seam and fully used beyond (SEAM_NEAR + SEAM_RAMP) * 2**l pixels.
SEAM_NEAR = 2.0
SEAM_RAMP = 2.0

#: Most pyramid levels chosen automatically (coarsest band spacing 2**MAX_AUTO_BANDS pixels).
MAX_AUTO_BANDS = 6

#: Multiband renders read this many times 2**bands pixels around the region (pyramid support).
MULTIBAND_MARGIN = 2


def _profile_norm(h: int, w: int) -> np.float32:
    """Largest distance of a pixel centre of an (h, w) frame to its border, + 0.5 px."""
    return np.float32(min((w + 1) // 2, (h + 1) // 2))


@lru_cache(maxsize=16)
def _profile(h: int, w: int, kind: str) -> np.ndarray:
    """(h, w) float32 feather profile in (0, 1], read-only (cached)."""
    u = np.arange(w, dtype=np.float32)
    v = np.arange(h, dtype=np.float32)
    du = np.minimum(u + 1.0, w - u)  # distance of the pixel centre to the border at -0.5 / w - 0.5, + 0.5
    dv = np.minimum(v + 1.0, h - v)
    if kind == 'distance':
        out = np.minimum(dv[:, None], du[None, :]) / np.float32(min(du.max(), dv.max()))
    else:  # separable, eq. W(x, y) = w(x) w(y) of section 4.2.5
        out = (dv / dv.max())[:, None] * (du / du.max())[None, :]
    out = np.ascontiguousarray(out, dtype=np.float32)
    out.setflags(write=False)
    return out


def feather_weight(
    h: int,
    w: int,
    *,
    profile: str = 'separable',
    power: float = 1.0,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Feather weight of an (h, w) frame, float32 (h, w) in [0, 1].

    ``profile='separable'`` (default): ``w(u) w(v)`` with ``w(u) = min(u + 1, w - u) / max``, the
    dissertation's ``W(x, y) = w(x) w(y)``; ``'distance'``: ``min(u + 1, v + 1, w - u, h - v) / max``
    (distance to the frame border, + 0.5 px). Pixel centres at integers. ``mask`` (bool (h, w),
    True = valid): invalid pixels weigh 0, and the profile is multiplied by ``d_mask / d_border``
    (distance to the nearest invalid pixel or border over distance to the border alone,
    ``cv2.distanceTransform``), so the frame fades out around masked areas as it does at its
    border. The result is raised to ``power``.
    """
    if profile not in FEATHER_PROFILES:
        msg = f"feather profile must be one of {', '.join(FEATHER_PROFILES)}, got {profile!r}."
        raise ValueError(msg)
    base = _profile(h, w, profile)
    if mask is None:
        out = base if power == 1.0 else np.power(base, np.float32(power))
        return out
    padded = np.zeros((h + 2, w + 2), np.uint8)
    padded[1:-1, 1:-1] = mask
    dist = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_5)[1:-1, 1:-1]
    # dist / (distance to the border alone): 1 away from invalid pixels, -> 0 next to them.
    fade = np.minimum(dist / (_profile(h, w, 'distance') * _profile_norm(h, w)), np.float32(1.0))
    out = base * fade
    if power != 1.0:
        out = np.power(out, np.float32(power))
    return np.ascontiguousarray(out, dtype=np.float32)


def auto_bands(h: int, w: int) -> int:
    """Number of pyramid levels for an (h, w) render: ``clip(floor(log2(min(h, w))) - 3, 1, 6)``."""
    side = max(1, min(h, w))
    return int(np.clip(int(np.floor(np.log2(side))) - 3, 1, MAX_AUTO_BANDS))


def seam_distance(labels: np.ndarray) -> np.ndarray:
    """Distance (px, float32 (h, w)) of each pixel to the nearest seam of a label map.

    ``labels``: int (h, w), the frame that wins each pixel (eq. 4.7), -1 where uncovered. A seam
    pixel is a covered pixel whose right or lower covered neighbour has another label (the
    coverage border is no seam). Without any seam the distance is +inf.
    """
    seam = np.zeros(labels.shape, bool)
    a, b = labels[:, :-1], labels[:, 1:]
    diff = (a != b) & (a >= 0) & (b >= 0)
    seam[:, :-1] |= diff
    a, b = labels[:-1, :], labels[1:, :]
    diff = (a != b) & (a >= 0) & (b >= 0)
    seam[:-1, :] |= diff
    if not seam.any():
        return np.full(labels.shape, np.inf, np.float32)
    return cv2.distanceTransform((~seam).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)


def _pyr_down(img: np.ndarray) -> np.ndarray:
    return cv2.pyrDown(img).reshape(((img.shape[0] + 1) // 2, (img.shape[1] + 1) // 2, *img.shape[2:]))


def _pyr_up(img: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    return cv2.pyrUp(img, dstsize=(shape[1], shape[0])).reshape(shape)


def multiband_blend(
    feather: np.ndarray,
    seam_image: np.ndarray,
    labels: np.ndarray,
    bands: int,
    *,
    coarsest_by_seams: bool = False,
) -> np.ndarray:
    """Multi-band blend of the max-weight composite over the feather composite (Table 2).

    ``feather`` F and ``seam_image`` S: float32 (h, w, C), equal to each other (or both 0) where
    a single frame or none covers; ``labels``: int32 (h, w), winning frame per pixel (eq. 4.7),
    -1 where uncovered; ``bands``: pyramid levels N >= 1. Returns float32 (h, w, C):
    ``F + collapse(GR_l * L_l(S - F) for l < N)``, see the module docstring. ``coarsest_by_seams``:
    the coarsest Gaussian level too is taken from S by its region weight GR_N (Table 2 blends
    every level), so a region without seams renders as S exactly (the best-view compositor, whose F
    is a two-frame composite, not a smooth average of every frame).
    """
    diff = _sub(seam_image, feather)
    if not diff.any():
        return feather.copy()
    dist = seam_distance(labels)
    # Laplacian pyramid of the difference (eqs 4.8 to 4.10).
    gauss = [diff]
    for _ in range(bands):
        if min(gauss[-1].shape[:2]) < 2:
            break
        gauss.append(_pyr_down(gauss[-1]))
    levels = len(gauss) - 1
    if levels == 0:
        return feather.copy()
    def region_weight(lev: int, shape: tuple[int, ...]) -> np.ndarray:
        if np.isinf(dist).all():
            return np.ones(shape[:2], np.float32)
        d = dist if lev == 0 else cv2.resize(dist, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
        return np.clip((d / float(2**lev) - SEAM_NEAR) / SEAM_RAMP, 0.0, 1.0).astype(np.float32)

    # collapsed blend of levels > l; the coarsest band comes from F unless coarsest_by_seams
    top = gauss[levels]
    acc: np.ndarray | None = _times(top, region_weight(levels, top.shape)) if coarsest_by_seams else None
    for lev in range(levels - 1, -1, -1):
        g = gauss[lev]
        band = _times(_sub(g, _pyr_up(gauss[lev + 1], g.shape)), region_weight(lev, g.shape))
        acc = band if acc is None else _add(band, _pyr_up(acc, g.shape))
    assert acc is not None
    return _add(feather, acc)


# Element-wise float32 arithmetic by OpenCV: the same IEEE operations (one rounding each) as numpy's
# operators, whose broadcasting over the channel axis runs element by element (several times slower
# on (h, w, 3) images). Any layout OpenCV does not take (float64, non-contiguous) goes numpy's way.
def _cv_ready(*arrays: np.ndarray) -> bool:
    return all(a.dtype == np.float32 and a.flags.c_contiguous and a.ndim == 3 for a in arrays)


def _sub(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """float32 a - b, a and b (h, w, C) of one shape."""
    if not _cv_ready(a, b):
        return (a - b).astype(np.float32, copy=False)
    return cv2.subtract(a, b).reshape(a.shape)


def _add(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """float32 a + b, a and b (h, w, C) of one shape."""
    if not _cv_ready(a, b):
        return (a + b).astype(np.float32, copy=False)
    return cv2.add(a, b).reshape(a.shape)


def _times(a: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """float32 a * weight[..., None], a (h, w, C), weight float32 (h, w)."""
    if not (_cv_ready(a) and weight.dtype == np.float32 and weight.flags.c_contiguous):
        return a * weight[..., None]
    c = a.shape[2]
    if c == 1:
        return cv2.multiply(a.reshape(weight.shape), weight).reshape(a.shape)
    expanded = cv2.cvtColor(weight, cv2.COLOR_GRAY2RGB) if c == 3 else cv2.merge([weight] * c)
    return cv2.multiply(a, expanded).reshape(a.shape)


def feather_divide(acc: np.ndarray, wsum: np.ndarray, out: np.ndarray) -> np.ndarray:
    """The feather composite ``acc / wsum`` (acc (h, w, C), wsum (h, w)) written into ``out`` (h, w, C)
    where ``wsum > 0``, ``out`` left as it is elsewhere; returns that coverage, bool (h, w)."""
    covered = wsum > 0
    if _cv_ready(acc, out) and acc.shape[2] == 3 and wsum.dtype == np.float32 and wsum.flags.c_contiguous:
        # OpenCV's division (IEEE, as numpy's) of whole rows, copied where covered (0 / 0 elsewhere)
        quotient = cv2.divide(acc, cv2.cvtColor(wsum, cv2.COLOR_GRAY2RGB))
        copy_where(out, quotient, covered)
    else:
        np.divide(acc, wsum[..., None], out=out, where=covered[..., None])
    return covered


def update_max_weight(tile: Tile, loc: tuple[slice, slice], colour: np.ndarray, weight: np.ndarray, index: int,
                      cut: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Offer a frame's warped pixels to the max-weight composite of a multiband tile (eq. 4.7).

    loc: the tile slices written; colour (h, w, C) and weight (h, w) the frame's warped colour and
    feather weight there; index: the frame's label. Where ``weight`` exceeds the tile's ``best_w``
    the frame wins: ``best``, ``best_w`` and ``best_id`` take its colour, weight and index. cut: the
    seams' graph cut (:mod:`.seam_cut`), (free, take) bool (h, w): where free, the frame wins where
    it sees the pixel and take says so, not where its weight is larger.
    """
    assert tile.best is not None and tile.best_w is not None and tile.best_id is not None
    best_w = tile.best_w[loc]
    upd = weight > best_w  # eq. 4.7: the frame of largest weight wins; ties keep the first
    if cut is not None:
        upd = combine(upd, weight > 0, *cut)
    if upd.any():
        copy_where(tile.best[loc], colour, upd)
        copy_where(best_w, weight, upd)
        copy_where(tile.best_id[loc], np.full(upd.shape, index, np.int32), upd)


def copy_where(dst: np.ndarray, src: np.ndarray, mask: np.ndarray) -> None:
    """dst[mask] = src[mask] in place; dst, src (h, w) or (h, w, C), mask bool (h, w). OpenCV's
    masked copy, faster than numpy's ``copyto(where=)`` on these tile views."""
    out = cv2.copyTo(src, mask.view(np.uint8), dst)
    if out is not dst:  # a layout OpenCV could not write in place: numpy's way
        np.copyto(dst, src, where=mask[..., None] if dst.ndim == 3 else mask)


def pyramid_region(region: tuple[int, int, int, int], bands: int) -> tuple[int, int, int, int]:
    """The region (x0, y0, x1, y1) the pyramids of a ``bands``-level render of ``region`` run over.

    ``region`` grown by MULTIBAND_MARGIN * 2**bands pixels and snapped to multiples of 2**bands in
    mosaic coordinates, so every render samples the same pyramid grid and a region renders the same
    (to ~1e-5) alone, inside a larger region or in blocks.
    """
    x0, y0, x1, y1 = region
    step = 2**bands
    margin = MULTIBAND_MARGIN * step
    ex0, ey0 = (x0 - margin) // step * step, (y0 - margin) // step * step
    ex1, ey1 = -((-(x1 + margin)) // step) * step, -((-(y1 + margin)) // step) * step
    return ex0, ey0, ex1, ey1
