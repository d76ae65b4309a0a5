"""Orbit ("loiter") flights: the camera circles a point looking at it, obliquely, and comes back over
the ground it saw (issue 17's simulator conditions)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.errors import SimulationError
from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.app.process import process_input
from srmosaic_ros.sim import SimConfig, simulate, write_flight
from srmosaic_ros.sim.flight import gimbal_deg
from flights import simulated

ORBIT = {'trajectory': 'orbit', 'orbit_radius_m': 50.0, 'laps': 1.1, 'altitude_m': 80.0, 'hfov_deg': 40.0,
         'width': 160, 'height': 120, 'speed_m_s': 10.0, 'rate_hz': 1.5, 'seed': 4}


def test_orbit_circles_its_centre_looking_at_it() -> None:
    cfg = SimConfig(**ORBIT, start_east_m=20.0, start_north_m=-10.0)
    flight = simulate(cfg)
    # 1.1 laps of 2 pi 50 m at 10 m/s, 1.5 frames/s
    assert len(flight.frames) == int(2 * math.pi * 50.0 * 1.1 / 10.0 * 1.5) + 1
    centre = np.array([20.0, -10.0])
    cams = np.array([f.camera_enu_m for f in flight.truth.frames])
    radii = np.hypot(*(cams[:, :2] - centre).T)
    assert np.all(np.abs(radii - 50.0) < 4.0)        # gusts move the aircraft by ~1 m RMS
    bearing = np.unwrap(np.arctan2(*(cams[:, :2] - centre).T[::-1]))
    assert bearing[-1] - bearing[0] == pytest.approx(2 * math.pi * 1.1, abs=0.2)  # counter-clockwise, 1.1 laps
    # the optical axis meets the ground at the centre, up to the gusts' 2 deg of attitude (~3.3 m at 94 m)
    for f in flight.truth.frames:
        axis = f.R_enu_from_cam @ np.array([0.0, 0.0, 1.0])
        hit = f.camera_enu_m + axis * (-f.camera_enu_m[2] / axis[2])
        assert np.hypot(*(hit[:2] - centre)) < 12.0
    assert gimbal_deg(cfg) == pytest.approx((90.0, -math.degrees(math.atan2(80.0, 50.0))))


def test_orbit_longer_than_its_laps_is_refused() -> None:
    with pytest.raises(SimulationError, match='raise --laps'):
        simulate(SimConfig(**{**ORBIT, 'frames': 200}))


def test_orbit_is_mosaicked_and_georeferenced_with_its_mount(tmp_path, tmp_path_factory) -> None:
    """Every frame of an oblique orbit in one mosaic, the revisited quarter lap included, registered
    to a fraction of a pixel; with the camera mount given, on the map within a metre. The orbit is
    simulated once for the session (test/flights.py): test_sim_unmeasured_attitude.py takes it too."""
    cfg = SimConfig(**ORBIT)
    bag = write_flight(simulated(tmp_path_factory, cfg), tmp_path / 'bag')
    azimuth, elevation = gimbal_deg(cfg)
    out = tmp_path / 'out'
    process_input(bag, out, pipeline_config({'georef.gimbal_azimuth_deg': azimuth,
                                             'georef.gimbal_elevation_deg': elevation,
                                             'georef.nominal_agl_m': 80.0}), progress=False)
    fig = evaluate_dir(out, bag / 'ground_truth.json')
    assert fig['frames_registered'] == fig['frames_in'] == 52
    assert fig['corner_error_mean_px'] < 0.3, fig  # measured 0.077 px (max 0.20), georef 0.26 m RMS
    assert fig['georef_error_rms_m'] < 1.0, fig
