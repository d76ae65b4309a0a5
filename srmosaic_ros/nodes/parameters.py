"""Declare the pipeline's parameters on a node, with descriptions and ranges from params/default.yaml
and params/advanced.yaml.

Those two files are the one source of defaults: every key in them is declared with its default,
the comment after it as description, and a range where the config dataclass has one. Values
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

from ..config import PipelineConfig, pipeline_config
from ..core.sr_factors import SR_FACTORS
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
                 'live.sr_images_pending', 'live.sr_worker', 'live.message_types')
MAP_SERVER_PARAMETERS = ('live.map_port', 'live.map_bind', 'live.message_types')

# Ranges stated once here for the ROS parameter descriptors; the dataclasses check them again.
_RANGES: dict[str, tuple[float, float]] = {
    'registration.max_features': (8, 100000),
    'registration.contrast_threshold': (0.0, 1.0),
    'registration.ratio': (0.0, 1.0),
    'registration.ransac_threshold_px': (0.01, 50.0),
    'registration.ransac_confidence': (0.5, 0.999999),
    'registration.ransac_max_iterations': (1, 1000000),
    'registration.min_inliers': (4, 100000),
    'registration.min_inlier_ratio': (0.0, 1.0),
    'registration.max_rms_px': (0.01, 50.0),
    'registration.max_scale_change': (1.0, 10.0),
    'registration.max_perspective': (0.001, 10.0),
    'registration.guided_radius_px': (0.0, 100.0),
    'registration.max_width': (0, 100000),
    'registration.track_frames': (0, 100000),
    'mosaic.tile_size': (64, 4096),
    'mosaic.max_canvas_side_px': (256, 10000000),
    'mosaic.preview_max_side_px': (16, 16384),
    'mosaic.max_tiles_in_memory': (0, 1000000),
    'mosaic.settle_s': (0.0, 600.0),
    'mosaic.settle_max_frames': (1, 1000),
    'mosaic.revisit_spread_frames': (0, 1000),
    'mosaic.keyframe_min_correction_px': (0.0, 1000.0),
    'mosaic.max_width': (0, 100000),
    'live.queue_size': (1, 100),
    'live.max_rate_hz': (0.0, 1000.0),
    'live.torch_threads': (0, 256),
    'live.preview_period_s': (0.05, 3600.0),
    'live.sr_period_s': (0.1, 3600.0),
    'live.sr_tiles_per_round': (1, 100),
    'live.sr_frames_kept': (1, 1000),
    'live.sr_refresh_growth': (0.0, 100.0),
    'live.sr_images_pending': (1, 1000),
    'live.map_level': (0, 12),
    'live.map_bytes_per_s': (0, 10_000_000_000),
    'live.map_port': (1, 65535),
    'sr.psf_sigma': (0.0, 10.0),
    'sr.iterations': (0, 10000),
    'sr.margin': (0, 256),
    'sr_tiles.factor': (min(SR_FACTORS), max(SR_FACTORS)),
    'sr_tiles.tile_size': (16, 2048),
    'sr_tiles.min_frames': (1, 1000),
    'sr_tiles.max_frames': (1, 1000),
    'sr_tiles.max_tiles': (1, 1000000),
    'sr_tiles.min_coverage': (0.0, 1.0),
}


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


def _descriptor(name: str, value: Any, description: str, read_only: bool) -> ParameterDescriptor:
    desc = ParameterDescriptor(name=name, description=description, read_only=read_only)
    if name in _RANGES and not isinstance(value, bool):
        lo, hi = _RANGES[name]
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
    for name, value in defaults.items():
        if _is_own(name, own) and not node.has_parameter(name):
            node.declare_parameter(name, value, _descriptor(name, value, comments.get(name, ''), name not in changeable))
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
