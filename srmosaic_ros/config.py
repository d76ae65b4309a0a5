"""Parameters: load params/*.yaml (ros__parameters) into the frozen config dataclasses of the core.

params/default.yaml (what users set) and params/advanced.yaml (solver internals) are the one source
of defaults. A user file overrides any subset of their keys; an unknown key is refused with the list
of known ones, so a typo never silently does nothing.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from .core.georef.georef_config import GeorefConfig
from .core.mosaic.config import MosaicConfig
from .core.sr.sr_config import SRConfig
from .core.sr.scheduler import SRTileConfig
from .core.registration.registrar import RegistrationConfig
from .core.survey.config import SurveyConfig
from .bounded_yaml import preview
from .core.settings import Bounds, bounds_of, setting
from .errors import ConfigError, SrMosaicError
from .param_files import default_params, default_params_path, load_params, yaml_problem  # re-exported

__all__ = ['SECTIONS', 'PipelineConfig', 'check_type', 'default_params', 'default_params_path', 'load_params',
           'pipeline_config', 'setting_bounds', 'yaml_problem']

DEVICES = ('auto', 'cpu', 'cuda')
#: A section's refusal longer than this (characters: a long value quoted whole) is shortened.
MAX_MESSAGE_CHARS = 400

#: Replaced keys: old dotted name -> (new dotted name, why). Their values cannot be converted,
#: so a file that sets one is refused with a message naming the new key.
REPLACED_KEYS = {
    'georef.drift_pose_correlation_frames': (
        'georef.drift_pose_time_constant_s',
        'drift control now models the pose-error correlation as a time constant in seconds, taken from the '
        'filter by default (NaN); a number of frames meant a different correlation at every frame rate'),
}


@dataclass(frozen=True)
class PipelineConfig:
    """Everything the offline and live pipelines need; mirrors params/default.yaml."""

    device: str = setting('auto', choices=DEVICES)
    undistort: bool = True
    stamp_tolerance_s: float = setting(10.0, lo=0.0, unit='s')  # see core/stamp_gate.py
    registration: RegistrationConfig = RegistrationConfig()
    mosaic: MosaicConfig = MosaicConfig()
    georef_enabled: bool = True
    georef: GeorefConfig = field(default_factory=GeorefConfig)
    sr: SRConfig = field(default_factory=SRConfig)
    sr_tiles: SRTileConfig = field(default_factory=SRTileConfig)
    survey: SurveyConfig = field(default_factory=SurveyConfig)


#: The sections of params/*.yaml and the config dataclass whose fields are their keys.
SECTIONS: dict[str, type] = {'registration': RegistrationConfig, 'mosaic': MosaicConfig, 'georef': GeorefConfig,
                             'sr': SRConfig, 'sr_tiles': SRTileConfig, 'survey': SurveyConfig}


def setting_bounds() -> dict[str, Bounds]:
    """Dotted key -> Bounds of every setting declared with core/settings.setting (the one declaration of
    its range: the ROS descriptors and the docs take it from here)."""
    out = {f'{section}.{name}': b for section, cls in SECTIONS.items() for name, b in bounds_of(cls).items()}
    out.update({name: b for name, b in bounds_of(PipelineConfig).items() if name in ('device', 'stamp_tolerance_s')})
    return out


def _build(cls: type, prefix: str, flat: dict[str, Any]) -> Any:
    kwargs = {f.name: flat[prefix + f.name] for f in fields(cls) if prefix + f.name in flat}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError, SrMosaicError) as exc:  # a section's own refusal (SRError...) is a ConfigError here
        said = str(exc)
        if len(said) > MAX_MESSAGE_CHARS:  # a long value quoted whole: its head and tail say enough
            said = f'{said[:MAX_MESSAGE_CHARS // 2]} ... {said[-MAX_MESSAGE_CHARS // 4:]}'
        raise ConfigError(said) from None


_KINDS = {bool: 'a boolean (true or false, unquoted)', int: 'an integer', float: 'a number', str: 'a string',
          list: 'a list'}


def check_type(key: str, value: Any, default: Any) -> Any:
    """``value`` for parameter ``key`` if it has the type of its default (params/default.yaml): a
    boolean for a boolean (a quoted "false" is a string, and would read as true), an integer for an
    integer, a number (integer or float, not a boolean) for a float, a string for a string, a list
    for a list; ConfigError naming the key, the expected type and what was given otherwise."""
    if default is None or value is None:
        return value
    kind = bool if isinstance(default, bool) else int if isinstance(default, int) else \
        float if isinstance(default, float) else str if isinstance(default, str) else \
        list if isinstance(default, (list, tuple)) else None
    ok = {bool: lambda v: isinstance(v, bool),
          int: lambda v: isinstance(v, int) and not isinstance(v, bool),
          float: lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
          str: lambda v: isinstance(v, str),
          list: lambda v: isinstance(v, (list, tuple)),
          None: lambda v: True}[kind](value)
    if not ok:
        given = f'the string {preview(value)}' if isinstance(value, str) else f'{type(value).__name__} {preview(value)}'
        msg = f'parameter {preview(key)} must be {_KINDS[kind]}, got {given}.'
        if kind is bool and isinstance(value, str) and value.strip().lower() in ('true', 'false'):
            msg += f' Write {value.strip().lower()} without quotes.'
        raise ConfigError(msg)
    return float(value) if kind is float else value


def _stamp_tolerance(value: float) -> float:
    if not (value >= 0):  # NaN too
        msg = f'parameter \'stamp_tolerance_s\' must be >= 0 seconds (0: off), got {value!r}.'
        raise ConfigError(msg)
    return float(value)


def pipeline_config(overrides: dict[str, Any] | None = None, *, defaults: dict[str, Any] | None = None) -> PipelineConfig:
    """PipelineConfig from the defaults file, overridden by `overrides` (dotted names).

    Keys that the pipeline does not know are refused; keys of other stages (nodes, topics, ...)
    that appear in default.yaml are accepted and ignored here.
    """
    flat = dict(defaults if defaults is not None else default_params())
    for key, value in (overrides or {}).items():
        if key in REPLACED_KEYS:
            new, why = REPLACED_KEYS[key]
            msg = f'parameter {key!r} was replaced by {new!r}: {why}. Remove it or set {new!r} instead.'
            raise ConfigError(msg)
        if key not in flat:
            known = ', '.join(sorted(flat))
            msg = f'unknown parameter {preview(key)}; known parameters: {known}.'
            raise ConfigError(msg)
        flat[key] = check_type(key, value, flat[key])
    if 'sr.psf_sigma' in (overrides or {}) and 'sr.psf_ladder' not in (overrides or {}):
        flat['sr.psf_ladder'] = []  # a PSF the user gives is used as given, not chosen from the frames
    device = flat.get('device', 'auto')
    if device not in DEVICES:
        msg = f"device must be one of {', '.join(DEVICES)}, got {preview(device)}."
        raise ConfigError(msg)
    if flat.get('sr.device', 'auto') == 'auto':  # one device for all tensor work unless SR is given its own
        flat['sr.device'] = device
    return PipelineConfig(
        device=device,
        undistort=bool(flat.get('undistort', True)),
        stamp_tolerance_s=_stamp_tolerance(flat.get('stamp_tolerance_s', 10.0)),
        registration=_build(RegistrationConfig, 'registration.', flat),
        mosaic=_build(MosaicConfig, 'mosaic.', flat),
        georef_enabled=bool(flat.get('georef.enabled', True)),
        georef=_build(GeorefConfig, 'georef.', flat),
        sr=_build(SRConfig, 'sr.', {k: tuple(v) if isinstance(v, list) else v for k, v in flat.items()}),
        sr_tiles=_build(SRTileConfig, 'sr_tiles.', flat),
        survey=_build(SurveyConfig, 'survey.', flat),
    )
