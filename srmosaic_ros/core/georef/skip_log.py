"""What the Georeferencer left out and why: a count per kind (``skipped``), one logged warning per
kind, and the per-sensor stamp order (an input out of order is skipped, never raised)."""
from __future__ import annotations

import logging
from collections import Counter

__all__ = ['SkipLog']

_LOG = logging.getLogger('srmosaic_ros.core.georef.georeferencer')  # the Georeferencer's log


class SkipLog:
    """``skipped``: kind -> inputs left out; each kind is logged once, the rest only counted."""

    def __init__(self) -> None:
        self.skipped: Counter[str] = Counter()
        self._warned: set[str] = set()
        self._last_stamp: dict[str, int] = {}

    def skip(self, kind: str, message: str) -> None:
        """Count one input of ``kind`` left out; log ``message`` the first time."""
        self.skipped[kind] += 1
        if kind not in self._warned:
            self._warned.add(kind)
            _LOG.warning('%s (further ones are counted in skipped[%r], not logged).', message, kind)

    def warned(self, kind: str) -> bool:
        return kind in self._warned

    def count_once(self, kind: str) -> None:
        """Count a condition the caller logs itself, and mark it warned (it is said once)."""
        self.skipped[kind] += 1
        self._warned.add(kind)

    def in_order(self, sensor: str, stamp_ns: int) -> bool:
        """Whether ``stamp_ns`` is after the sensor's previous stamp (else skipped as out of order)."""
        last = self._last_stamp.get(sensor)
        if last is not None and int(stamp_ns) <= last:
            self.skip(f'{sensor}_out_of_order', f'{sensor} message at {stamp_ns} ns not after the previous one '
                      f'({last} ns) ignored')
            return False
        self._last_stamp[sensor] = int(stamp_ns)
        return True
