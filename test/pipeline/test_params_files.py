"""Every shipped parameter file loads and validates against the defaults."""
from __future__ import annotations

import re

import pytest

from srmosaic_ros.config import default_params_path, load_params, pipeline_config
from srmosaic_ros.param_files import advanced_params_path
from repo_paths import REPO

PARAMS = sorted((REPO / 'params').glob('*.yaml'))


@pytest.mark.parametrize('path', PARAMS, ids=[p.name for p in PARAMS])
def test_params_file_is_valid(path):
    flat = load_params(path)
    cfg = pipeline_config(flat)
    for key, value in flat.items():
        if key.startswith('registration.'):
            assert getattr(cfg.registration, key.split('.', 1)[1]) == value


def test_shipped_files():
    assert {p.name for p in PARAMS} >= {'default.yaml', 'eo_camera.yaml', 'ir_camera.yaml', 'gpu.yaml', 'live_hd.yaml'}
    assert default_params_path().name == 'default.yaml'


def test_live_keys_have_descriptions_and_ranges():
    """Every live.* key of default.yaml and advanced.yaml is described (its comment) and numeric ones
    have a range."""
    from srmosaic_ros.nodes.parameters import _RANGES, _comments

    for path in (default_params_path(), advanced_params_path()):
        comments = _comments(path)
        for key, value in load_params(path).items():
            if key.startswith('live.'):
                assert comments.get(key), f'{key} has no description comment in {path.name}'
                if isinstance(value, int | float) and not isinstance(value, bool):
                    assert key in _RANGES, f'{key} has no range in nodes/parameters.py'
                    lo, hi = _RANGES[key]
                    assert lo <= value <= hi, key


def test_users_see_their_parameters_and_the_internals_apart():
    """default.yaml holds what a user sets (about 50 keys), advanced.yaml the solver internals; they
    share no key, their values are the config dataclasses' defaults, and an internal set in a user's
    file (same dotted name) takes effect, a misspelt one is refused."""
    import dataclasses
    import math

    from srmosaic_ros.config import PipelineConfig
    from srmosaic_ros.errors import ConfigError

    users, internals = load_params(default_params_path()), load_params(advanced_params_path())
    assert 40 <= len(users) <= 55 and len(internals) >= 60, (len(users), len(internals))
    assert not set(users) & set(internals)
    defaults = PipelineConfig()
    for key, value in {**users, **internals}.items():
        section, _, name = key.partition('.')
        config = getattr(defaults, section, None)
        if not dataclasses.is_dataclass(config) or not name:
            continue  # live.* (the nodes read them), top-level keys, georef.enabled
        if name in {f.name for f in dataclasses.fields(config)}:
            field = getattr(config, name)
            field = list(field) if isinstance(field, tuple) else field
            assert field == value or (isinstance(value, float) and math.isnan(value) and math.isnan(field)), key
    assert pipeline_config({'registration.ratio': 0.7, 'georef.ut_alpha': 0.5}).registration.ratio == 0.7
    with pytest.raises(ConfigError, match="unknown parameter 'georef.ut_alfa'"):
        pipeline_config({'georef.ut_alfa': 0.5})


@pytest.mark.parametrize(('key', 'value', 'expect'), [
    ('georef.enabled', 'false', "must be a boolean (true or false, unquoted), got the string 'false'. Write false"),
    ('registration.opencv_fallback', 'false', 'must be a boolean'),
    ('registration.max_features', 'lots', "'registration.max_features' must be an integer, got the string 'lots'"),
    ('registration.max_features', 1000.5, 'must be an integer, got float 1000.5'),
    ('georef.nominal_agl_m', True, 'must be a number, got bool True'),
    ('mosaic.blend', 3, 'must be a string'),
])
def test_parameters_are_typed_strictly(key, value, expect):
    """A quoted boolean used to read as true, a word for a number failed far away without the key."""
    from srmosaic_ros.errors import ConfigError

    with pytest.raises(ConfigError, match=re.escape(expect)):
        pipeline_config({key: value})


def test_an_integer_for_a_float_parameter_is_a_float():
    assert pipeline_config({'georef.nominal_agl_m': 60}).georef.nominal_agl_m == 60.0
    assert isinstance(pipeline_config({'georef.nominal_agl_m': 60}).georef.nominal_agl_m, float)


def test_the_device_reaches_sr_unless_sr_has_its_own():
    """`--device cpu` set `device` only, and SR (sr.device: auto) still chose for itself."""
    from srmosaic_ros.config import pipeline_config

    assert pipeline_config({'device': 'cpu'}).sr.device == 'cpu'
    assert pipeline_config({}).sr.device == 'auto'
    assert pipeline_config({'device': 'cpu', 'sr.device': 'cuda'}).sr.device == 'cuda'


def test_a_section_refusal_is_a_config_error():
    """Every invalid setting reaches the user as a ConfigError naming it, whatever stage checks it."""
    from srmosaic_ros.errors import ConfigError

    with pytest.raises(ConfigError, match='psf_sigma'):
        pipeline_config({'sr.psf_sigma': -1.0})
