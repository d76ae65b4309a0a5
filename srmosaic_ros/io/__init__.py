"""Input and output at the edges: bags (rosbags), video, stills, the metadata real footage carries
(exif.py, klv.py, dji_srt.py, gpmf.py, turned into core types by metadata.py), GeoTIFF, KML, PNG.

Only the bag layer is imported here; the others are imported where used (they pull PyAV, Pillow).
"""
from __future__ import annotations

from .bags import (
    BagInfo,
    BagSummary,
    BagWriter,
    FlightReader,
    TopicConfig,
    TopicSummary,
    bag_summary,
    inspect_bag,
    read_flight,
)

__all__ = [
    'BagInfo',
    'BagSummary',
    'BagWriter',
    'FlightReader',
    'TopicConfig',
    'TopicSummary',
    'bag_summary',
    'inspect_bag',
    'read_flight',
]
