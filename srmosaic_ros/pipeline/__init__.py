"""The pipeline: a conductor (conductor.Pipeline) of named collaborators (conductor.py's docstring).

Everything importable from ``srmosaic_ros.pipeline`` before the split still is; ``_Held`` stays
for the checkpoints written then, which pickle frames held by that name.
"""
from __future__ import annotations

from ..core.time_sync import SYNC_HOLD_FRAMES
from .conductor import _STATE, _STATE_NEWER, STATE_VERSION, Pipeline
from .painter import THIN_MAX_DEPTH_RATIO
from .records import FrameRecord, Held, PipelineResult
from .revisits import PASS_TURN_DEG
from .telemetry_sync import FIRST_FIX_HOLD_FRAMES

_Held = Held  # the name checkpoints written before the split pickle held frames by

__all__ = ['FIRST_FIX_HOLD_FRAMES', 'PASS_TURN_DEG', 'STATE_VERSION', 'SYNC_HOLD_FRAMES', 'THIN_MAX_DEPTH_RATIO',
           'FrameRecord', 'Pipeline', 'PipelineResult', '_STATE', '_STATE_NEWER', '_Held']
