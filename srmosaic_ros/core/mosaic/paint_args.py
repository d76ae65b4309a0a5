"""The checks of ``TiledCanvas.paint``'s arguments: each returns the argument in the form the paint
uses, or raises a CanvasError naming the problem."""
from __future__ import annotations

from collections.abc import Collection, Mapping

import numpy as np

from .canvas_settings import CanvasError
from .tile_store import TileKey

__all__ = ['as_image', 'as_mask', 'as_rects', 'as_scale', 'as_tiles']


def as_image(image: np.ndarray, channels: int) -> np.ndarray:
    """(H, W, C) C-contiguous float32, or uint8 as given."""
    if not isinstance(image, np.ndarray):
        msg = f'image must be a numpy array, got {type(image).__name__}.'
        raise CanvasError(msg)
    if not (np.issubdtype(image.dtype, np.floating) or image.dtype == np.uint8):
        msg = (f'image dtype {image.dtype} is neither floating point nor uint8; convert it to float32 in [0, 1] '
               '(e.g. core.image_ops.to_float01).')
        raise CanvasError(msg)
    if image.ndim == 2 and channels == 1:
        image = image[:, :, None]
    if image.ndim != 3 or image.shape[2] != channels:
        msg = (f'image shape {image.shape} does not match the canvas: expected (H, W, {channels})'
               + (' or (H, W)' if channels == 1 else '') + '.')
        raise CanvasError(msg)
    if image.shape[0] < 1 or image.shape[1] < 1:
        msg = f'image shape {image.shape} is empty.'
        raise CanvasError(msg)
    return np.ascontiguousarray(image, dtype=np.uint8 if image.dtype == np.uint8 else np.float32)


def as_scale(scale: np.ndarray | None, channels: int) -> np.ndarray | None:
    """(C,) float32 positive finite multipliers, or None."""
    if scale is None:
        return None
    g = np.asarray(scale, dtype=np.float64).reshape(-1)
    if g.shape != (channels,) or not np.all(np.isfinite(g)) or not np.all(g > 0):
        msg = f'scale must be {channels} positive finite multipliers (one per channel), got {scale!r}.'
        raise CanvasError(msg)
    return g.astype(np.float32)


def as_mask(mask: np.ndarray | None, img: np.ndarray, finite: bool = False) -> np.ndarray | None:
    """Valid-pixel mask (bool (H, W)) or None when every pixel is valid and finite (``finite``: the
    caller knows it is, the image is not read)."""
    valid = None
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != img.shape[:2]:
            msg = f'mask shape {mask.shape} differs from the image shape {img.shape[:2]}.'
            raise CanvasError(msg)
        valid = mask.astype(bool)
    # fast path: the extremes (NaN propagates through both), the full check only if needed
    if not finite and not (np.isfinite(img.max()) and np.isfinite(img.min())):
        finite = np.isfinite(img).all(axis=2)
        if not finite.all():
            valid = finite if valid is None else valid & finite
    return valid


def as_tiles(tiles: Collection[TileKey]) -> tuple[frozenset[TileKey], tuple[int, int, int, int] | None]:
    """(``tiles`` as a frozenset, their (min tx, min ty, max tx, max ty) or None when empty);
    CanvasError when a key is not a pair of integers."""
    try:
        keys = frozenset((int(tx), int(ty)) for tx, ty in tiles)
    except (TypeError, ValueError) as exc:
        msg = f'tiles must be (tx, ty) pairs of integers: {exc}'
        raise CanvasError(msg) from exc
    if not keys:
        return keys, None
    a = np.array(list(keys), np.int64)
    lo, hi = a.min(axis=0), a.max(axis=0)
    return keys, (int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1]))


def as_rects(tiles: Mapping[TileKey, tuple[int, int, int, int]]) -> dict[TileKey, tuple[int, int, int, int]]:
    """{(tx, ty): (x0, y0, x1, y1)} as integers; CanvasError when a rectangle is not 4 integers."""
    try:
        out = {(int(k[0]), int(k[1])): tuple(int(v) for v in r) for k, r in tiles.items()}
        if any(len(r) != 4 for r in out.values()):
            raise ValueError('a rectangle of other than 4 numbers')
        return out  # type: ignore[return-value]
    except (TypeError, ValueError) as exc:
        msg = f'tiles must map (tx, ty) to (x0, y0, x1, y1) integers: {exc}'
        raise CanvasError(msg) from exc
