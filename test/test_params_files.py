"""Every shipped parameter file loads and validates against the defaults."""
from __future__ import annotations

from pathlib import Path

import pytest

from srmosaic_ros.config import default_params_path, load_params, pipeline_config

PARAMS = sorted((Path(__file__).resolve().parent.parent / 'params').glob('*.yaml'))


@pytest.mark.parametrize('path', PARAMS, ids=[p.name for p in PARAMS])
def test_params_file_is_valid(path):
    flat = load_params(path)
    cfg = pipeline_config(flat)
    for key, value in flat.items():
        if key.startswith('registration.'):
            assert getattr(cfg.registration, key.split('.', 1)[1]) == value


def test_shipped_files():
    assert {p.name for p in PARAMS} >= {'default.yaml', 'eo_camera.yaml', 'ir_camera.yaml', 'gpu.yaml'}
    assert default_params_path().name == 'default.yaml'


def test_live_keys_have_descriptions_and_ranges():
    """Every live.* key of default.yaml is described (its comment) and numeric ones have a range."""
    from srmosaic_ros.nodes.parameters import _RANGES, _comments

    path = default_params_path()
    comments = _comments(path)
    for key, value in load_params(path).items():
        if key.startswith('live.'):
            assert comments.get(key), f'{key} has no description comment in {path.name}'
            if isinstance(value, int | float) and not isinstance(value, bool):
                assert key in _RANGES, f'{key} has no range in nodes/parameters.py'
                lo, hi = _RANGES[key]
                assert lo <= value <= hi, key
