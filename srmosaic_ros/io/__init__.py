"""Input and output at the edges: bags (rosbags), and in time video, GeoTIFF, KML, PNG."""
from __future__ import annotations

from .bags import (
    BagInfo,
    BagWriter,
    FlightReader,
    TopicConfig,
    TopicSummary,
    inspect_bag,
    read_flight,
)

__all__ = [
    'BagInfo',
    'BagWriter',
    'FlightReader',
    'TopicConfig',
    'TopicSummary',
    'inspect_bag',
    'read_flight',
]
