"""Mosaic settings; the field names are the keys under `mosaic.` in params/*.yaml."""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ['MosaicConfig', 'BLEND_MODES', 'INTERPOLATION_MODES', 'SEAM_MODES']

BLEND_MODES = ('feather', 'multiband', 'bestview')
SEAM_MODES = ('cut', 'score')
INTERPOLATION_MODES = ('cubic', 'lanczos', 'linear')  # resample.INTERPOLATIONS' keys


@dataclass(frozen=True)
class MosaicConfig:
    tile_size: int = 256
    blend: str = 'bestview'
    max_stretch: float = 4.0  # frame pixels this many times coarser than the frame's finest are not painted (0: all)
    interpolation: str = 'cubic'  # how frames are resampled onto the mosaic: cubic | lanczos (clamped) | linear (resample.py)
    recency_frames: int = 90  # bestview: a frame this many frames newer wins over an e-fold better view (0: none)
    seams: str = 'score'  # bestview, multiband: 'score' (where view scores cross) | 'cut' (graph cut: where frames agree, seam_cut.py)
    agree: float = 0.0  # bestview: frames within this of the winner (intensity) are averaged into it (0: none)
    moving: float = 0.0  # bestview: moving objects kept out where a frame differs from the pixel's background by this (intensity; 0: off)
    moving_history: int = 5  # bestview with moving: colour samples kept per pixel; their median is the background (odd, 3..31)
    max_canvas_side_px: int = 100000
    preview_max_side_px: int = 1024
    max_tiles_in_memory: int = 256  # per canvas; 0: no bound (see canvas.TiledCanvas)
    spill_dir: str = ''  # parent of the spill directories; '': $TMPDIR, else /var/tmp
    keyframe_interval: int = 10  # register every n-th frame of a segment to the mosaic (0: never); see keyframe.py
    keyframe_revisit_frames: int = 20  # only where the frame revisits ground painted this many frames before (0: always)
    keyframe_min_coverage: float = 0.5  # fraction of the frame's view the mosaic must cover
    keyframe_min_correction_px: float = 2.0  # smaller corner corrections are not applied: within the noise of a registration to the mosaic
    keyframe_max_correction_px: float = 40.0  # larger corner corrections are refused (prediction kept)
    settle_s: float = 3.0  # a georeferenced segment's first frames are painted once this span of them is placed (0: at once)
    settle_max_frames: int = 30  # ... or once this many are held, whichever comes first
    revisit_spread_frames: int = 30  # frames painted this many frames late, so a revisit correction reaches back over them (revisit.py; 0: at once)
    paint_stride: int = 3  # a frame within paint_shift_px of the last painted one is painted only every paint_stride-th (thinning.py; 1: every frame)
    paint_shift_px: float = 16.0  # ... a frame whose footprint corners moved this far (mosaic px) is always painted
    max_width: int = 1280  # frames wider are painted at the coarser ground sampling that brings them to this width (0: their own)

    def __post_init__(self) -> None:
        if not 64 <= self.tile_size <= 4096:
            msg = f'mosaic.tile_size must be in 64..4096, got {self.tile_size}.'
            raise ValueError(msg)
        if self.blend not in BLEND_MODES:
            msg = f"mosaic.blend must be one of {', '.join(BLEND_MODES)}, got {self.blend!r}."
            raise ValueError(msg)
        if not (isinstance(self.max_stretch, (int, float)) and math.isfinite(self.max_stretch)
                and (self.max_stretch == 0 or self.max_stretch > 1)):
            msg = (f'mosaic.max_stretch must be 0 (paint every frame pixel) or a number > 1, got {self.max_stretch!r}; '
                   '4 leaves out the far field and sky of oblique views.')
            raise ValueError(msg)
        if self.interpolation not in INTERPOLATION_MODES:
            msg = (f"mosaic.interpolation must be one of {', '.join(INTERPOLATION_MODES)} (cubic: frames painted as "
                   f"sharp as they are; linear: the fastest, softer), got {self.interpolation!r}.")
            raise ValueError(msg)
        if isinstance(self.recency_frames, bool) or not isinstance(self.recency_frames, int) or self.recency_frames < 0:
            msg = f'mosaic.recency_frames must be an integer >= 0 (0: no preference for newer frames), got {self.recency_frames!r}.'
            raise ValueError(msg)
        if self.seams not in SEAM_MODES:
            msg = f"mosaic.seams must be one of {', '.join(SEAM_MODES)} (cut: seams where frames agree), got {self.seams!r}."
            raise ValueError(msg)
        if not (isinstance(self.agree, (int, float)) and 0.0 <= self.agree < 1.0):
            msg = f'mosaic.agree must be in [0, 1) (intensity; 0: one frame per pixel), got {self.agree!r}.'
            raise ValueError(msg)
        if not (isinstance(self.moving, (int, float)) and 0.0 <= self.moving < 1.0):
            msg = f'mosaic.moving must be in [0, 1) (intensity; 0: no vote), got {self.moving!r}.'
            raise ValueError(msg)
        if isinstance(self.moving_history, bool) or not isinstance(self.moving_history, int) \
                or not 3 <= self.moving_history <= 31 or self.moving_history % 2 == 0:
            msg = (f'mosaic.moving_history must be an odd integer in 3..31 (colour samples per mosaic pixel whose median '
                   f'is the background), got {self.moving_history!r}.')
            raise ValueError(msg)
        if self.max_canvas_side_px < 256:
            msg = f'mosaic.max_canvas_side_px must be >= 256, got {self.max_canvas_side_px}.'
            raise ValueError(msg)
        if self.preview_max_side_px < 16:
            msg = f'mosaic.preview_max_side_px must be >= 16, got {self.preview_max_side_px}.'
            raise ValueError(msg)
        if isinstance(self.max_tiles_in_memory, bool) or not isinstance(self.max_tiles_in_memory, int) \
                or self.max_tiles_in_memory < 0:
            msg = f'mosaic.max_tiles_in_memory must be an integer >= 0 (0: no bound), got {self.max_tiles_in_memory!r}.'
            raise ValueError(msg)
        if isinstance(self.keyframe_interval, bool) or not isinstance(self.keyframe_interval, int) \
                or self.keyframe_interval < 0:
            msg = f'mosaic.keyframe_interval must be an integer >= 0 (0: no keyframes), got {self.keyframe_interval!r}.'
            raise ValueError(msg)
        if isinstance(self.keyframe_revisit_frames, bool) or not isinstance(self.keyframe_revisit_frames, int) \
                or self.keyframe_revisit_frames < 0:
            msg = f'mosaic.keyframe_revisit_frames must be an integer >= 0 (0: every keyframe), got {self.keyframe_revisit_frames!r}.'
            raise ValueError(msg)
        if not 0.0 < self.keyframe_min_coverage <= 1.0:
            msg = f'mosaic.keyframe_min_coverage must be in (0, 1], got {self.keyframe_min_coverage}.'
            raise ValueError(msg)
        if not (isinstance(self.keyframe_min_correction_px, (int, float)) and 0.0 <= self.keyframe_min_correction_px
                < self.keyframe_max_correction_px):
            msg = (f'mosaic.keyframe_min_correction_px must be >= 0 and below keyframe_max_correction_px '
                   f'({self.keyframe_max_correction_px}), got {self.keyframe_min_correction_px!r}.')
            raise ValueError(msg)
        if not self.keyframe_max_correction_px > 0.0:
            msg = f'mosaic.keyframe_max_correction_px must be > 0, got {self.keyframe_max_correction_px}.'
            raise ValueError(msg)
        if not (isinstance(self.settle_s, (int, float)) and 0.0 <= self.settle_s <= 600.0):
            msg = f'mosaic.settle_s must be in 0 .. 600 seconds (0: paint a segment\'s first frames at once), got {self.settle_s!r}.'
            raise ValueError(msg)
        if isinstance(self.max_width, bool) or not isinstance(self.max_width, int) \
                or not (self.max_width == 0 or self.max_width >= 64):
            msg = f'mosaic.max_width must be 0 (the frames\' own resolution) or an integer >= 64, got {self.max_width!r}.'
            raise ValueError(msg)
        if isinstance(self.settle_max_frames, bool) or not isinstance(self.settle_max_frames, int) \
                or not 1 <= self.settle_max_frames <= 1000:
            msg = f'mosaic.settle_max_frames must be an integer in 1 .. 1000, got {self.settle_max_frames!r}.'
            raise ValueError(msg)
        if isinstance(self.revisit_spread_frames, bool) or not isinstance(self.revisit_spread_frames, int) \
                or not 0 <= self.revisit_spread_frames <= 1000:
            msg = (f'mosaic.revisit_spread_frames must be an integer in 0 .. 1000 (0: paint every frame at once), '
                   f'got {self.revisit_spread_frames!r}.')
            raise ValueError(msg)
        if isinstance(self.paint_stride, bool) or not isinstance(self.paint_stride, int) or not 1 <= self.paint_stride <= 100:
            msg = f'mosaic.paint_stride must be an integer in 1 .. 100 (1: paint every frame), got {self.paint_stride!r}.'
            raise ValueError(msg)
        if not 0.0 <= self.paint_shift_px <= 1e6:
            msg = f'mosaic.paint_shift_px must be in 0 .. 1e6 mosaic pixels, got {self.paint_shift_px!r}.'
            raise ValueError(msg)
        if not isinstance(self.spill_dir, str):
            msg = f"mosaic.spill_dir must be a directory path or '' (a temporary directory), got {self.spill_dir!r}."
            raise ValueError(msg)
