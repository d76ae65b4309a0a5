"""One still of a survey as the global solve sees it (app/survey.py builds them; app/ground_control.py
places the ground control points on them)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np

__all__ = ['SurveyStill']


@dataclass
class SurveyStill:
    """One still: file, size (w, h) as decoded at full size, stamp_ns, K (3, 3) full-size intrinsics,
    position_m (east, north on the survey plane, NaN), latlon (the GPS fix at capture, NaN)."""

    file: Path
    size: tuple[int, int]
    stamp_ns: int
    K: np.ndarray
    focal_known: bool
    position_m: np.ndarray
    latlon: tuple[float, float]
    nadir_view: bool
    R_enu_from_cam: np.ndarray | None = None  # from the gimbal angles (None: unknown)
    height_m: float = math.nan  # above the ground: the XMP's height above take-off (NaN: unknown)
    altitude_m: float = math.nan  # the GPS altitude (EXIF, or the telemetry CSV's alt_msl; NaN: unknown)
