"""The survey's output settings (app/survey.py): the canvas's tile bound follows the stills'
footprint, never the number of stills; the threads writing the files; mosaic.tif's 8-bit conversion
(io/geotiff._to_u8) keeps the bytes of the formula it replaced."""
from __future__ import annotations

import numpy as np

from srmosaic_ros.app.survey import TILE_MEMORY_BUDGET_BYTES, TILES_PER_FOOTPRINT, tiles_in_memory
from srmosaic_ros.io.outputs import output_threads
from srmosaic_ros.core.mosaic.tile_store import TileLayout
from srmosaic_ros.io.geotiff import _to_u8


def test_the_tile_bound_follows_the_footprint_not_the_number_of_stills() -> None:
    still_12mp = 4000 * 3000 * 1.3  # bounding box of a slightly turned 12 MP still, mosaic px
    bound = tiles_in_memory(256, 256, [still_12mp] * 10)
    assert bound == int(np.ceil(TILES_PER_FOOTPRINT * still_12mp / 256**2)) > 256
    assert tiles_in_memory(256, 256, [still_12mp] * 1000) == bound  # flat in the number of stills
    assert tiles_in_memory(256, 256, [640 * 480.0] * 10) == 256  # small stills: the configured bound
    assert tiles_in_memory(0, 256, [still_12mp]) == 0  # no bound stays no bound
    assert tiles_in_memory(256, 512, [still_12mp]) < bound  # larger tiles, fewer of them
    tile = TileLayout(256, 3, multiband=True).nbytes  # 2.25 MiB
    assert tiles_in_memory(256, 256, [still_12mp] * 10, tile) == bound  # 1.3 GB of tiles: within the budget
    still_24mp = 6000 * 4000 * 1.3
    big = tiles_in_memory(256, 256, [still_24mp] * 10, tile)
    assert big * tile <= TILE_MEMORY_BUDGET_BYTES < tiles_in_memory(256, 256, [still_24mp] * 10) * tile
    assert tiles_in_memory(256, 256, [still_24mp] * 1000, tile) == big  # still flat in the number of stills
    assert tiles_in_memory(2000, 256, [still_24mp], tile) == 2000  # a configured bound stands


def test_output_threads() -> None:
    assert 1 <= output_threads() <= 4


def test_to_u8_keeps_the_bytes_of_the_clip_formula() -> None:
    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        x = rng.normal(0.5, 0.6, (300, 200, 3)).astype(dtype)
        x.flat[::97] = np.nan
        x.flat[1::101] = np.inf
        x.flat[2::103] = -np.inf
        x.flat[3:3 + 256] = ((np.arange(256) + 0.5) / 255).astype(dtype)  # half-way cases
        with np.errstate(over='ignore'):
            want = np.clip(np.nan_to_num(x, nan=0.0) * 255.0 + 0.5, 0, 255).astype(np.uint8)
        assert np.array_equal(_to_u8(x), want)
