"""Which consecutive video frames are registered by photometric tracking alone (TorchRegistrar.track).

At video rates the motion between two frames is close to that of the pair before, well inside the
photometric refinement's basin: started from that prediction, the refinement reaches the estimate
that describing, matching and RANSAC would have led it to, at a third of their cost. A false
minimum shows as a residual above the video's own (scenes differ in noise and texture, so the
reference is the refinement's RMS on the last pair registered by features, times TRACK_RMS_FACTOR)
or as a move outside the basin (TorchRegistrarOptions.track_radius_px); the pair is then
registered by features. Every ``frames``-th pair is registered by features anyway, so that a
slowly growing error cannot go on unseen and the reference follows the scene.

A prediction is made only for the frame right after the last one placed, when the pair before was
also consecutive and the two frame intervals differ by at most TRACK_MAX_DT_RATIO: the pair before's
motion continued over the new interval (prev_H_cur ** (dt / dt_before): a dropped frame doubles the
motion). A live node that drops frames from its queue sees irregular intervals; without the scaling
nearly every pair would go to features, which is slower, which drops more frames.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..homography import homography_power
from .registrar import Registration

__all__ = ['TRACK_MAX_DT_RATIO', 'TRACK_RMS_FACTOR', 'TRACK_SAME_DT', 'MotionTracker']

#: a tracked pair may leave this many times the residual RMS of the last pair registered by features
TRACK_RMS_FACTOR = 1.5
#: frame intervals of the predicting pair and the tracked one may differ by this factor at most
TRACK_MAX_DT_RATIO = 4.0
#: intervals within this fraction of each other are the same (stamps rounded to ns or to the
#: stream's time base: 33333333 and 33333334 ns at 30 fps); the motion is then taken as it is
TRACK_SAME_DT = 0.01


@dataclass
class MotionTracker:
    """State of the tracking policy over one stream of frames (frame indices and stamps in ns).

    frames: registration.track_frames (0 or 1: never track); reference_rms: the photometric RMS of
    the last pair registered by features whose refinement was applied (None: no tracking until one
    is); run: pairs tracked since it; motion: (index of the frame, its stamp, the stamp of the frame
    before it, prev_H_cur (3, 3)) of the last placed pair of consecutive frames."""

    frames: int
    reference_rms: float | None = None
    run: int = 0
    motion: tuple[int, int, int, np.ndarray] | None = None

    def prediction(self, prev_index: int, prev_stamp_ns: int, index: int, stamp_ns: int) -> np.ndarray | None:
        """prev_H_cur (3, 3) predicted for frame ``index`` against frame ``prev_index``, or None when
        the pair is to be registered by features (module docstring)."""
        if self.frames <= 1 or self.reference_rms is None or self.run >= self.frames - 1 or self.motion is None:
            return None
        m_index, m_stamp, m_prev_stamp, prev_H_cur = self.motion
        if m_index != prev_index or index != prev_index + 1:
            return None
        dt_before, dt = m_stamp - m_prev_stamp, stamp_ns - prev_stamp_ns
        if dt_before <= 0 or dt <= 0 or not 1.0 / TRACK_MAX_DT_RATIO <= dt / dt_before <= TRACK_MAX_DT_RATIO:
            return None
        ratio = dt / dt_before
        return prev_H_cur if abs(ratio - 1.0) <= TRACK_SAME_DT else homography_power(prev_H_cur, ratio)

    def max_rms(self) -> float:
        """The largest photometric RMS a tracked pair may leave."""
        return TRACK_RMS_FACTOR * (self.reference_rms if self.reference_rms is not None else 0.0)

    def placed(self, reg: Registration, prev_index: int, prev_stamp_ns: int, index: int, stamp_ns: int) -> None:
        """Frame ``index`` was placed by ``reg`` (prev_H_cur against frame ``prev_index``)."""
        if reg.extras.get('tracked'):
            self.run += 1
        else:
            self.run = 0
            refined = reg.extras.get('refined') == 1.0 and np.isfinite(reg.extras.get('photometric_rms', np.nan))
            self.reference_rms = float(reg.extras['photometric_rms']) if refined else None
        consecutive = index == prev_index + 1 and reg.prev_H_cur is not None
        self.motion = (index, stamp_ns, prev_stamp_ns, np.asarray(reg.prev_H_cur, dtype=np.float64)) if consecutive else None

    def lost(self) -> None:
        """A frame was not placed: the next one is registered by features."""
        self.motion = None
        self.run = 0
