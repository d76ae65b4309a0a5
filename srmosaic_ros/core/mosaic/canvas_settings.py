"""``TiledCanvas``'s settings, grouped by the part of the canvas that uses them, and their checks.

Each group is a small frozen dataclass whose fields declare the canvas's defaults once
(:func:`..settings.setting`; ``TiledCanvas``'s keyword defaults are read from them):
:class:`PlacementSettings` (which frames the canvas accepts, :mod:`.placement`),
:class:`FeatherSettings` (every blend's feather weight), :class:`MultibandSettings` and
:class:`BestViewSettings` (:mod:`.multiband_compositor`, :mod:`.best_view_compositor`) and :class:`RenderSettings`
(:mod:`.canvas_reader`).

The canvas is also built without a :class:`.config.MosaicConfig` (tests, tools), so it checks its
own arguments, over wider ranges than the config's (e.g. tile sizes from 16). ``settings_problem``
returns the first problem's message; the canvas raises it as a ``CanvasError``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from srmosaic_ros.errors import SrMosaicError

from .blend import FEATHER_PROFILES
from .config import BLEND_MODES, SEAM_MODES
from ..settings import setting
from .resample import INTERPOLATIONS


class CanvasError(SrMosaicError, ValueError):
    """A frame cannot be painted or a region rendered (absurd homography, bad image or mask)."""

__all__ = ['BestViewSettings', 'CanvasError', 'FeatherSettings', 'MultibandSettings', 'PlacementSettings', 'RenderSettings',
           'settings_problem']


@dataclass(frozen=True)
class PlacementSettings:
    """Which frames the canvas accepts, and how much of an oblique one it paints."""

    max_canvas_side_px: int = setting(100000, unit='px', doc='a frame making the painted area wider or taller than this is refused')
    max_area_ratio: float = setting(50.0, doc="a frame whose footprint's bounding box exceeds this many frame areas is refused")
    max_stretch: float = setting(0.0, doc='frame pixels this many times (linearly) coarser than its finest are not painted (0: all)')


@dataclass(frozen=True)
class FeatherSettings:
    """The feather weight every blend accumulates (:func:`.blend.feather_weight`)."""

    profile: str = setting('separable', doc="'separable' (w(x) w(y), section 4.2.5) or 'distance' (to the frame border)")
    power: float = setting(1.0, doc='exponent of the normalised weight; larger values narrow the transitions')


@dataclass(frozen=True)
class MultibandSettings:
    """The max-weight composite of eq. 4.7 (:class:`.multiband_compositor.MultibandCompositor`)."""

    seams: str = setting('score', doc="'score' (where the weights cross) or 'cut' (a graph cut, :mod:`.seam_cut`)")


@dataclass(frozen=True)
class BestViewSettings:
    """The best-view composite (:mod:`.best_view`, :class:`.best_view_compositor.BestViewCompositor`)."""

    recency_frames: int = setting(90, doc='a frame this many frames newer wins over an e-fold better view (0: no preference)')
    agree: float = setting(0.0, doc="frames within this of the winner (intensity, every channel) are averaged into it (0: none)")
    moving: float = setting(0.0, doc="a frame's pixels this far from the pixel's background are kept out (intensity; 0: off)")
    moving_history: int = setting(5, doc='colour samples kept per pixel with moving > 0 (odd); their median is the background')
    seams: str = setting('score', doc="'score' (where the scores cross) or 'cut' (a graph cut, :mod:`.seam_cut`)")


@dataclass(frozen=True)
class RenderSettings:
    """How the tiles render (:mod:`.canvas_reader`)."""

    bands: int = setting(0, doc='pyramid levels of multiband and best-view rendering (0: from the region size, blend.auto_bands)')
    background: float = setting(0.0, doc='value of uncovered pixels')


def settings_problem(
    channels: int,
    tile_size: int,
    *,
    blend: str,
    feather_profile: str,
    feather_power: float,
    max_canvas_side_px: int,
    max_area_ratio: float,
    bands: int,
    max_tiles_in_memory: int,
    max_stretch: float,
    recency_frames: int,
    agree: float,
    moving: float,
    moving_history: int,
    seams: str,
    interpolation: str,
) -> str | None:
    """The message of the first invalid ``TiledCanvas`` argument, None when all are valid."""
    if int(channels) != channels or channels < 1:
        return f'channels must be a positive integer, got {channels!r}.'
    if int(tile_size) != tile_size or not 16 <= tile_size <= 4096:
        return f'tile_size must be an integer in 16..4096, got {tile_size!r}.'
    if blend not in BLEND_MODES:
        return f"blend must be one of {', '.join(BLEND_MODES)}, got {blend!r}."
    if seams not in SEAM_MODES:
        return f"seams must be one of {', '.join(SEAM_MODES)}, got {seams!r}."
    if feather_profile not in FEATHER_PROFILES:
        return f"feather_profile must be one of {', '.join(FEATHER_PROFILES)}, got {feather_profile!r}."
    if not (math.isfinite(feather_power) and feather_power > 0):
        return f'feather_power must be a positive number, got {feather_power!r}.'
    if max_canvas_side_px < 16:
        return f'max_canvas_side_px must be >= 16, got {max_canvas_side_px!r}.'
    if not max_area_ratio > 1.0:
        return f'max_area_ratio must be > 1, got {max_area_ratio!r}.'
    if int(bands) != bands or not 0 <= bands <= 12:
        return f'bands must be an integer in 0..12 (0: automatic), got {bands!r}.'
    if int(max_tiles_in_memory) != max_tiles_in_memory or max_tiles_in_memory < 0:
        return f'max_tiles_in_memory must be an integer >= 0 (0: no bound), got {max_tiles_in_memory!r}.'
    if not (math.isfinite(max_stretch) and max_stretch >= 0) or 0 < max_stretch <= 1:
        return f'max_stretch must be 0 (no cut) or a number > 1, got {max_stretch!r}.'
    if isinstance(recency_frames, bool) or int(recency_frames) != recency_frames or recency_frames < 0:
        return f'recency_frames must be an integer >= 0 (0: no preference for newer frames), got {recency_frames!r}.'
    if not (math.isfinite(agree) and 0.0 <= agree < 1.0):
        return f'agree must be in [0, 1) (intensity; 0: no consensus), got {agree!r}.'
    if not (math.isfinite(moving) and 0.0 <= moving < 1.0):
        return f'moving must be in [0, 1) (intensity; 0: no vote), got {moving!r}.'
    if isinstance(moving_history, bool) or int(moving_history) != moving_history or not 3 <= moving_history <= 31 \
            or moving_history % 2 == 0:
        return f'moving_history must be an odd integer in 3..31, got {moving_history!r}.'
    if interpolation not in INTERPOLATIONS:
        return f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {interpolation!r}."
    return None
