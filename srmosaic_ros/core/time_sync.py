"""Approximate-time association of frames (or their registrations) with telemetry.

A frame stamped t is fused once telemetry stamped after t has arrived (the fixes and attitudes
around it are known), or once more than SYNC_HOLD_FRAMES frames wait behind it (telemetry stopped or
never comes), or, live, once it waited longer than a timeout. The offline pipeline and the
standalone georef node apply the same rule to their queues.
"""
from __future__ import annotations

__all__ = ['SYNC_HOLD_FRAMES', 'telemetry_ready']

#: Frames that may wait for their telemetry; one more and the oldest goes without it.
SYNC_HOLD_FRAMES = 3


def telemetry_ready(stamp_ns: int, latest_telemetry_ns: int | None, waiting: int, *, late: bool = False) -> bool:
    """Whether the oldest of ``waiting`` queued items, stamped ``stamp_ns``, is to be processed now:
    telemetry newer than it has been seen (``latest_telemetry_ns``, None: none yet), more than
    SYNC_HOLD_FRAMES wait, or it is ``late`` (the caller's timeout)."""
    seen = latest_telemetry_ns is not None and latest_telemetry_ns > stamp_ns
    return seen or late or waiting > SYNC_HOLD_FRAMES
