"""Simulated flights with geometry and telemetry only (blank images): fast fixtures for georef tests."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim import flight as sim_flight


def _geometry_only(world, H, size, **kw):
    d = kw.get('decimate', 1)
    return np.zeros((size[1] // d, size[0] // d, 3), np.float32)


def simulate_geometry(config: SimConfig):
    """simulate(config) without rendering: true poses, homographies and telemetry; blank frames."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sim_flight, 'render_frame', _geometry_only)
        return simulate(config)
