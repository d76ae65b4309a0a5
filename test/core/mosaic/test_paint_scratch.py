"""Painting's per-thread scratch arrays and fast arithmetic (srmosaic_ros.core.mosaic.scratch, canvas):
the same canvas bytes whatever the thread, the frame sizes before, or the buffers' history."""
from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.mosaic import TiledCanvas
from srmosaic_ros.core.mosaic.paint_ops import add_into as _add_into, times_weight as _times_weight
from srmosaic_ros.core.mosaic.scratch import release, scratch

BLENDS = ('feather', 'multiband', 'bestview')


def texture(h: int, w: int, c: int = 3, *, seed: int = 0) -> np.ndarray:
    """Seeded smooth random texture, float32 (h, w, c) in [0, 1]."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w, c)).astype(np.float32), (0, 0), 2.0).reshape(h, w, c)
    return ((img - img.min()) / (img.max() - img.min())).astype(np.float32)


def placement(k: int) -> np.ndarray:
    """A rotated, scaled, slightly projective mosaic_H_frame, different for each k."""
    a = np.deg2rad(11.0 * k)
    s = 0.8 + 0.15 * k
    return np.array([[s * np.cos(a), -s * np.sin(a), 37.0 * k - 20.0],
                     [s * np.sin(a), s * np.cos(a), -23.0 * k + 5.0],
                     [1e-4 * k, -5e-5 * k, 1.0]])


def in_thread(fn: Callable[..., Any], *args: Any) -> Any:
    """fn(*args) on a new thread (fresh scratch arrays); its result or its exception."""
    out: dict[str, object] = {}

    def run() -> None:
        try:
            out['result'] = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller
            out['error'] = exc

    t = threading.Thread(target=run)
    t.start()
    t.join()
    if 'error' in out:
        raise out['error']  # type: ignore[misc]
    return out['result']


def tile_bytes(canvas: TiledCanvas) -> dict[tuple[int, int], bytes]:
    return {key: canvas._store.peek(key).buf.tobytes() for key in canvas.tile_keys()}


# ---------------------------------------------------------------- scratch arrays
def test_scratch_is_reused_grown_and_shrunk() -> None:
    release()
    a = scratch('t', (40, 50, 3))
    assert a.shape == (40, 50, 3) and a.dtype == np.float32 and a.flags.c_contiguous
    assert np.shares_memory(scratch('t', (40, 50, 3)), a)  # same size: the same memory
    assert np.shares_memory(scratch('t', (30, 20)), a)  # smaller: a view of it
    big = scratch('t', (600, 700, 3))  # larger: grown
    assert big.shape == (600, 700, 3) and not np.shares_memory(big, a)
    small = scratch('t', (40, 50))  # far smaller: a new, small buffer (a one-off large frame lets go)
    assert small.shape == (40, 50) and not np.shares_memory(small, big)
    assert not np.shares_memory(scratch('u', (40, 50)), small)  # names are separate
    release()
    assert not np.shares_memory(scratch('t', (40, 50)), small)


def test_scratch_is_per_thread() -> None:
    mine = scratch('t', (64, 64))
    theirs = in_thread(scratch, 't', (64, 64))
    assert not np.shares_memory(mine, theirs)


# ---------------------------------------------------------------- fast arithmetic: numpy's values exactly
@pytest.mark.parametrize('channels', [1, 3, 4, 5])
def test_times_weight_is_numpys_broadcast_product(channels: int) -> None:
    rng = np.random.default_rng(channels)
    colour = rng.random((37, 53, channels), dtype=np.float32)
    weight = rng.random((37, 53), dtype=np.float32)
    weight[:, :4] = 0.0
    out = _times_weight(colour, weight)
    assert out.shape == colour.shape and out.dtype == np.float32
    np.testing.assert_array_equal(out, colour * weight[..., None])


@pytest.mark.parametrize('shape', [(64, 64), (64, 64, 1), (64, 64, 3), (64, 64, 5)])
def test_add_into_adds_in_place_on_views(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(len(shape))
    dst = rng.random(shape, dtype=np.float32)
    src = rng.random((80, 90, *shape[2:]), dtype=np.float32)
    view, part = dst[5:50, 3:60], src[10:55, 20:77]
    expected = dst.copy()
    expected[5:50, 3:60] += part
    _add_into(view, part)
    np.testing.assert_array_equal(dst, expected)


# ---------------------------------------------------------------- the canvas: same bytes whatever the history
def paint_all(blend: str, frames: list[tuple[np.ndarray, np.ndarray]], fresh_thread_each: bool) -> TiledCanvas:
    canvas = TiledCanvas(3, tile_size=64, blend=blend, recency_frames=3, max_stretch=4.0)
    for img, m in frames:
        if fresh_thread_each:
            in_thread(canvas.paint, img, m)
        else:
            canvas.paint(img, m)
    return canvas


@pytest.mark.parametrize('blend', BLENDS)
def test_frames_of_changing_size_paint_as_with_fresh_buffers(blend: str) -> None:
    """Frames of several sizes in turn (the scratch arrays grow, are reused as views, and are
    replaced by smaller ones) paint the same tile bytes as each frame painted on a thread of its
    own (fresh arrays), and as two canvases painted at once on two threads."""
    sizes = [(60, 80), (300, 400), (30, 40), (300, 400), (61, 79)]
    frames = [(texture(h, w, seed=k), placement(k)) for k, (h, w) in enumerate(sizes)]
    release()
    reused = tile_bytes(paint_all(blend, frames, fresh_thread_each=False))
    fresh = tile_bytes(paint_all(blend, frames, fresh_thread_each=True))
    assert reused.keys() == fresh.keys() and len(reused) > 4
    assert all(reused[k] == fresh[k] for k in reused)
    results: list[dict[tuple[int, int], bytes]] = [{}, {}]

    def worker(i: int) -> None:
        results[i] = tile_bytes(paint_all(blend, frames, fresh_thread_each=False))

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results[0] == reused and results[1] == reused


@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
def test_non_finite_pixels_are_invalid(bad: float) -> None:
    """A frame with non-finite pixels paints as the same frame with those pixels masked out."""
    img = texture(50, 70, seed=4)
    dirty = img.copy()
    dirty[20:24, 30:33, 1] = bad
    mask = np.isfinite(dirty).all(axis=2)
    a = TiledCanvas(3, tile_size=64, blend='bestview')
    a.paint(dirty, placement(1))
    b = TiledCanvas(3, tile_size=64, blend='bestview')
    b.paint(np.where(mask[..., None], dirty, 0.0).astype(np.float32), placement(1), mask=mask)
    assert tile_bytes(a) == tile_bytes(b)


@pytest.mark.parametrize('blend', BLENDS)
def test_a_frame_known_finite_paints_the_same_unchecked(blend: str) -> None:
    """paint(finite=True) (the caller knows every pixel is finite: converted from uint8) skips the
    pass over the frame and paints the same bytes as the checked paint."""
    frames = [(texture(60, 80, seed=k), placement(k)) for k in range(3)]
    checked = TiledCanvas(3, tile_size=64, blend=blend)
    trusted = TiledCanvas(3, tile_size=64, blend=blend)
    for img, m in frames:
        checked.paint(img, m)
        trusted.paint(img, m, finite=True)
    assert tile_bytes(checked) == tile_bytes(trusted)
