"""What the pipeline decides and returns: one FrameRecord per input frame, the PipelineResult of a
run, and Held, a frame kept between the collaborators (registration, settling, painting)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.georef.georeferencer import FramePose, Georeferencer
from ..core.georef.pose_check import PoseCheck
from ..core.mosaic.keyframe import KeyframeResult
from ..core.mosaic.segments import Segment
from ..core.registration import Features, Registration
from ..core.types import CameraAttitude, CameraIntrinsics, GeoFix, ImuSample

__all__ = ['FrameRecord', 'Held', 'PipelineResult']


@dataclass
class FrameRecord:
    """What happened to one input frame.

    segment: index of the segment the frame was painted into, or -1 (not painted).
    seg_H_frame: (3, 3) frame pixels -> segment plane pixels, or None.
    registration: the registration that placed it (None for the first frame of a segment).
    camera: the intrinsics the frame was taken with (a zoom changes them frame to frame), or None.
    """

    index: int
    stamp_ns: int
    size: tuple[int, int]
    segment: int = -1
    seg_H_frame: np.ndarray | None = None
    registration: Registration | None = None
    reason: str = ''
    time_s: float = 0.0
    pose: FramePose | None = None
    keyframe: KeyframeResult | None = None
    camera: CameraIntrinsics | None = None
    corrected_px: float = 0.0  # largest corner move (px) of this frame by a later keyframe's correction spread back

    @property
    def painted(self) -> bool:
        return self.segment >= 0


@dataclass
class PipelineResult:
    records: list[FrameRecord]
    segments: list[Segment]
    fixes: list[GeoFix] = field(default_factory=list)
    imus: list[ImuSample] = field(default_factory=list)
    georef: Georeferencer | None = None
    attitudes: list[CameraAttitude] = field(default_factory=list)
    georef_note: str = ''  # why the offline fallback (the fit to geotags) did not place the mosaic
    pose_check: PoseCheck | None = None  # whether the poses of an unmeasured attitude placed the mosaic
    attitude_check: dict[str, Any] | None = None  # the measured attitude against the frames' (pose_check.py)
    frames_thinned: int = 0  # placed frames whose pixels were left to their neighbours' (mosaic.paint_stride)
    frames_painted_in_part: int = 0  # ... but for the tiles where they reach beyond them

    @property
    def main_segment(self) -> Segment | None:
        """The segment with the most frames (ties: the earliest)."""
        if not self.segments:
            return None
        return max(self.segments, key=lambda s: (len(s.frames), -s.index))


@dataclass
class Held:
    """A frame kept for registration and painting: its features, record, camera and ``raw``, the
    input image (H, W) or (H, W, C) as it came, or reduced to the mosaic's sampling while it waits
    for revisit spreading (converted for the canvas when it is painted: PaintInput)."""

    features: Features
    record: FrameRecord
    camera: CameraIntrinsics | None
    raw: np.ndarray
