"""Pipeline: chaining, segments on failure, nothing smeared, config handling. No ROS involved."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from srmosaic_ros.config import default_params_path, load_params, pipeline_config
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.types import Frame, GeoFix
from srmosaic_ros.errors import ConfigError
from srmosaic_ros.pipeline import Pipeline

from imagery import translation, view

W, H = 256, 192


def _frames(offsets, noise=2.0):
    return [Frame(i * 100_000_000, view(translation(*o), W, H, noise=noise, seed=i)) for i, o in enumerate(offsets)]


def test_chain_matches_truth():
    offsets = [(100 + 15 * i, 120 + 4 * i) for i in range(8)]
    pipe = Pipeline(pipeline_config())
    for f in _frames(offsets):
        pipe.feed(f)
    res = pipe.finish()
    assert len(res.segments) == 1
    assert all(r.painted for r in res.records)
    for r, o in zip(res.records, offsets):
        truth = translation(o[0] - offsets[0][0], o[1] - offsets[0][1])  # segment plane = first frame
        assert corner_error_px(r.seg_H_frame, truth, W, H) < 0.5
    image, coverage = res.segments[0].canvas.render()
    assert coverage.mean() > 0.5
    assert image.shape[2] == 3


def test_bad_frame_is_skipped_not_painted():
    frames = _frames([(100 + 15 * i, 120) for i in range(6)])
    frames[3] = Frame(frames[3].stamp_ns, np.full((H, W, 3), 127, np.uint8))  # textureless
    pipe = Pipeline(pipeline_config())
    for f in frames:
        pipe.feed(f)
    res = pipe.finish()
    assert [r.painted for r in res.records] == [True, True, True, False, True, True]
    assert 'too few' in res.records[3].reason
    assert len(res.segments) == 1
    assert corner_error_px(res.records[4].seg_H_frame, translation(60, 0), W, H) < 1.0


def test_scene_change_starts_new_segment():
    offsets = [(100 + 15 * i, 120) for i in range(4)] + [(650 + 15 * i, 500) for i in range(4)]
    pipe = Pipeline(pipeline_config())
    for f in _frames(offsets):
        pipe.feed(f)
    res = pipe.finish()
    assert len(res.segments) == 2
    assert [r.segment for r in res.records] == [0] * 4 + [1] * 4
    # The new segment's plane is its first frame: the chain restarts instead of smearing segment 0.
    assert np.allclose(res.records[4].seg_H_frame, np.eye(3))
    assert corner_error_px(res.records[7].seg_H_frame, translation(45, 0), W, H) < 0.5


def test_telemetry_is_kept_and_unknown_input_refused():
    pipe = Pipeline(pipeline_config())
    pipe.feed(GeoFix(1, 30.0, -98.0, 300.0))
    assert len(pipe.finish().fixes) == 1
    with pytest.raises(TypeError, match='Frame, GeoFix, ImuSample or CameraAttitude'):
        pipe.feed('not a frame')


def test_params_defaults_and_unknown_keys(tmp_path):
    flat = load_params(default_params_path())
    assert flat['registration.max_features'] == 1000
    assert pipeline_config().registration.ratio == 0.8  # an internal: params/advanced.yaml
    cfg = pipeline_config({'mosaic.blend': 'multiband'})
    assert cfg.mosaic.blend == 'multiband'
    with pytest.raises(ConfigError, match='unknown parameter'):
        pipeline_config({'registration.max_feature': 5})
    with pytest.raises(ConfigError, match='mosaic.blend'):
        pipeline_config({'mosaic.blend': 'average'})
    bad = tmp_path / 'bad.yaml'
    bad.write_text('node:\n  not_params: {}\n')
    with pytest.raises(ConfigError, match='ros__parameters'):
        load_params(bad)


def test_core_imports_no_ros():
    code = ('import sys, srmosaic_ros.core, srmosaic_ros.core.registration, srmosaic_ros.core.mosaic, '
            'srmosaic_ros.core.metrics, srmosaic_ros.pipeline; '
            "bad = [m for m in ('rclpy', 'rosbags', 'sensor_msgs', 'msg_adapters') if m in sys.modules]; "
            'print(bad); sys.exit(1 if bad else 0)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
