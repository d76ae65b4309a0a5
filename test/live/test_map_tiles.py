"""The live map's changed tiles without a graph: encoding, the budget, the stream over real canvases."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.mosaic import TiledCanvas
from srmosaic_ros.core.mosaic.segments import Segment
from srmosaic_ros.errors import SrMosaicError
from srmosaic_ros.live.map_tiles import ChangedTiles, MapTileStream, decode_tile, encode_tile, parse_whole_map
from srmosaic_ros.live.raster import ImagePlacement


def texture(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 2.0)
    return (0.2 + 0.6 * (img - img.min()) / (img.max() - img.min())).astype(np.float32)


def shift(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def test_a_tile_is_an_rgba_png_transparent_where_nothing_is_painted() -> None:
    image = np.zeros((8, 8, 3), np.float32)
    image[..., 0] = 1.0
    covered = np.zeros((8, 8), bool)
    covered[2:5, 3:7] = True
    data = encode_tile(image, covered)
    assert data[:8] == b'\x89PNG\r\n\x1a\n'
    rgba = decode_tile(data)
    assert rgba.shape == (8, 8, 4)
    np.testing.assert_array_equal(rgba[..., 3] == 255, covered)
    assert (rgba[covered][:, :3] == [255, 0, 0]).all() and (rgba[~covered] == 0).all()
    grey = decode_tile(encode_tile(np.full((4, 4), 0.5, np.float32), np.ones((4, 4), bool)))
    assert (grey[..., :3] == 128).all() and (grey[..., 3] == 255).all()
    with pytest.raises(SrMosaicError, match='not an image'):
        decode_tile(b'not a png')


def test_the_budget_sends_oldest_first_and_loses_none() -> None:
    q = ChangedTiles(bytes_per_s=1000, burst_s=1.0)
    q.mark([(0, 0, 0), (0, 1, 0)], now_s=0.0)
    q.mark([(0, 2, 0), (0, 0, 0)], now_s=0.5)  # (0, 0, 0) keeps its place
    assert q.candidates(0.5)[:1] == [(0, 0, 0)]
    sent, t = [], 0.5
    while q.pending and t < 10:
        for key in q.candidates(t):
            if not q.allowed():
                break
            q.sent(key, 600)
            sent.append((t, key))
        t += 0.25
    assert [k for _, k in sent] == [(0, 0, 0), (0, 1, 0), (0, 2, 0)]  # all of them, oldest change first
    assert sent[0][0] == 0.5 and sent[-1][0] > 0.5  # the budget held the others for a later round
    for t0 in np.arange(0.0, 10.0, 0.25):  # any window of T s: at most rate (T + burst) + one tile
        for span in (1.0, 2.0, 5.0):
            in_window = sum(600 for ts, _ in sent if t0 <= ts < t0 + span)
            assert in_window <= 1000 * (span + 1.0) + 600
    unlimited = ChangedTiles(0)
    unlimited.mark([(0, k, 0) for k in range(10)], 0.0)
    assert len(unlimited.candidates(0.0)) == 10 and unlimited.allowed()
    with pytest.raises(SrMosaicError, match='bytes_per_s'):
        ChangedTiles(-1)


def test_the_stream_sends_the_tiles_a_frame_changed_with_their_place_on_the_plane() -> None:
    seg = Segment(0, TiledCanvas(3, tile_size=64))
    stream = MapTileStream(level=1, bytes_per_s=0)
    img = texture(60, 80, 1)
    seg.add(0, img, shift(10.0, 20.0))
    first = stream.encode(stream.collect([seg], 0.0), stamp_ns=1)
    assert len(first) == len(seg.canvas.tile_keys())
    for frame_id, data in first:
        place = ImagePlacement.parse(frame_id)
        rgba = decode_tile(data)
        assert rgba.shape == (32, 32, 4) and place.width == place.height == 64
        # its opaque pixels are the painted ones: the frame's footprint [10, 90) x [20, 80) at half size
        xs = place.x0 + 2 * np.arange(32) + 0.5
        ys = place.y0 + 2 * np.arange(32) + 0.5
        inside = ((ys[:, None] > 20.5) & (ys[:, None] < 78.5)) & ((xs[None, :] > 10.5) & (xs[None, :] < 88.5))
        assert (rgba[..., 3][inside] == 255).all()
        outside = ~(((ys[:, None] > 18) & (ys[:, None] < 81)) & ((xs[None, :] > 8) & (xs[None, :] < 91)))
        assert (rgba[..., 3][outside] == 0).all()
    assert stream.encode(stream.collect([seg], 1.0), stamp_ns=2) == []  # nothing changed, nothing sent
    seg.add(1, img, shift(150.0, 20.0))
    second = [ImagePlacement.parse(f) for f, _ in stream.encode(stream.collect([seg], 2.0), stamp_ns=3)]
    assert second and all(p.x0 + p.width > 150 for p in second)  # only the tiles the new frame touched
    summary = json.loads(stream.summary())
    assert summary['pending'] == 0 and summary['tile_px'] == 32 and summary['level'] == 1
    assert len(summary['tiles']) == len(seg.canvas.tile_keys())
    whole = parse_whole_map(stream.whole_map())
    assert {f for f, _, _ in whole} == {t[0] for t in summary['tiles']}
    assert all(decode_tile(d).shape == (32, 32, 4) for _, _, d in whole)


def test_the_stream_under_a_budget_sends_everything_in_later_rounds() -> None:
    seg = Segment(0, TiledCanvas(3, tile_size=64))
    img = texture(120, 160, 2)
    seg.add(0, img, shift(0.0, 0.0))
    n_tiles = len(seg.canvas.tile_keys())
    one = len(encode_tile(*seg.canvas.tile_blocks(seg.canvas.tile_keys()[0], 1)))
    stream = MapTileStream(level=0, bytes_per_s=one * 1.5, burst_s=1.0)
    got, rounds = {}, 0
    for t in range(40):
        for frame_id, data in stream.encode(stream.collect([seg], float(t)), stamp_ns=t):
            got[frame_id] = data
        rounds += 1
        if len(got) == n_tiles:
            break
    assert len(got) == n_tiles and rounds > 2  # not in one round, and none lost
    assert stream.queue.pending == 0
    with pytest.raises(SrMosaicError, match='map_level'):
        MapTileStream(level=20)
