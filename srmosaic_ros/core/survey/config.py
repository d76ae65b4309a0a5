"""Survey settings; the field names are the keys under `survey.` in params/*.yaml."""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..mosaic.exposure import EXPOSURE_MODES
from ..settings import check_settings, setting

__all__ = ['SURVEY_MODES', 'SurveyConfig']

SURVEY_MODES = ('auto', 'global', 'chain')


@dataclass(frozen=True)
class SurveyConfig:
    """How a folder of stills is mosaicked (see srmosaic_ros/survey.py).

    mode: 'global' aligns every frame at once (pairs by predicted footprint, one robust solve);
        'chain' runs the stills through the video pipeline (consecutive pairs, segments);
        'auto': global when at least three stills carry a GPS position or ground control points are
        given (a gcp_list.txt in or beside the folder, or process --gcp), else chain.
    working_megapixels: stills are decoded reduced (JPEG DCT scaling by 2, 4 or 8) to at most
        this size for registration.
    min_overlap: smallest predicted footprint overlap (0..1) of a candidate pair;
        max_pairs_per_frame: a pair is kept when it is among the largest predicted overlaps of
        one of its frames (0: all).
    mosaic_gsd_m: the mosaic's ground sampling distance (NaN: the stills' median at full size);
        max_mosaic_megapixels caps the mosaic's area (the GSD grows to fit).
    blend: 'multiband' (each ground point from the frame that sees it closest to its centre,
        eq. 4.7, blended across seams, Table 2) or 'feather'.
    feature_cache_frames: described frames kept for the pairs to come (the others are described
        again when a pair needs them): bounds memory whatever the number of stills.
    model_px: sd (working-resolution pixels) of what the planar model leaves out (lens
        distortion, relief), added to each registered point's own.
    tilt_allowance_deg: without a camera attitude, the optical axis is taken as vertical within
        this; its offset on the ground (height x tan) widens each GPS position's sd.
    exposure: stills' exposures matched before painting (core/mosaic/exposure.py): 'channels' (a
        gain per colour channel: exposure and white balance), 'gain' (one per still) or 'none'.
    paint_rank: with blend multiband, a still is painted only on the tiles where its weight ranks
        among the first paint_rank at some sample of the tile or its neighbours, and where it alone
        covers ground (core/survey/paint_plan.py); 0: every still wherever it falls.
    """

    mode: str = setting('auto', choices=SURVEY_MODES)
    working_megapixels: float = setting(1.0, lo=0.05, hi=100.0, unit='Mpx')
    min_overlap: float = setting(0.2, lo=0.0, lt=1.0)
    max_pairs_per_frame: int = setting(10, lo=0)
    mosaic_gsd_m: float = setting(math.nan, gt=0.0, nan=True, unit='m/px')
    max_mosaic_megapixels: float = setting(150.0, lo=1.0, unit='Mpx')
    blend: str = setting('multiband', choices=('feather', 'multiband'))
    feature_cache_frames: int = setting(48, lo=2)
    model_px: float = setting(1.0, gt=0.0, unit='px')
    tilt_allowance_deg: float = setting(5.0, lo=0.0, lt=45.0, unit='deg')
    exposure: str = setting('channels', choices=EXPOSURE_MODES)
    paint_rank: int = setting(2, lo=0)

    def __post_init__(self) -> None:
        check_settings(self, 'survey')
