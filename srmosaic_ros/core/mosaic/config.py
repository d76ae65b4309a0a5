"""Mosaic settings; the field names are the keys under `mosaic.` in params/*.yaml."""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ['MosaicConfig', 'BLEND_MODES']

BLEND_MODES = ('feather', 'multiband')


@dataclass(frozen=True)
class MosaicConfig:
    tile_size: int = 256
    blend: str = 'feather'
    max_canvas_side_px: int = 100000
    preview_max_side_px: int = 1024

    def __post_init__(self) -> None:
        if not 64 <= self.tile_size <= 4096:
            msg = f'mosaic.tile_size must be in 64..4096, got {self.tile_size}.'
            raise ValueError(msg)
        if self.blend not in BLEND_MODES:
            msg = f"mosaic.blend must be one of {', '.join(BLEND_MODES)}, got {self.blend!r}."
            raise ValueError(msg)
        if self.max_canvas_side_px < 256:
            msg = f'mosaic.max_canvas_side_px must be >= 256, got {self.max_canvas_side_px}.'
            raise ValueError(msg)
        if self.preview_max_side_px < 16:
            msg = f'mosaic.preview_max_side_px must be >= 16, got {self.preview_max_side_px}.'
            raise ValueError(msg)
