"""Heap trimming (malloc_tuning.py): runs on glibc, every n-th frame of the pipeline. Its effect
on resident memory is measured by bench/memory.py (2000 frames), not here."""
from __future__ import annotations

import sys

import pytest

from srmosaic_ros.malloc_tuning import HEAP_TRIM_EVERY, HeapTrimmer, trim_heap


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='glibc only')
def test_trims_every_nth_tick():
    assert trim_heap() is True
    t = HeapTrimmer(3)
    for _ in range(7):
        t.tick()
    assert (t.ticks, t.trims) == (7, 2)


def test_refuses_bad_period():
    assert HEAP_TRIM_EVERY >= 1
    with pytest.raises(ValueError, match='every >= 1'):
        HeapTrimmer(0)
