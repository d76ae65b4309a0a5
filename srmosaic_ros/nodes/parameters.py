"""Declare the pipeline's parameters on a node, with descriptions and ranges from params/default.yaml
and params/advanced.yaml.

Those two files are the one source of defaults: every key in them is declared with its default,
the comment after it as description, and the range its configuration dataclass declares once
(core/settings.setting; live.* on live/live_config.LiveConfig). Values
given with `--ros-args --params-file FILE` or `-p name:=value` override them; invalid values are
refused at start (ConfigError) with the dataclass's message.

Each node declares its own keys only (MOSAIC_PARAMETERS, GEOREF_PARAMETERS, SR_PARAMETERS below), so
`ros2 param list` shows what it uses. Parameters are read-only once the node runs (`ros2 param set` is refused with rclpy's reason), except
those a node names as changeable: their changes are checked (type and range by the descriptor, then
the node's own check) and take effect at once (`on_parameter_change`).
"""
from __future__ import annotations

import re
from pathlib import Path
from collections.abc import Callable, Collection
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node

from ..config import PipelineConfig, pipeline_config, setting_bounds
from ..core.settings import Bounds, bounds_of
from ..live.live_config import LiveConfig, live_config
from ..param_files import advanced_params_path, default_params, default_params_path

__all__ = ['MOSAIC_PARAMETERS', 'GEOREF_PARAMETERS', 'SR_PARAMETERS', 'MAP_SERVER_PARAMETERS', 'declare_pipeline_parameters',
           'read_pipeline_config', 'on_parameter_change']

#: The keys each node declares: names, or section prefixes for all the keys of a section.
_POSE_OUTPUT = ('live.map_frame', 'live.body_frame', 'live.georef_standalone', 'live.reliable_inputs', 'live.preview_period_s',
                'live.message_types')
MOSAIC_PARAMETERS = ('device', 'undistort', 'stamp_tolerance_s', 'registration', 'mosaic', 'georef', *_POSE_OUTPUT,
                     'live.queue_size', 'live.max_rate_hz', 'live.torch_threads', 'live.output_dir', 'live.autostart',
                     'live.map_tiles', 'live.map_level', 'live.map_bytes_per_s')
GEOREF_PARAMETERS = ('undistort', 'stamp_tolerance_s', 'georef', *_POSE_OUTPUT, 'live.autostart')
SR_PARAMETERS = ('device', 'undistort', 'stamp_tolerance_s', 'sr', 'sr_tiles', 'live.reliable_inputs', 'live.torch_threads',
                 'live.sr_period_s', 'live.sr_tiles_per_round', 'live.sr_refresh_growth', 'live.sr_frames_kept',
                 'live.sr_images_pending', 'live.sr_worker', 'live.message_types', 'live.map_tiles', 'live.sr_map_bytes_per_s')
MAP_SERVER_PARAMETERS = ('live.map_port', 'live.map_bind', 'live.message_types')

def parameter_bounds() -> dict[str, Bounds]:
    """Dotted key -> Bounds of every parameter that declares its range once (config dataclasses, LiveConfig)."""
    return {**setting_bounds(), **{f'live.{name}': b for name, b in bounds_of(LiveConfig).items()}}


def _comments(path: Path) -> dict[str, str]:
    """Trailing comments of a parameter file (params/default.yaml, advanced.yaml) keyed by dotted name
    (the descriptions)."""
    out: dict[str, str] = {}
    stack: list[tuple[int, str]] = []
    for line in path.read_text().splitlines():
        m = re.match(r'^(\s*)([A-Za-z_][\w]*):\s*([^#]*?)\s*(?:#\s*(.*))?$', line)
        if not m:
            continue
        indent, key, value, comment = len(m.group(1)), m.group(2), m.group(3), m.group(4)
        while stack and stack[-1][0] >= indent:
            stack.pop()
        if value == '':
            stack.append((indent, key))
            continue
        parents = [k for _, k in stack if k not in ('ros__parameters',) and not k.startswith('/')]
        out['.'.join([*parents, key])] = comment or ''
    return out


def _descriptor(name: str, value: Any, description: str, read_only: bool,
                bounds: dict[str, Bounds] | None = None) -> ParameterDescriptor:
    desc = ParameterDescriptor(name=name, description=description, read_only=read_only)
    if isinstance(value, bool):
        return desc
    declared = (bounds if bounds is not None else parameter_bounds()).get(name)
    if declared is None:
        return desc
    desc.additional_constraints = declared.text()
    span = declared.ros_range(isinstance(value, int))
    if span is not None:
        lo, hi = span
        if isinstance(value, int):
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
        elif isinstance(value, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return desc


def declare_pipeline_parameters(node: Node, own: Collection[str], changeable: Collection[str] = ()) -> dict[str, Any]:
    """Declare the node's own keys of params/default.yaml and advanced.yaml on `node` (`own`: names or section
    prefixes, 'georef' for every georef.* key), read-only but for `changeable`; return the defaults
    of every key (dotted names). Keys of other nodes in a shared parameter file are left undeclared,
    which rclpy ignores."""
    defaults = default_params()
    comments = {**_comments(default_params_path()), **_comments(advanced_params_path())}
    bounds = parameter_bounds()
    for name, value in defaults.items():
        if _is_own(name, own) and not node.has_parameter(name):
            node.declare_parameter(name, value, _descriptor(name, value, comments.get(name, ''), name not in changeable, bounds))
    if unknown := [name for name in changeable if name not in defaults or not _is_own(name, own)]:
        msg = f'changeable parameters {unknown} are not among the node\'s own'
        raise ValueError(msg)
    return defaults


def _is_own(name: str, own: Collection[str]) -> bool:
    return any(name == prefix or name.startswith(prefix + '.') for prefix in own)


def read_pipeline_config(node: Node, defaults: dict[str, Any]) -> PipelineConfig:
    """PipelineConfig from the node's parameter values, the defaults for keys it does not declare
    (raises ConfigError when invalid)."""
    values = {name: node.get_parameter(name).value for name in defaults if node.has_parameter(name)}
    live_config(values)  # the live.* keys' checks (ConfigError), from their one declaration
    return pipeline_config(values, defaults=defaults)


def on_parameter_change(node: Node, apply: dict[str, Callable[[Any], None]],
                        check: dict[str, Callable[[Any], str | None]] | None = None) -> None:
    """Changes of the changeable parameters take effect: `check[name](value)` may refuse one (the
    reason it returns reaches `ros2 param set`), then `apply[name](value)` runs once rclpy stored it."""
    check = check or {}
    for name in apply:
        if node.describe_parameter(name).read_only:
            msg = f'{name} is read-only; declare it changeable to apply its changes'
            raise ValueError(msg)

    def refuse(params: list) -> SetParametersResult:
        for param in params:
            reason = check[param.name](param.value) if param.name in check else None
            if reason:
                return SetParametersResult(successful=False, reason=f'{param.name}: {reason}')
        return SetParametersResult(successful=True)

    def take_effect(params: list) -> None:
        for param in params:
            if param.name in apply:
                apply[param.name](param.value)
                node.get_logger().info(f'{param.name} is now {param.value!r}')

    node.add_on_set_parameters_callback(refuse)
    node.add_post_set_parameters_callback(take_effect)
