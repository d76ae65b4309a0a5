"""What one still's EXIF and XMP say (io/exif.py reads it; io/camera_db.py turns it into intrinsics)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ['StillMetadata']


@dataclass(frozen=True)
class StillMetadata:
    """What a still's EXIF and XMP say about its capture.

    Sizes are pixels of the image as decoded (as stored, before EXIF orientation is applied);
    ``exif_width_px`` is the width the EXIF describes (``PixelXDimension``), which the focal
    plane resolution and DJI's calibrated values refer to: a resized still keeps its original
    EXIF, so scale those by ``width_px / exif_width_px``. Positions are WGS84 degrees (S and W
    negative) and metres (``altitude_m`` as the EXIF states it: above sea level for ref 0/1);
    NaN when absent. ``stamp_ns`` is UTC nanoseconds since the Unix epoch (the capture);
    ``gps_stamp_ns`` when the GPS position was fixed, which a camera's GPS tags can trail by seconds
    (caliterra: 0 to 2 s; one still repeats its predecessor's fix). Angles are degrees:
    ``gimbal_ypr_deg`` = (yaw clockwise from north, pitch with -90 nadir and 0 horizon, roll) of
    the camera; ``flight_ypr_deg`` = (yaw clockwise from north, pitch nose up +, roll right wing
    down +) of the aircraft. ``calibrated_optical_center_px`` is (cx, cy) in this package's
    convention (pixel centres at integers) scaled to the decoded size. ``notes`` lists what was
    missing or assumed, one short phrase each.
    """

    path: Path
    width_px: int
    height_px: int
    exif_width_px: int | None
    stamp_ns: int | None
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    relative_altitude_m: float
    make: str
    model: str
    focal_length_mm: float | None
    focal_length_35mm_mm: float | None
    focal_plane_x_res_px_per_mm: float | None
    calibrated_focal_length_px: float | None
    calibrated_optical_center_px: tuple[float, float] | None
    gimbal_ypr_deg: tuple[float, float, float] | None
    flight_ypr_deg: tuple[float, float, float] | None
    exif_orientation: int
    notes: tuple[str, ...]
    gps_stamp_ns: int | None = None          # GPSDateStamp + GPSTimeStamp (UTC): when the position was fixed

    @property
    def has_position(self) -> bool:
        return math.isfinite(self.latitude_deg) and math.isfinite(self.longitude_deg)
