"""ROS 2 parameter files: where params/default.yaml is, and reading one into dotted names.

Light on purpose (PyYAML only): the command line and the launcher read parameter files without
importing the pipeline's configuration classes (config.py), which pull in torch and filterpy.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import yaml

from .bounded_yaml import MAX_BYTES, LimitError, load_bounded
from .errors import ConfigError

__all__ = ['advanced_params_path', 'default_params', 'default_params_path', 'load_params', 'yaml_problem']


def default_params_path() -> Path:
    """params/default.yaml of the source tree, or of the installed share/ directory."""
    candidates = [
        Path(__file__).resolve().parent.parent / 'params' / 'default.yaml',
        Path(sys.prefix) / 'share' / 'srmosaic_ros' / 'params' / 'default.yaml',
    ]
    env = os.environ.get('AMENT_PREFIX_PATH', '')
    candidates += [Path(p) / 'share' / 'srmosaic_ros' / 'params' / 'default.yaml' for p in env.split(os.pathsep) if p]
    for path in candidates:
        if path.is_file():
            return path
    msg = 'params/default.yaml not found; reinstall the package (make venv) or pass --params.'
    raise ConfigError(msg)


def advanced_params_path() -> Path:
    """params/advanced.yaml (the solver internals), beside params/default.yaml."""
    path = default_params_path().with_name('advanced.yaml')
    if not path.is_file():
        msg = f'{path} not found (it is installed with params/default.yaml); reinstall the package (make venv).'
        raise ConfigError(msg)
    return path


def default_params() -> dict[str, Any]:
    """Every parameter's default, dotted names: params/default.yaml (what users set) and
    params/advanced.yaml (solver internals), which share no key."""
    return {**load_params(default_params_path()), **load_params(advanced_params_path())}


def _flatten(tree: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(_flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def yaml_problem(exc: yaml.YAMLError) -> str:
    """PyYAML's several-line message as one line: what is wrong, and where (line, column)."""
    problem = getattr(exc, 'problem', None)
    mark = getattr(exc, 'problem_mark', None)
    if problem is None:
        return ' '.join(str(exc).split())
    where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark is not None else ''
    return f'{problem}{where}'


def load_params(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a ROS 2 parameter file; return dotted names -> values, merged over all node sections."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_BYTES:
            msg = (f'parameter file {path} is {path.stat().st_size} bytes, more than the {MAX_BYTES} a parameter file '
                   'may hold; pass the file of settings, not another file.')
            raise ConfigError(msg)
        doc = load_bounded(path.read_text())
    except FileNotFoundError:
        msg = f'parameter file {path} does not exist.'
        raise ConfigError(msg) from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as exc:
        msg = f'parameter file {path} cannot be read ({getattr(exc, "strerror", None) or exc}); pass a YAML text file.'
        raise ConfigError(msg) from None
    except LimitError as exc:
        msg = f'parameter file {path} is refused: {yaml_problem(exc)}.'
        raise ConfigError(msg) from None
    except yaml.YAMLError as exc:
        msg = f'parameter file {path} is not valid YAML: {yaml_problem(exc)}'
        raise ConfigError(msg) from None
    if not isinstance(doc, dict):
        msg = f'parameter file {path} must map node names to {{ros__parameters: ...}}.'
        raise ConfigError(msg)
    flat: dict[str, Any] = {}
    for node, section in doc.items():
        if not isinstance(section, dict) or 'ros__parameters' not in section:
            msg = f'parameter file {path}: section {node!r} has no ros__parameters.'
            raise ConfigError(msg)
        flat.update(_flatten(section['ros__parameters'] or {}))
    return flat
