"""Header stamps checked against the clock the messages arrive on.

A message's header stamp says when its data was taken; the clock it arrives on (a bag's log time,
a node's receive time) says when it was recorded. Their difference, the stamp's offset, is nearly
constant along one stream (the latency, and any fixed offset between the sensor's clock and the
recorder's). One message stamped far from its stream's offset (a driver's glitch: a stamp 10^6 s
in the future) would move the filter's clock past every later message and cost the rest of the
flight; the gate refuses that message alone.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

__all__ = ['StampGate']


@dataclass
class _Stream:
    offsets: deque[int] = field(default_factory=lambda: deque(maxlen=StampGate.HISTORY))
    refused: list[int] = field(default_factory=list)  # offsets of the refusals since the last accepted


class StampGate:
    """Per-stream check of header stamps against the arrival clock.

    tolerance_s: a stamp whose offset (stamp - clock) differs from the median offset of its
        stream's last HISTORY accepted messages by more than this is refused (0 or inf: off).

    A stream's first message sets its offset. When REBASE consecutive refusals agree among
    themselves within the tolerance, the stream's clock has jumped for good (a GNSS receiver
    switching to GPS time, or a bad first stamp): the gate follows the new offset from then on and
    says so in :attr:`rebased`.
    """

    HISTORY = 9
    REBASE = 3

    def __init__(self, tolerance_s: float = 10.0) -> None:
        if not (isinstance(tolerance_s, (int, float)) and not isinstance(tolerance_s, bool)
                and tolerance_s >= 0 and not math.isnan(tolerance_s)):
            msg = f'the stamp tolerance must be a number of seconds >= 0 (0: off), got {tolerance_s!r}.'
            raise ValueError(msg)
        self.tolerance_ns = 0 if math.isinf(tolerance_s) else int(round(tolerance_s * 1e9))
        self._streams: dict[str, _Stream] = {}
        self.rebased: dict[str, int] = {}  # stream -> how many times it followed a clock jump

    REASON = "header stamp off its stream's clock by more than stamp_tolerance_s"

    def check(self, stream: str, stamp_ns: int, clock_ns: int) -> float | None:
        """None if ``stamp_ns`` (int ns) of a message of ``stream`` arriving at ``clock_ns`` (int
        ns) is accepted, else how far (s, signed) its offset is from the stream's."""
        if self.tolerance_ns <= 0:
            return None
        state = self._streams.setdefault(stream, _Stream())
        offset = int(stamp_ns) - int(clock_ns)
        if state.offsets:
            reference = sorted(state.offsets)[len(state.offsets) // 2]
            deviation = offset - reference
            if abs(deviation) > self.tolerance_ns:
                state.refused.append(offset)
                recent = state.refused[-self.REBASE:]
                if len(recent) == self.REBASE and max(recent) - min(recent) <= self.tolerance_ns:
                    state.offsets.clear()
                    state.offsets.extend(recent)
                    state.refused.clear()
                    self.rebased[stream] = self.rebased.get(stream, 0) + 1
                    return None
                return deviation / 1e9
        state.refused.clear()
        state.offsets.append(offset)
        return None
