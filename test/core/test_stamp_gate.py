"""Header stamps against the arrival clock (srmosaic_ros/core/stamp_gate.py)."""
from __future__ import annotations

import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.stamp_gate import StampGate
from srmosaic_ros.errors import ConfigError

S = 10**9


def test_one_stamp_off_its_stream_is_refused_alone() -> None:
    gate = StampGate(10.0)
    clock = 1_000 * S
    # a stream whose stamps lag its log times by 0.3 s (plus jitter), and another 10^8 s behind
    for k in range(20):
        t = clock + k * S // 10
        assert gate.check('image', t - 3 * S // 10 + (k % 3) * S // 100, t) is None
        assert gate.check('fix', t - 10**8 * S, t) is None
    t = clock + 2 * S
    assert gate.check('image', t + 10**6 * S, t) == pytest.approx(10**6 + 0.3, rel=1e-6)
    assert gate.check('image', t - 40 * S, t) == pytest.approx(-39.7, rel=1e-3)
    assert gate.check('image', t, t + S // 10) is None  # the next good one, and the other stream, unharmed
    assert gate.check('fix', t - 10**8 * S, t) is None
    assert gate.rebased == {}


def test_a_clock_that_jumps_for_good_is_followed_after_three_messages() -> None:
    gate = StampGate(10.0)
    for k in range(5):
        assert gate.check('fix', k * S, k * S) is None
    refused = [gate.check('fix', (k + 18) * S, k * S) for k in range(5, 9)]  # GPS time: 18 s ahead from now on
    assert refused[:2] == [pytest.approx(18.0)] * 2 and refused[2:] == [None, None]
    assert gate.rebased == {'fix': 1}


def test_off_and_bad_tolerances() -> None:
    assert StampGate(0.0).check('image', 10**6 * S, 0) is None
    assert StampGate(float('inf')).check('image', 10**6 * S, 0) is None
    for bad in (-1.0, float('nan'), True):
        with pytest.raises(ValueError, match='stamp tolerance'):
            StampGate(bad)  # type: ignore[arg-type]
    assert pipeline_config({'stamp_tolerance_s': 2}).stamp_tolerance_s == 2.0
    with pytest.raises(ConfigError, match="'stamp_tolerance_s' must be a number"):
        pipeline_config({'stamp_tolerance_s': 'lots'})
    with pytest.raises(ConfigError, match=">= 0 seconds"):
        pipeline_config({'stamp_tolerance_s': -3.0})
