"""Bounded memory of the mosaic canvas: tiles spilled to disk and loaded back (core.mosaic.tile_store)."""
from __future__ import annotations

import gc
import pickle
from pathlib import Path

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.mosaic import CanvasError, MosaicConfig, TiledCanvas
from srmosaic_ros.core.mosaic import canvas_reader as reader_mod
from srmosaic_ros.core.mosaic.segments import Segment
from srmosaic_ros.core.mosaic.tile_store import TileStoreError

BLENDS = ('feather', 'multiband')
T = 32  # tile side: small, so that a frame spans many tiles


def texture(h: int, w: int, c: int = 3, *, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w, c)).astype(np.float32), (0, 0), 1.5).reshape(h, w, c)
    return (0.1 + 0.8 * (img - img.min()) / (img.max() - img.min())).astype(np.float32)


def homography(k: int) -> np.ndarray:
    """Frame k of a back-and-forth path (revisits old tiles), slightly rotated and projective."""
    x = 23.0 * k if k < 6 else 23.0 * (11 - k)
    y = 9.0 * (k // 6) * 4 - 3.0 * k
    a = np.deg2rad(2.0 * np.sin(k))
    return np.array([[np.cos(a), -np.sin(a), x], [np.sin(a), np.cos(a), y], [1e-5 * k, -1e-5, 1.0]])


def paint_flight(canvas: TiledCanvas, frames: int = 12, channels: int = 3, *, check_bound: bool = False) -> None:
    for k in range(frames):
        img = texture(50, 70, channels, seed=k)
        canvas.paint(img[:, :, 0] if channels == 1 else img, homography(k))
        if check_bound:
            assert canvas.tiles_in_memory <= canvas.max_tiles_in_memory


def tile_bytes(blend: str, channels: int = 3, t: int = T) -> int:
    return 4 * t * t * ((channels + 1) if blend == 'feather' else (2 * channels + 3))


@pytest.mark.parametrize('blend', BLENDS)
def test_spilled_canvas_renders_bit_identical(blend: str, tmp_path: Path) -> None:
    ref = TiledCanvas(3, tile_size=T, blend=blend)
    paint_flight(ref)
    with TiledCanvas(3, tile_size=T, blend=blend, max_tiles_in_memory=4, spill_dir=tmp_path) as c:
        paint_flight(c, check_bound=True)
        stats = c.tile_stats()
        assert stats['writes'] > 0 and stats['loads'] > 0  # tiles went to disk and came back for painting
        assert c.tile_keys() == ref.tile_keys() and c.frames_per_tile() == ref.frames_per_tile()
        assert c.bounds() == ref.bounds() and c.frames_painted == ref.frames_painted
        assert c.tiles_in_memory == 4 and c.tiles_on_disk == len(ref.tile_keys()) - 4
        # memory_bytes counts the tiles in memory only.
        assert ref.memory_bytes == len(ref.tile_keys()) * tile_bytes(blend)
        assert c.memory_bytes == 4 * tile_bytes(blend)
        assert c.disk_bytes >= c.tiles_on_disk * tile_bytes(blend)
        # The spill files: in a directory of the canvas's own under spill_dir, whole files only.
        spill = Path(c.spill_dir)
        assert spill.parent == tmp_path and spill.is_dir()
        files = sorted(spill.iterdir())
        assert len(files) >= c.tiles_on_disk and all(f.suffix == '.npy' and not f.name.startswith('.') for f in files)
        for region in (None, (-40, -40, 300, 90), (5, 7, 6, 8), (1000, 1000, 1010, 1003)):
            a, ca = ref.render(region)
            b, cb = c.render(region)
            assert a.dtype == b.dtype and a.shape == b.shape
            np.testing.assert_array_equal(b, a)  # bit for bit
            np.testing.assert_array_equal(cb, ca)
        np.testing.assert_array_equal(c.weights(), ref.weights())
        assert c.tiles_in_memory == 4  # rendering reads spilled tiles without keeping them
    assert not spill.exists() and c.closed and c.spill_dir == ''
    with pytest.raises(CanvasError, match='closed'):
        c.render()
    with pytest.raises(CanvasError, match='closed'):
        c.paint(texture(10, 10), np.eye(3))


@pytest.mark.parametrize('blend', BLENDS)
@pytest.mark.parametrize('channels', [1, 3])
def test_render_blocks_reassemble_render(blend: str, channels: int, tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(reader_mod, 'RENDER_BLOCK_PX', 70)  # several block rows, strips across them
    c = TiledCanvas(channels, tile_size=T, blend=blend, max_tiles_in_memory=3, spill_dir=tmp_path)
    paint_flight(c, channels=channels)
    for region in (None, (-13, 4, 150, 201)):
        whole, cov = c.render(region)
        for rows, threads in ((1, 1), (33, 2), (64, 1), (1000, 3)):  # threads: a row's blocks rendered at once
            strips = list(c.render_blocks(rows, region, threads=threads))
            assert [r for r, _, _ in strips] == list(range(0, whole.shape[0], rows))
            assert all(img.shape[0] == min(rows, whole.shape[0] - r) for r, img, _ in strips)
            assert all(img.shape[1:] == whole.shape[1:] for _, img, _ in strips)
            np.testing.assert_array_equal(np.concatenate([img for _, img, _ in strips]), whole)
            np.testing.assert_array_equal(np.concatenate([cv for _, _, cv in strips]), cov)
    assert list(c.render_blocks(8, (0, 0, 0, 0))) == []
    with pytest.raises(CanvasError, match='block_rows'):
        next(c.render_blocks(0))
    c.close()


@pytest.mark.parametrize('blend', BLENDS)
def test_spill_on_demand_and_pickle(blend: str, tmp_path: Path) -> None:
    ref = TiledCanvas(3, tile_size=T, blend=blend)
    paint_flight(ref, 8)
    c = TiledCanvas(3, tile_size=T, blend=blend, spill_dir=tmp_path)  # no bound
    paint_flight(c, 8)
    assert c.spill_dir == '' and c.tile_stats()['writes'] == 0  # nothing written without a bound
    n = len(c.tile_keys())
    assert c.spill(keep=2) == n - 2 and c.tiles_in_memory == 2 and c.memory_bytes == 2 * tile_bytes(blend)
    np.testing.assert_array_equal(c.render()[0], ref.render()[0])
    # A pickled canvas carries its spilled tiles and spills into a directory of its own.
    d = pickle.loads(pickle.dumps(c))
    assert d.spill_dir == '' and d.tiles_in_memory == n  # unbounded: all back in memory
    b = pickle.loads(pickle.dumps(TiledCanvas(3, tile_size=T, blend=blend, max_tiles_in_memory=3,
                                              spill_dir=tmp_path)))
    paint_flight(b, 8)
    e = pickle.loads(pickle.dumps(b))
    assert e.tiles_in_memory == 3 and e.spill_dir not in ('', b.spill_dir)
    for k in range(8, 12):  # all go on painting identically
        for canvas in (ref, c, d, e):
            canvas.paint(texture(50, 70, seed=k), homography(k))
    for canvas in (c, d, e):
        np.testing.assert_array_equal(canvas.render()[0], ref.render()[0])
        assert canvas.frames_per_tile() == ref.frames_per_tile()


def test_spill_files_removed_when_garbage_collected(tmp_path: Path) -> None:
    c = TiledCanvas(3, tile_size=T, max_tiles_in_memory=1, spill_dir=tmp_path)
    paint_flight(c, 3)
    spill = Path(c.spill_dir)
    assert any(spill.iterdir())
    del c
    gc.collect()
    assert not spill.exists() and list(tmp_path.iterdir()) == []


def test_spill_failure_is_a_clear_error_and_keeps_the_tiles(tmp_path: Path) -> None:
    blocker = tmp_path / 'a_file'
    blocker.write_text('not a directory')
    c = TiledCanvas(3, tile_size=T, max_tiles_in_memory=2, spill_dir=blocker / 'spill')
    with pytest.raises(TileStoreError, match='spill') as info:
        paint_flight(c, 1)
    assert not isinstance(info.value, ValueError)  # the pipeline must not mistake it for a bad frame
    ref = TiledCanvas(3, tile_size=T)
    paint_flight(ref, 1)
    np.testing.assert_array_equal(c.render()[0], ref.render()[0])  # the frame is painted, no tile lost


def test_bad_settings() -> None:
    with pytest.raises(CanvasError, match='max_tiles_in_memory'):
        TiledCanvas(3, max_tiles_in_memory=-1)
    with pytest.raises(ValueError, match='max_tiles_in_memory'):
        MosaicConfig(max_tiles_in_memory=-5)
    with pytest.raises(ValueError, match='spill_dir'):
        MosaicConfig(spill_dir=None)  # type: ignore[arg-type]


def test_segment_passes_the_bound(tmp_path: Path) -> None:
    seg = Segment.create(0, 3, MosaicConfig(tile_size=64, max_tiles_in_memory=2, spill_dir=str(tmp_path)))
    for k in range(4):
        seg.add(k, texture(50, 70, seed=k), homography(k) @ np.diag([3.0, 3.0, 1.0]))
    assert seg.canvas.max_tiles_in_memory == 2 and seg.canvas.tiles_in_memory <= 2
    assert Path(seg.canvas.spill_dir).parent == tmp_path


def test_pickling_a_spilled_canvas_streams_its_tiles(tmp_path: Path) -> None:
    """pickle.dump to a file holds about one tile beyond the canvas's bound, not the whole canvas."""
    import copy
    import tracemalloc

    t = 128
    c = TiledCanvas(3, tile_size=t, max_tiles_in_memory=2, spill_dir=tmp_path / 'spill')
    for k in range(24):
        c.paint(texture(120, 160, seed=k), np.array([[1.0, 0, 140.0 * (k % 8)], [0, 1.0, 110.0 * (k // 8)], [0, 0, 1]]))
    total = len(c.tile_keys()) * tile_bytes('feather', t=t)
    assert c.tiles_on_disk >= 20 and total > 6 * 1024 * 1024
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        with open(tmp_path / 'state.pkl', 'wb') as handle:
            pickle.dump(c, handle, protocol=pickle.HIGHEST_PROTOCOL)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert peak < 4 * tile_bytes('feather', t=t) < total / 4
    with open(tmp_path / 'state.pkl', 'rb') as handle:
        d = pickle.load(handle)
    assert d.tiles_in_memory == 2 and d.tile_stats()['tiles'] == len(c.tile_keys())
    np.testing.assert_array_equal(d.render()[0], c.render()[0])
    e = copy.deepcopy(c)
    np.testing.assert_array_equal(e.render()[0], c.render()[0])
    for canvas in (c, d, e):
        canvas.close()
    assert list((tmp_path / 'spill').iterdir()) == []


def test_default_spill_root_follows_tmpdir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv('TMPDIR', str(tmp_path))
    c = TiledCanvas(3, tile_size=T, max_tiles_in_memory=1)
    paint_flight(c, 2)
    assert Path(c.spill_dir).parent == tmp_path
    c.close()
    assert list(tmp_path.iterdir()) == []
