"""`process --sr`'s SR settings for a flight (app/sr_process._flight_psf): the PSF chosen from the frames
turns `sr.clamp: auto` off; a PSF given keeps the cell clamp; an explicit clamp stays as set."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.app.sr_process import _flight_psf
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.sr.psf_select import TileFrames
from srmosaic_ros.core.sr.ringing import resolve_clamp
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile

from imagery import world_rgb


@pytest.fixture(scope='module')
def tiles() -> list[TileFrames]:
    st = make_synthetic_tile(world_rgb().astype(np.float32) / 255.0, (120, 440), (32, 32), 2, 5, noise_sigma=1.0, seed=1)
    return [TileFrames(st.frames, st.tile_H_frames, st.tile_shape)]


def test_resolve_clamp() -> None:
    assert resolve_clamp('auto', psf_chosen=True) == 'off'
    assert resolve_clamp('auto', psf_chosen=False) == 'cell'
    for mode in ('cell', 'wide', 'off'):
        assert resolve_clamp(mode, psf_chosen=True) == resolve_clamp(mode, psf_chosen=False) == mode


def test_a_chosen_psf_unclamps_a_given_one_does_not(tiles: list[TileFrames]) -> None:
    chosen, how = _flight_psf(pipeline_config({'sr.psf_ladder': [0.2, 0.5], 'sr.device': 'cpu'}), tiles, 2)
    assert how['method'] == 'held_out_frames' and chosen.psf_sigma in (0.2, 0.5)
    assert chosen.clamp == 'off'
    given, how = _flight_psf(pipeline_config({'sr.psf_ladder': [], 'sr.device': 'cpu'}), tiles, 2)
    assert how['method'] == 'given' and given.clamp == 'cell'
    kept, _ = _flight_psf(pipeline_config({'sr.psf_ladder': [0.2, 0.5], 'sr.clamp': 'wide', 'sr.device': 'cpu'}), tiles, 2)
    assert kept.clamp == 'wide'
