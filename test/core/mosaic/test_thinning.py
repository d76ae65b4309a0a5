"""Paint thinning (core/mosaic/thinning.py): which placed frames are painted, and where."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.core.mosaic.thinning import PaintThinning

W, H = 200, 150


def rect(x: float, y: float, w: float = W, h: float = H) -> np.ndarray:
    return np.array([[x - 0.5, y - 0.5], [x + w - 0.5, y - 0.5], [x + w - 0.5, y + h - 0.5], [x - 0.5, y + h - 0.5]])


def feed(thin: PaintThinning, xs: list[float], ys: list[float] | None = None, segment: int = 0) -> list[list]:
    ys = ys or [0.0] * len(xs)
    return [thin.offer(segment, k, rect(x, y), rect(x, y)) for k, (x, y) in enumerate(zip(xs, ys))]


def test_stride_one_paints_every_frame_at_once() -> None:
    thin = PaintThinning(1, 16.0)
    assert feed(thin, [0, 1, 2, 3]) == [[(0, None)], [(1, None)], [(2, None)], [(3, None)]]
    assert thin.release() == [] and thin.thinned == 0


def test_slow_frames_are_painted_every_stride_and_the_last_at_the_end() -> None:
    thin = PaintThinning(3, 16.0, tile_size=32)
    out = feed(thin, [2.0 * k for k in range(8)])
    # painted: 0, 3, 6; 1, 2 and 4, 5 lie between their painted neighbours: not painted at all
    assert out == [[(0, None)], [], [], [(3, None)], [], [], [(6, None)], []]
    assert thin.thinned == 5
    assert thin.release() == [(7, None)] and thin.thinned == 4


def test_a_frame_that_moved_far_enough_is_painted() -> None:
    thin = PaintThinning(3, 16.0)
    out = feed(thin, [0.0, 20.0, 40.0, 50.0, 70.0])
    assert out == [[(0, None)], [(1, None)], [(2, None)], [], [(4, None)]]
    assert thin.thinned == 1  # frame 3 lies between 2 and 4: not painted


def test_a_held_frame_reaching_beyond_both_neighbours_is_painted_there_only() -> None:
    thin = PaintThinning(2, 100.0, tile_size=32)
    # frame 1 jumps 40 px down (a gust): its bottom rows see ground neither 0 nor 2 sees
    out = feed(thin, [0.0, 4.0, 8.0], [0.0, 40.0, 0.0])
    assert out[0] == [(0, None)] and out[1] == []
    (frame, tiles), last = out[2]
    assert frame == 1 and last == (2, None)
    rows = {ty for _, ty in tiles}
    cols = {tx for tx, _ in tiles}
    # rows 150 .. 189 only: tiles 4 and 5 down (y 128 .. 191); across its width (x 4 .. 203: tiles 0 .. 6)
    assert rows == {4, 5} and cols == set(range(7))
    # in each, the box of those pixels (the frame's edge row left out) and a margin of 4
    assert tiles[(1, 4)] == (32, 147, 64, 160) and tiles[(1, 5)] == (32, 160, 64, 192)
    assert tiles[(0, 4)][0] == 1 and tiles[(6, 5)] == (192, 160, 208, 192)
    assert thin.thinned == 0


def test_another_segment_paints_the_frames_held_back() -> None:
    thin = PaintThinning(3, 16.0)
    feed(thin, [0.0, 1.0], segment=0)
    assert thin.offer(1, 'b', rect(500, 0), rect(500, 0)) == [(1, None), ('b', None)]
    assert thin.release() == [] and thin.thinned == 0


@pytest.mark.parametrize(('stride', 'shift', 'tile'), [(0, 16.0, 256), (1.5, 16.0, 256), (True, 16.0, 256), (3, -1.0, 256),
                                                       (3, float('nan'), 256), (3, 16.0, 0)])
def test_bad_settings_are_refused(stride: object, shift: float, tile: int) -> None:
    with pytest.raises(ValueError, match='paint thinning needs'):
        PaintThinning(stride, shift, tile)  # type: ignore[arg-type]
