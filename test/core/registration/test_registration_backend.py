"""registration.backend: the factory, the OpenCV fallback of the torch registrar, pickling, and
the pipeline with either backend against the truth."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.errors import ConfigError
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.registration import (
    FallbackRegistrar,
    Registrar,
    RegistrationConfig,
    TorchRegistrar,
    make_registrar,
)
from srmosaic_ros.core.types import Frame
from srmosaic_ros.io.image_folder import ImageFolderReader
from srmosaic_ros.pipeline import Pipeline

from imagery import similarity, translation, view
from repo_paths import REPO

BRIGHTON = REPO / 'data' / 'sequences' / 'brighton_beach'


def test_factory_selects_backend():
    assert isinstance(make_registrar(RegistrationConfig(), 'cpu'), FallbackRegistrar)
    assert type(make_registrar(RegistrationConfig(opencv_fallback=False), 'cpu')) is TorchRegistrar
    assert type(make_registrar(RegistrationConfig(backend='opencv'), 'cpu')) is Registrar
    with pytest.raises(ValueError, match="backend='sift'"):
        RegistrationConfig(backend='sift')


def test_params_refuse_unknown_backend():
    with pytest.raises(ConfigError, match='backend'):
        pipeline_config({'registration.backend': 'orb'})


def test_fallback_registers_the_pair_torch_features_miss():
    """Real survey stills: pair 4 -> 5 of brighton_beach (scale 0.91, ~115 px motion) has too few
    torch inliers; the fallback registers it, and agrees with the torch estimate elsewhere."""
    frames = [it.image for it in ImageFolderReader(BRIGHTON) if isinstance(it, Frame)]
    reg = make_registrar(RegistrationConfig(), 'cpu')
    torch_only = reg.primary
    f4, f5 = reg.describe(frames[4]), reg.describe(frames[5])
    alone = torch_only.register(f4.primary, f5.primary)
    assert not alone.ok and 'too few' in alone.reason
    both = reg.register(f4, f5)
    assert both.ok and both.extras['fallback_opencv'] == 1.0 and both.inliers >= 20
    sift = Registrar(RegistrationConfig()).register(Registrar(RegistrationConfig()).describe(frames[4]),
                                                     Registrar(RegistrationConfig()).describe(frames[5]))
    assert corner_error_px(both.prev_H_cur, sift.prev_H_cur, 640, 360) < 1e-6
    # A pair torch registers never calls OpenCV (no SIFT features are described for it).
    f7, f8 = reg.describe(frames[7]), reg.describe(frames[8])
    good = reg.register(f7, f8)
    assert good.ok and 'fallback_opencv' not in good.extras and f7.fallback is None and good.covariance is not None


def test_fallback_keeps_textureless_failure_explicit():
    rng = np.random.default_rng(3)
    sea = (120 + rng.normal(0, 1.5, (240, 320))).clip(0, 255).astype(np.uint8)
    reg = make_registrar(RegistrationConfig(), 'cpu')
    out = reg.register(reg.describe(sea), reg.describe(np.roll(sea, 3, axis=1)))
    assert not out.ok and 'OpenCV fallback failed too' in out.reason and out.extras['fallback_opencv'] == 0.0


def test_torch_registrar_pickles():
    reg = make_registrar(RegistrationConfig(max_features=500), 'cpu')
    back = pickle.loads(pickle.dumps(reg))
    assert back.primary.config.max_features == 500 and back.primary.device.type == 'cpu'
    prev, cur, truth = (view(translation(200, 150), 320, 240, noise=2, seed=1),
                        view(translation(200, 150) @ similarity(3, 1.02, 7.5, -4.2, 160, 120), 320, 240, noise=2, seed=2),
                        similarity(3, 1.02, 7.5, -4.2, 160, 120))
    fp = pickle.loads(pickle.dumps(back.describe(prev)))   # checkpointed features still register
    out = back.register(fp, back.describe(cur))
    assert out.ok and corner_error_px(out.prev_H_cur, truth, 320, 240) < 0.1


@pytest.mark.parametrize('backend', ['torch', 'opencv'])
def test_pipeline_backends_against_truth(backend):
    """Eight synthetic frames through the pipeline: consecutive homographies against the truth;
    the torch backend's covariance reaches the records (the georeferencing filter uses it)."""
    pipe = Pipeline(pipeline_config({'registration.backend': backend, 'device': 'cpu'}))
    truths = []
    world_H = translation(150, 120)
    for k in range(8):
        step = similarity(1.0, 1.01, 12.0, -6.0, 160, 120)
        world_H = world_H @ step
        truths.append(step)
        pipe.feed(Frame(k * 100_000_000, view(world_H, 320, 240, noise=2, seed=k)))
    res = pipe.finish()
    regs = [r.registration for r in res.records[1:]]
    assert all(r.ok for r in regs) and len(res.segments) == 1
    errs = [corner_error_px(r.prev_H_cur, t, 320, 240) for r, t in zip(regs, truths[1:], strict=True)]
    assert max(errs) < (0.1 if backend == 'torch' else 0.5), errs
    assert all((r.covariance is not None) == (backend == 'torch') for r in regs)
