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
    assert {p.name for p in PARAMS} >= {'default.yaml', 'eo_camera.yaml', 'ir_camera.yaml', 'gpu.yaml', 'live_hd.yaml', 'detail.yaml'}
    assert default_params_path().name == 'default.yaml'


def test_live_keys_have_descriptions_and_ranges():
    """Every live.* key of default.yaml and advanced.yaml is described (its comment), is a LiveConfig field
    with the same default, and numeric ones declare a range."""
    import dataclasses

    from srmosaic_ros.live.live_config import LiveConfig
    from srmosaic_ros.nodes.parameters import _comments, parameter_bounds

    bounds = parameter_bounds()
    live = {}
    for path in (default_params_path(), advanced_params_path()):
        comments = _comments(path)
        for key, value in load_params(path).items():
            if key.startswith('live.'):
                live[key[5:]] = value
                assert comments.get(key), f'{key} has no description comment in {path.name}'
                if isinstance(value, int | float) and not isinstance(value, bool):
                    assert key in bounds, f'{key} declares no range (live/live_config.py)'
                    assert bounds[key].holds(value), key
    assert live == dataclasses.asdict(LiveConfig()), 'params/*.yaml live.* and LiveConfig disagree'


def test_each_range_is_declared_once_and_agrees_everywhere():
    """The YAML default, the ROS descriptor a node declares and the configuration's check come from one
    declaration: the default is accepted, every value the check accepts lies inside the descriptor's
    range, and a value outside the declared range is refused by the check (offline) and by the node."""
    import math

    from srmosaic_ros.config import pipeline_config
    from srmosaic_ros.errors import ConfigError
    from srmosaic_ros.live.live_config import live_config
    from srmosaic_ros.nodes.parameters import _descriptor, parameter_bounds

    defaults = {**load_params(default_params_path()), **load_params(advanced_params_path())}
    bounds = parameter_bounds()
    assert len(bounds) >= 80, len(bounds)
    for key, b in bounds.items():
        assert key in defaults, f'{key} is declared but in no params file'
        value = defaults[key]
        assert b.holds(tuple(value) if isinstance(value, list) else value), f'{key}: default {value!r} outside {b.text()}'
        desc = _descriptor(key, value, '', True, bounds)
        ros = desc.integer_range or desc.floating_point_range
        if ros and not b.choices:
            lo, hi = ros[0].from_value, ros[0].to_value
            assert lo <= value <= hi, key
            for edge in (lo, hi):  # just outside the descriptor: the check refuses it too
                outside = edge - 1 if edge == lo else edge + 1
                if isinstance(value, float):
                    outside = edge - max(abs(edge) * 1e-6, 1e-9) if edge == lo else edge + max(abs(edge) * 1e-6, 1e-9)
                if math.isinf(outside) or abs(outside) > 1e300 or abs(outside) >= 2**62:
                    continue
                assert not b.holds(type(value)(outside)), f'{key}: {outside!r} outside the descriptor yet accepted'
                build = live_config if key.startswith('live.') else pipeline_config
                with pytest.raises(ConfigError):
                    build({key: type(value)(outside)})


#: a range in words ("(0 .. 1]", "3..31", "(pixels, >= 0)"): each setting's range is declared once, with
#: setting(), and reaches the ROS descriptor and the reference page from there, so a YAML comment that
#: repeats it would be a second copy free to disagree.
_RANGE_IN_WORDS = re.compile(r'\d\s*\.\.\s*<?\s*-?\d|[(,;]\s*[<>]=?\s*-?\d[\d.]*\s*[);]')


@pytest.mark.parametrize('path', PARAMS, ids=[p.name for p in PARAMS])
def test_yaml_comments_do_not_repeat_ranges(path):
    stated = [(n, line.strip()) for n, line in enumerate(path.read_text().splitlines(), 1)
              if '#' in line and _RANGE_IN_WORDS.search(line.split('#', 1)[1])]
    assert not stated, f'{path.name} states ranges the declarations own (core/settings.py setting()): {stated}'


def test_the_range_check_finds_ranges_in_words():
    for text in ('Lowe ratio (0 .. 1]', 'odd, 3..31; bytes', 'pixels (>= 0)', 'tile side (64 .. 4096)', 'x (pixels, > 0): y'):
        assert _RANGE_IN_WORDS.search(text), text
    for text in ('auto (global when >= 3 stills carry GPS)', '1920 -> 960', 'NaN: first fix - nominal_agl_m'):
        assert not _RANGE_IN_WORDS.search(text), text


def test_users_see_their_parameters_and_the_internals_apart():
    """default.yaml holds what a user sets (about 55 keys), advanced.yaml the solver internals; they
    share no key, their values are the config dataclasses' defaults, and an internal set in a user's
    file (same dotted name) takes effect, a misspelt one is refused."""
    import dataclasses
    import math

    from srmosaic_ros.config import PipelineConfig
    from srmosaic_ros.errors import ConfigError

    users, internals = load_params(default_params_path()), load_params(advanced_params_path())
    # about 55 a user sets, with the live web map's five (live.map_*)
    assert 40 <= len(users) <= 60 and len(internals) >= 60, (len(users), len(internals))
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
