"""The flight's PSF chosen without truth (core/sr/psf_select.py): the ladder's sigma that best predicts
frames left out, on synthetic tiles whose blur is known."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.sr import SRConfig, SRError
from srmosaic_ros.core.sr.psf_select import TileFrames, choose_psf_sigma
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile

from imagery import world_rgb

LADDER = (0.2, 0.35, 0.5, 0.7, 0.9)
ORIGINS = ((120, 440), (150, 480), (250, 350))


@pytest.fixture(scope='module')
def world() -> np.ndarray:
    return world_rgb().astype(np.float32) / 255.0


@pytest.mark.parametrize(('true_sigma', 'chosen'), [(0.3, 0.35), (0.76, 0.7)])
def test_the_rung_nearest_the_true_blur_is_chosen(world, true_sigma, chosen):
    tiles = [make_synthetic_tile(world, o, (32, 32), 2, 6, psf_sigma=true_sigma, noise_sigma=2.0, seed=5 + i)
             for i, o in enumerate(ORIGINS)]
    choice = choose_psf_sigma([TileFrames(t.frames, t.tile_H_frames, (32, 32)) for t in tiles], 2,
                              SRConfig(device='cpu'), LADDER)
    assert choice.sigma == chosen, choice
    assert choice.predictions == 9 and choice.ladder == LADDER
    # a PSF far too wide predicts the held-out frames clearly worse (it rings)
    assert choice.rms[-1] > min(choice.rms) * (1.2 if true_sigma < 0.5 else 1.005)


def test_too_few_frames_to_leave_one_out(world):
    t = make_synthetic_tile(world, ORIGINS[0], (32, 32), 2, 2, psf_sigma=0.5, seed=1)
    with pytest.raises(SRError, match='three frames'):
        choose_psf_sigma([TileFrames(t.frames, t.tile_H_frames, (32, 32))], 2, SRConfig(device='cpu'), LADDER)


def test_a_psf_the_user_gives_is_used_as_given():
    assert pipeline_config().sr.psf_ladder == LADDER
    assert pipeline_config({'sr.psf_sigma': 0.6}).sr.psf_ladder == ()
    assert pipeline_config({'sr.psf_sigma': 0.6, 'sr.psf_ladder': [0.4, 0.6]}).sr.psf_ladder == (0.4, 0.6)
