"""LiveConfig: the ``live.*`` parameters of the nodes (params/default.yaml, params/advanced.yaml),
each declared once with its default and range (core/settings.py): the nodes' ROS parameter
descriptors, the check at start and the parameter reference all come from these fields.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from ..core.settings import check_settings, setting
from ..errors import ConfigError

__all__ = ['MESSAGE_TYPES', 'SR_WORKERS', 'LiveConfig', 'live_config']

#: live.message_types: the portable encoding (std_msgs and sensor_msgs only) or srmosaic_interfaces' messages.
MESSAGE_TYPES = ('portable', 'typed')
#: live.sr_worker: where the SR node reconstructs tiles.
SR_WORKERS = ('process', 'thread')


@dataclass(frozen=True)
class LiveConfig:
    """The nodes' settings; the field names are the keys under ``live.`` (units in the names: s, Hz)."""

    preview_period_s: float = setting(1.0, lo=0.05, hi=3600.0, unit='s')
    reliable_inputs: bool = False
    output_dir: str = ''
    georef_standalone: bool = False
    message_types: str = setting('portable', choices=MESSAGE_TYPES)
    autostart: bool = True
    map_frame: str = 'srmosaic_enu'
    body_frame: str = 'srmosaic'
    sr_period_s: float = setting(2.0, lo=0.1, hi=3600.0, unit='s')
    sr_tiles_per_round: int = setting(1, lo=1, hi=100)
    sr_refresh_growth: float = setting(2.0, lo=0.0, hi=100.0)
    queue_size: int = setting(8, lo=1, hi=100)
    max_rate_hz: float = setting(0.0, lo=0.0, hi=1000.0, unit='Hz')
    torch_threads: int = setting(1, lo=0, hi=256)
    sr_frames_kept: int = setting(48, lo=1, hi=1000)
    sr_images_pending: int = setting(100, lo=1, hi=1000)
    sr_worker: str = setting('process', choices=SR_WORKERS)
    map_tiles: bool = True
    map_level: int = setting(1, lo=0, hi=12)
    map_bytes_per_s: int = setting(1_000_000, lo=0, hi=10_000_000_000, unit='B/s')
    sr_map_bytes_per_s: int = setting(500_000, lo=0, hi=10_000_000_000, unit='B/s')
    map_port: int = setting(8080, lo=1, hi=65535)
    map_bind: str = '127.0.0.1'

    def __post_init__(self) -> None:
        check_settings(self, 'live')


def live_config(values: dict[str, Any]) -> LiveConfig:
    """LiveConfig from dotted ``live.*`` values (others ignored); ConfigError when one is invalid."""
    names = {f.name for f in fields(LiveConfig)}
    kwargs = {key[5:]: value for key, value in values.items() if key.startswith('live.') and key[5:] in names}
    try:
        return LiveConfig(**kwargs)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
