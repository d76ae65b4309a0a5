"""The launcher's check of ``-p name:=value`` overrides, before it starts any node.

A node refuses a bad parameter when it starts (rclpy for a value of the wrong type, then the
configuration's own checks), by then the launcher has started the other processes of the graph,
and they are stopped again. `srmosaic launch` runs the same checks first, from the same declarations
(params/default.yaml and advanced.yaml for the names and types, core/settings.setting for the
ranges through pipeline_config and live_config, the nodes' own cross-checks in node_checks.py), for
every node of the graph the override reaches:

- a name that no node of the graph declares (a typo rclpy would ignore without a word);
- a value of another type than the parameter's default (rclpy's InvalidParameterTypeException), or
  outside the range of its descriptor (nodes/parameters.py; rclpy's InvalidParameterValueException);
- a value the configuration refuses (out of range, not one of the choices, a cross-check).

Only the overrides are judged: a value from a parameter file is the context they are judged in, and
a problem of the files alone is left to the nodes, as before.
"""
from __future__ import annotations

import difflib
from collections.abc import Collection, Iterable, Mapping
from typing import Any

from ..bounded_yaml import load_bounded, preview
from ..errors import ConfigError, SrMosaicError
from ..param_files import default_params, load_params

__all__ = ['EXECUTABLE_KINDS', 'ROS_PARAMETERS', 'check_overrides', 'parse_overrides']

#: Parameters rclpy declares on every node itself (rcl's own, not in params/*.yaml).
ROS_PARAMETERS = ('use_sim_time', 'start_type_description_service')
_ROS_PREFIXES = ('qos_overrides.',)


def _node_parameters() -> dict[str, tuple[str, ...]]:
    from .parameters import GEOREF_PARAMETERS, MAP_SERVER_PARAMETERS, MOSAIC_PARAMETERS, SR_PARAMETERS

    return {'mosaic': MOSAIC_PARAMETERS, 'georef': GEOREF_PARAMETERS, 'sr': SR_PARAMETERS, 'map_server': MAP_SERVER_PARAMETERS}


#: launch-file executable or description node name -> the node kind whose keys it declares
EXECUTABLE_KINDS = {'mosaic_node': 'mosaic', 'georef_node': 'georef', 'sr_node': 'sr', 'map_server': 'map_server',
                    'mosaic': 'mosaic', 'georef': 'georef', 'sr': 'sr'}


def parse_overrides(ros_arguments: Iterable[str]) -> dict[str, Any]:
    """``-p name:=value`` (``--param``) of a --ros-args list -> {name: value read as YAML, as rcl reads -p}."""
    args = [a for a in ros_arguments if a != '--ros-args']
    out: dict[str, Any] = {}
    for flag, text in zip(args, args[1:]):
        if flag in ('-p', '--param') and ':=' in text:
            name, _, value = text.partition(':=')
            out[name] = load_bounded(value) if value else ''
    return out


def _is_own(name: str, own: Collection[str]) -> bool:
    return any(name == prefix or name.startswith(prefix + '.') for prefix in own)


def _is_ros(name: str) -> bool:
    return name in ROS_PARAMETERS or name.startswith(_ROS_PREFIXES)


def _type_problem(name: str, value: Any, default: Any) -> str | None:
    """rclpy's refusal of ``value`` for a parameter declared with ``default`` (its type), or None."""
    from rclpy.exceptions import InvalidParameterTypeException
    from rclpy.parameter import Parameter

    try:
        given = Parameter.Type.from_parameter_value(value)
    except TypeError as exc:
        return f'invalid parameter {name}: {exc}'
    declared = Parameter.Type.from_parameter_value(default)
    if isinstance(default, list) and isinstance(value, list) and (not default or not value):
        return None  # an empty list has no element type to compare
    if given != declared:
        return f'invalid parameter: {InvalidParameterTypeException(Parameter(name, value=value), declared.name)}'
    return None


def _range_problem(name: str, value: Any, descriptor: Any) -> str | None:
    """rclpy's refusal of ``value`` outside the range of the parameter's descriptor (nodes/parameters._descriptor),
    by rclpy's own rule (the ends included, doubles to its relative tolerance), or None."""
    from rclpy.exceptions import InvalidParameterValueException
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    parameter = Parameter(name, value=value)
    if isinstance(value, int) and not isinstance(value, bool) and descriptor.integer_range:
        result = Node._apply_integer_range(Node, parameter, descriptor.integer_range[0])  # self: its PARAM_REL_TOL only
    elif isinstance(value, float) and descriptor.floating_point_range:
        result = Node._apply_floating_point_range(Node, parameter, descriptor.floating_point_range[0])
    else:
        return None
    if result.successful:
        return None
    return f'invalid parameter: {InvalidParameterValueException(name, value, result.reason)}'


def _unknown(name: str, where: str, candidates: Collection[str], defaults: Mapping[str, Any]) -> str:
    """The refusal of ``-p name`` that no node ``where`` declares; ``candidates``: the names they do declare."""
    from ..config import REPLACED_KEYS

    if name in REPLACED_KEYS:
        new, why = REPLACED_KEYS[name]
        return f'parameter {name!r} was replaced by {new!r}: {why}. Remove it or set {new!r} instead.'
    if name in defaults:
        users = [kind for kind, keys in _node_parameters().items() if _is_own(name, keys)]
        whose = f"a parameter of {', '.join(users)}" if users else 'read by `srmosaic process` only'
        return f'-p {name}: no node {where} declares it ({whose}); drop it, or start the node that reads it.'
    close = difflib.get_close_matches(name, list(candidates), n=1)
    hint = f'; did you mean {close[0]}?' if close else '.'
    return (f'-p {preview(name)}: no node {where} declares this parameter{hint} The parameters are the keys of '
            'params/default.yaml and params/advanced.yaml (docs/reference/parameters.md).')


def _config_problem(kind: str, values: dict[str, Any], defaults: dict[str, Any]) -> str | None:
    """What node ``kind`` would refuse at start in these values (dotted names), or None."""
    from ..config import pipeline_config
    from ..live.live_config import live_config
    from .node_checks import NODE_CHECKS

    try:
        live_config(values)
        config = pipeline_config(values, defaults=defaults)
        NODE_CHECKS[kind](values, config)
    except SrMosaicError as exc:
        return str(exc)
    return None


def check_overrides(overrides: Mapping[str, Any], nodes: Mapping[str, str], files: Mapping[str, Iterable[str]] | None = None,
                    node_overrides: Mapping[str, Mapping[str, Any]] | None = None) -> None:
    """Refuse (ConfigError, one line) the overrides a node of the graph would refuse at start.

    overrides: {name: value} given to every node (the launcher's -p); nodes: {label: kind} of the
    nodes the launch starts (mosaic, georef, sr, map_server; other executables are not judged);
    files: {label: parameter files} each node reads before its overrides; node_overrides: {label:
    {name: value}} given to that node alone (a description's `parameters:`, a launch file's <param>).
    """
    from .parameters import _descriptor, parameter_bounds

    defaults = default_params()
    bounds = parameter_bounds()
    own = _node_parameters()
    judged = {label: kind for label, kind in nodes.items() if kind in own}
    if not judged:
        return

    def declares(kind: str, name: str) -> bool:
        return name in defaults and _is_own(name, own[kind])

    kinds = sorted(set(judged.values()))
    for name in overrides:
        if not _is_ros(name) and not any(declares(kind, name) for kind in kinds):
            raise ConfigError(_unknown(name, f"this launch starts ({', '.join(kinds)})",
                                       [k for k in defaults if any(declares(kind, k) for kind in kinds)], defaults))
    for label, kind in judged.items():
        given = {**overrides, **((node_overrides or {}).get(label) or {})}
        for name in (node_overrides or {}).get(label) or {}:
            if not _is_ros(name) and not declares(kind, name):
                raise ConfigError(_unknown(name, f'{label} ({kind})', [k for k in defaults if declares(kind, k)], defaults))
        mine = {name: value for name, value in given.items() if declares(kind, name)}
        for name, value in mine.items():  # rclpy's checks as the node declares each parameter: type, then range
            if problem := _type_problem(name, value, defaults[name]) or _range_problem(
                    name, value, _descriptor(name, defaults[name], '', True, bounds)):
                raise ConfigError(f'{label} would refuse its parameters: {problem}')
        context = dict(defaults)  # what the node reads: its own keys from the files, the defaults for the others
        for path in (files or {}).get(label) or []:
            context.update({k: v for k, v in load_params(path).items() if declares(kind, k)})
        if not mine or _config_problem(kind, context, defaults) is not None:
            continue  # nothing of its own, or the files alone are refused: the node says so at start
        if problem := _config_problem(kind, {**context, **mine}, defaults):
            raise ConfigError(f'{label} would refuse its parameters: {problem}')
