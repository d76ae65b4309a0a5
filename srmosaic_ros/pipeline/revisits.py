"""Keyframes registered to the mosaic on revisits, and their corrections spread back.

Every mosaic.keyframe_interval-th frame of a segment that flies over ground an earlier pass painted
(:meth:`RevisitCorrector.revisits`) is registered to the mosaic rendered where the chain puts it
(core/mosaic/keyframe.py). When that moves it, the frames placed since the last keyframe and not
painted yet (Painter.unpainted, mosaic.revisit_spread_frames) take their share of the correction
(core/mosaic/revisit.py: the mean of a random-walk drift pinned at both ends) before they are
painted; ``FrameRecord.corrected_px`` says how far each was moved.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..config import PipelineConfig
from ..core.mosaic.keyframe import KeyframeResult, corner_shift_px, render_view
from ..core.mosaic.revisit import footprint_pose, spread_correction
from ..core.mosaic.segments import Segment
from ..core.stage_clock import StageClock
from .checkpointed import Checkpointed
from .painter import Painter
from .records import Held

__all__ = ['PASS_TURN_DEG', 'RevisitCorrector']

#: A frame turned by more than this (degrees) from the frames centred near it views their ground
#: from another direction: a new pass over it (RevisitCorrector.revisits).
PASS_TURN_DEG = 45.0


class RevisitCorrector(Checkpointed):
    """anchor: record index of the last keyframe the mosaic placed (corrections spread back to it);
    footprints: segment -> (x, y, heading rad) of its painted frames' centres, a cache rebuilt from
    the segments on resume (not in the state)."""

    STATE = (('_anchor', 'anchor'),)

    def __init__(self, config: PipelineConfig, clock: StageClock, painter: Painter) -> None:
        self.config = config
        self.clock = clock
        self.painter = painter
        self.anchor = -1
        self.footprints: dict[int, list[np.ndarray]] = {}

    def keyframe(self, seg: Segment, held: Held, seg_H_frame: np.ndarray, registrar: Any) -> np.ndarray:
        """seg_H_frame (3, 3), corrected by registering the frame to the mosaic when it is a keyframe."""
        cfg = self.config.mosaic
        if cfg.keyframe_interval <= 0 or len(seg.frames) % cfg.keyframe_interval != 0:
            return seg_H_frame
        w, h = held.record.size
        if cfg.keyframe_revisit_frames > 0 and not self.revisits(seg, seg_H_frame, w, h):
            return seg_H_frame
        with self.clock.stage('register'):
            result = self._register_to_mosaic(seg, held, seg_H_frame, registrar)
        held.record.keyframe = result
        if result.seg_H_frame is None:
            return seg_H_frame
        self._spread_back(seg, held, seg_H_frame, result.seg_H_frame)
        return result.seg_H_frame

    def _spread_back(self, seg: Segment, held: Held, predicted: np.ndarray, corrected: np.ndarray) -> None:
        """The frames of ``seg`` placed after the last anchor and not painted yet take their share of
        the keyframe's correction (revisit.py); the keyframe becomes the anchor."""
        back = [h for s, h, _ in self.painter.unpainted if s is seg and h.record.index > self.anchor
                and h.record.seg_H_frame is not None]
        self.anchor = held.record.index
        if not back:
            return
        moved, shifts = spread_correction([h.record.seg_H_frame for h in back], [h.record.size for h in back],
                                          predicted, corrected)
        for h, m, shift in zip(back, moved, shifts, strict=True):
            h.record.seg_H_frame = m
            h.record.corrected_px = float(shift)
            seg.seg_H_frames[h.record.index] = m
        known = self.footprints.get(seg.index)
        if known:  # the moved frames' footprints: computed again
            del known[seg.frames.index(back[0].record.index):]

    def _register_to_mosaic(self, seg: Segment, held: Held, seg_H_frame: np.ndarray, registrar: Any) -> KeyframeResult:
        """The keyframe's registration to the mosaic rendered where the chain puts it."""
        cfg = self.config.mosaic
        w, h = held.record.size
        self.painter.sync()
        view, covered = render_view(seg.canvas, seg_H_frame, w, h, gray=True)
        coverage = float(covered.mean())
        if coverage < cfg.keyframe_min_coverage:
            return KeyframeResult(None, coverage, float('nan'), f'mosaic covers {coverage:.0%} of the view')
        # Optional refinement: no OpenCV second opinion (its SIFT on both images would cost a live
        # node several frame periods, and a failed keyframe changes nothing).
        extra = {'second_opinion': False} if getattr(registrar, 'has_second_opinion', False) else {}
        reg = registrar.register(registrar.describe(view), held.features, **extra)
        if not reg.ok:
            return KeyframeResult(None, coverage, float('nan'), f'registration to the mosaic failed: {reg.reason}')
        refined = seg_H_frame @ reg.prev_H_cur
        shift = corner_shift_px(seg_H_frame, refined, w, h)
        if shift > cfg.keyframe_max_correction_px:
            return KeyframeResult(None, coverage, shift, f'correction of {shift:.1f} px refused')
        if shift < cfg.keyframe_min_correction_px:  # within the noise of the rendered reference
            return KeyframeResult(None, coverage, shift, f'correction of {shift:.1f} px below the minimum')
        return KeyframeResult(refined / refined[2, 2], coverage, shift)

    def revisits(self, seg: Segment, seg_H_frame: np.ndarray, w: int, h: int) -> bool:
        """Whether the frame flies over ground an earlier pass painted: its predicted centre lies within
        half its smaller side of the centre of a frame painted at least mosaic.keyframe_revisit_frames
        frames earlier that is not part of the current pass (the unbroken run just before it of
        frames centred nearby and facing the same way, within PASS_TURN_DEG). Along a straight pass
        the frames overlap many frames back: those are not a revisit, and registering to the mosaic
        there would cost a live node a frame period for nothing the chain does not already have. An
        orbit looking at its centre keeps every footprint there and turns: once it has turned, the
        frames before the turn are an earlier pass over the same ground."""
        n = len(seg.frames)
        gap = self.config.mosaic.keyframe_revisit_frames
        if n <= gap:
            return False
        now = footprint_pose(seg_H_frame, w, h)
        # footprints of the segment's painted frames, computed once each (O(1) per frame on long flights)
        known = self.footprints.setdefault(seg.index, [])
        known.extend(footprint_pose(seg.seg_H_frames[i], w, h) for i in seg.frames[len(known):])
        done = np.asarray(known)
        near = np.linalg.norm(done[:, :2] - now[:2], axis=1) < 0.5 * min(w, h)
        turn = np.abs(np.angle(np.exp(1j * (done[:, 2] - now[2]))))
        same_pass = near & (turn < math.radians(PASS_TURN_DEG))
        run = n
        while run > 0 and same_pass[run - 1]:
            run -= 1
        return bool(near[:min(run, n - gap)].any())
