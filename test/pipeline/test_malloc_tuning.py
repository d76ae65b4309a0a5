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


_QUEUE_OF_FRAMES = '''
import resource, sys
import numpy as np
if sys.argv[1] == 'settle':
    from srmosaic_ros.malloc_tuning import settle_allocator
    assert settle_allocator()
def rounds(n):
    for _ in range(n):
        held = [np.ones((720, 1280, 3), np.uint8) for _ in range(16)]  # a node's queue of 720p frames
        del held
rounds(1)
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
rounds(4)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
'''


@pytest.mark.skipif(not sys.platform.startswith('linux'),
                    reason="glibc's mallopt thresholds: elsewhere settle_allocator is a no-op and there is nothing to measure")
def test_a_settled_allocator_reuses_a_queue_of_frames_without_page_faults():
    """A fresh process (glibc's thresholds as at start): 16 frames of 720p held and freed, four
    times over. Unsettled, each round is trimmed from the heap and faulted in again (measured 43092
    minor faults over four rounds); settled, none."""
    import subprocess

    def faults(mode: str) -> int:
        out = subprocess.run([sys.executable, '-c', _QUEUE_OF_FRAMES, mode], capture_output=True, text=True,
                             check=True, timeout=120)
        return int(out.stdout.strip())

    plain, settled = faults('plain'), faults('settle')
    assert plain > 20000, plain  # 16 x 2.76 MB x 4 rounds = 43 000 pages: the storm is real here
    assert settled < 2000, settled
