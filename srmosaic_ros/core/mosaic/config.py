"""Mosaic settings; the field names are the keys under `mosaic.` in params/*.yaml."""
from __future__ import annotations

from dataclasses import dataclass

from ..settings import check_settings, setting

__all__ = ['MosaicConfig', 'BLEND_MODES', 'INTERPOLATION_MODES', 'RESOLUTION_MODES', 'SEAM_MODES']

BLEND_MODES = ('feather', 'multiband', 'bestview')
SEAM_MODES = ('cut', 'score')
INTERPOLATION_MODES = ('cubic', 'lanczos', 'linear')  # resample.INTERPOLATIONS' keys
RESOLUTION_MODES = ('first', 'finest')  # resolution.RESOLUTION_MODES


@dataclass(frozen=True)
class MosaicConfig:
    tile_size: int = setting(256, lo=64, hi=4096)
    blend: str = setting('bestview', choices=BLEND_MODES)
    max_stretch: float = setting(4.0, gt=1.0, zero=True)  # frame pixels this many times coarser than the frame's finest are not painted (0: all)
    # how frames are resampled onto the mosaic: cubic | lanczos (clamped) | linear (resample.py)
    interpolation: str = setting('cubic', choices=INTERPOLATION_MODES)
    # the canvas's sampling: 'first' (the first frame's, scaled to max_width) | 'finest' (the sharpest of a
    # segment's first frames, held for settle_s / settle_max_frames, map as the first would; resolution.py)
    resolution: str = setting('first', choices=RESOLUTION_MODES)
    oversample: float = setting(1.0, lo=1.0, hi=4.0)  # canvas pixels per frame pixel of the frames that set the sampling
    recency_frames: int = setting(90, lo=0)  # bestview: a frame this many frames newer wins over an e-fold better view (0: none)
    # bestview, multiband: 'score' (where view scores cross) | 'cut' (graph cut: where frames agree, seam_cut.py)
    seams: str = setting('score', choices=SEAM_MODES)
    agree: float = setting(0.0, lo=0.0, lt=1.0)  # bestview: frames within this of the winner (intensity) are averaged into it (0: none)
    # bestview: moving objects kept out where a frame differs from the pixel's background by this (intensity; 0: off)
    moving: float = setting(0.0, lo=0.0, lt=1.0)
    # bestview with moving: colour samples kept per pixel; their median is the background (odd, 3..31)
    moving_history: int = setting(5, lo=3, hi=31, odd=True)
    max_canvas_side_px: int = setting(100000, lo=256, hi=10_000_000)
    preview_max_side_px: int = setting(1024, lo=16, hi=16384)
    max_tiles_in_memory: int = setting(256, lo=0, hi=1_000_000)  # per canvas; 0: no bound (see canvas.TiledCanvas)
    spill_dir: str = ''  # parent of the spill directories; '': $TMPDIR, else /var/tmp
    keyframe_interval: int = setting(10, lo=0)  # register every n-th frame of a segment to the mosaic (0: never); see keyframe.py
    keyframe_revisit_frames: int = setting(20, lo=0)  # only where the frame revisits ground painted this many frames before (0: always)
    keyframe_min_coverage: float = setting(0.5, gt=0.0, hi=1.0)  # fraction of the frame's view the mosaic must cover
    # smaller corner corrections are not applied: within the noise of a registration to the mosaic
    keyframe_min_correction_px: float = setting(2.0, lo=0.0, hi=1000.0)
    keyframe_max_correction_px: float = setting(40.0, gt=0.0)  # larger corner corrections are refused (prediction kept)
    # a georeferenced segment's first frames are painted once this span of them is placed (0: at once)
    settle_s: float = setting(3.0, lo=0.0, hi=600.0)
    settle_max_frames: int = setting(30, lo=1, hi=1000)  # ... or once this many are held, whichever comes first
    # frames painted this many frames late, so a revisit correction reaches back over them (revisit.py; 0: at once)
    revisit_spread_frames: int = setting(30, lo=0, hi=1000)
    # a frame within paint_shift_px of the last painted one is painted only every paint_stride-th (thinning.py; 1: every frame)
    paint_stride: int = setting(3, lo=1, hi=100)
    paint_shift_px: float = setting(16.0, lo=0.0, hi=1e6)  # ... a frame whose footprint corners moved this far (mosaic px) is always painted
    # frames wider are painted at the coarser ground sampling that brings them to this width (0: their own)
    max_width: int = setting(1280, lo=64, hi=100000, zero=True)

    def __post_init__(self) -> None:
        check_settings(self, 'mosaic')
        if not self.keyframe_min_correction_px < self.keyframe_max_correction_px:
            msg = (f'invalid mosaic settings: mosaic.keyframe_min_correction_px={self.keyframe_min_correction_px!r} must '
                   f'be below mosaic.keyframe_max_correction_px={self.keyframe_max_correction_px!r}.')
            raise ValueError(msg)
        if not isinstance(self.spill_dir, str):
            msg = f"mosaic.spill_dir must be a directory path or '' (a temporary directory), got {self.spill_dir!r}."
            raise ValueError(msg)
