"""What each node checks in its parameters at start beyond their declared ranges: cross-checks of
several keys, frame ids, the message types, the output folder.

One function per node, on plain values (dotted names) and the PipelineConfig built from them, so that
the nodes (at start) and the launcher (nodes/override_check.py, before it starts any) run the same
code. Each raises SrMosaicError with the problem and the way out.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from ..errors import SrMosaicError
from ..live.live_config import MESSAGE_TYPES

__all__ = ['NODE_CHECKS', 'check_frame_id', 'check_message_types', 'refresh_growth_problem', 'check_sr_frames_kept',
           'check_georef_standalone']


def check_frame_id(name: str, value: Any) -> str:
    """``value`` of live.map_frame or live.body_frame, refused unless a frame id (a non-empty name without a leading /)."""
    if not isinstance(value, str) or not value.strip() or value.startswith('/'):
        msg = f'{name} must be a frame id (a non-empty name without a leading /), got {value!r}.'
        raise SrMosaicError(msg)
    return value


def check_message_types(kind: Any) -> str:
    """live.message_types, refused unless one of MESSAGE_TYPES, or 'typed' where this Python cannot import srmosaic_interfaces."""
    if kind not in MESSAGE_TYPES:
        msg = f'live.message_types must be one of {", ".join(MESSAGE_TYPES)}, got {kind!r}.'
        raise SrMosaicError(msg)
    if kind == 'typed':
        try:
            import srmosaic_interfaces.msg  # noqa: F401 - the check is the import
        except ImportError as exc:
            msg = (f'live.message_types: typed needs the srmosaic_interfaces messages, which this Python cannot '
                   f'import ({exc}): build interfaces/srmosaic_interfaces with colcon and source its '
                   'install/setup.bash before starting the node (docs/guide/live.md, "Typed messages"), or set '
                   'live.message_types: portable for the whole graph.')
            raise SrMosaicError(msg) from None
    return kind


def refresh_growth_problem(value: float) -> str | None:
    """Why live.sr_refresh_growth = ``value`` is refused (at start and by `ros2 param set`), or None."""
    if 0.0 < value <= 1.0:
        return (f'live.sr_refresh_growth = {value} would publish the same tiles again and again; '
                'use 0 (each tile once) or a factor above 1 (default 2.0).')
    return None


def check_sr_frames_kept(kept: int, min_frames: int) -> None:
    """The SR node keeps at least the frames a tile needs (sr_tiles.min_frames)."""
    if kept < min_frames:
        msg = (f'live.sr_frames_kept = {kept} is below sr_tiles.min_frames = '
               f'{min_frames}: no tile could ever be scheduled; raise it.')
        raise SrMosaicError(msg)


def check_georef_standalone(standalone: bool, georef_enabled: bool) -> None:
    """The standalone georef node has nothing to do with the filter disabled."""
    if standalone and not georef_enabled:
        msg = 'live.georef_standalone is true but georef.enabled is false: nothing to do; enable one of them.'
        raise SrMosaicError(msg)


def _mosaic(values: Mapping[str, Any], config: Any) -> None:
    check_message_types(values['live.message_types'])
    for name in ('live.map_frame', 'live.body_frame'):
        check_frame_id(name, values[name])
    if values['live.output_dir']:
        from ..io.output_dir import check_output_dir

        check_output_dir(Path(str(values['live.output_dir'])), 'live.output_dir')


def _georef(values: Mapping[str, Any], config: Any) -> None:
    check_message_types(values['live.message_types'])
    for name in ('live.map_frame', 'live.body_frame'):
        check_frame_id(name, values[name])
    check_georef_standalone(bool(values['live.georef_standalone']), config.georef_enabled)


def _sr(values: Mapping[str, Any], config: Any) -> None:
    if problem := refresh_growth_problem(float(values['live.sr_refresh_growth'])):
        raise SrMosaicError(problem)
    check_sr_frames_kept(int(values['live.sr_frames_kept']), config.sr_tiles.min_frames)
    check_message_types(values['live.message_types'])


def _map_server(values: Mapping[str, Any], config: Any) -> None:
    check_message_types(values['live.message_types'])
    if not str(values['live.map_bind']):
        msg = f"live.map_bind must be an address, got {values['live.map_bind']!r}."
        raise SrMosaicError(msg)


#: node kind -> its checks of (values by dotted name, PipelineConfig of them)
NODE_CHECKS: dict[str, Callable[[Mapping[str, Any], Any], None]] = {
    'mosaic': _mosaic, 'georef': _georef, 'sr': _sr, 'map_server': _map_server}
