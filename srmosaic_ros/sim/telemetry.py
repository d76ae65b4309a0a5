"""Simulated GNSS fixes and IMU samples from a trajectory's true state.

- GeoFix: the body origin's true position plus Gaussian noise (east, north: ``sigma_h_m``; up:
  ``sigma_v_m``), converted to WGS84 around the world origin; covariance diag(sh^2, sh^2, sv^2),
  covariance_type 2 (diagonal known), status 0 (fix).
- ImuSample: orientation of the body in ENU (REP 145) perturbed by a random rotation with
  ``orientation_sigma_deg`` per axis (covariance diag(sigma^2) rad^2); angular velocity (body,
  rad/s) and specific force (body, m/s^2; +9.81 on z when level and unaccelerated) with white
  Gaussian noise.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.georef.frames import matrix_from_rotvec, quat_xyzw_from_matrix
from ..core.georef.geodetic import LocalTangentPlane
from ..core.types import GeoFix, ImuSample
from .trajectory import Trajectory

__all__ = ['sample_stamps', 'simulate_fixes', 'simulate_imu']


def sample_stamps(start_ns: int, end_ns: int, rate_hz: float) -> list[int]:
    """Stamps start_ns + round(j * 1e9 / rate_hz) up to and including end_ns."""
    period_ns = 1e9 / rate_hz
    n = int(math.floor((end_ns - start_ns) / period_ns + 1e-9)) + 1
    return [start_ns + int(round(j * period_ns)) for j in range(n)]


def simulate_fixes(traj: Trajectory, stamps_ns: list[int], t0_ns: int, ltp: LocalTangentPlane, *,
                   sigma_h_m: float, sigma_v_m: float, rng: np.random.Generator,
                   frame_id: str = 'gps') -> list[GeoFix]:
    """One noisy fix per stamp; t0_ns is the trajectory's time origin."""
    cov = np.diag([sigma_h_m**2, sigma_h_m**2, sigma_v_m**2])
    fixes = []
    for stamp in stamps_ns:
        true = traj.state((stamp - t0_ns) * 1e-9).position_enu_m
        noisy = true + rng.normal(0.0, 1.0, 3) * np.array([sigma_h_m, sigma_h_m, sigma_v_m])
        lat, lon, alt = ltp.geodetic_from_enu(noisy)
        fixes.append(GeoFix(stamp_ns=int(stamp), latitude_deg=float(lat), longitude_deg=float(lon),
                            altitude_m=float(alt), status=0, position_covariance_m2=cov.copy(),
                            covariance_type=2, frame_id=frame_id))
    return fixes


def simulate_imu(traj: Trajectory, stamps_ns: list[int], t0_ns: int, *, orientation_sigma_deg: float,
                 gyro_sigma_rad_s: float, accel_sigma_m_s2: float, rng: np.random.Generator,
                 frame_id: str = 'base_link') -> list[ImuSample]:
    """One noisy IMU sample per stamp."""
    sigma = math.radians(orientation_sigma_deg)
    cov = np.eye(3) * sigma**2
    samples = []
    for stamp in stamps_ns:
        t = (stamp - t0_ns) * 1e-9
        r_true = traj.state(t).R_enu_from_body
        r_noisy = r_true @ matrix_from_rotvec(rng.normal(0.0, sigma, 3))
        gyro = traj.angular_velocity_body(t) + rng.normal(0.0, gyro_sigma_rad_s, 3)
        accel = traj.specific_force_body(t) + rng.normal(0.0, accel_sigma_m_s2, 3)
        samples.append(ImuSample(stamp_ns=int(stamp), orientation_xyzw=quat_xyzw_from_matrix(r_noisy),
                                 angular_velocity_rad_s=gyro, linear_acceleration_m_s2=accel,
                                 orientation_covariance=cov.copy(), frame_id=frame_id))
    return samples
