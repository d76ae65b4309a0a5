"""GeorefConfig: the georeferencing settings (the ``georef.`` parameters) and the filter settings
derived from them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

from .ukf import CameraMount, UkfParams

__all__ = ['GeorefConfig']


@dataclass(frozen=True)
class GeorefConfig:
    """Georeferencing settings; the field names are the keys under ``georef.`` in params/*.yaml.

    Angles in degrees, lengths in metres, NaN means "not set" (ROS parameters have no None).
    """

    ground_altitude_m: float = float('nan')  # ellipsoidal height of the ground plane; NaN: first fix - nominal_agl_m
    ground_altitude_sigma_m: float = 1.0     # prior uncertainty of ground_altitude_m when it is given
    nominal_agl_m: float = 100.0             # height of the first fix above the ground, when ground_altitude_m is NaN
    nominal_agl_sigma_m: float = 30.0        # prior uncertainty of nominal_agl_m
    ground_walk_m_per_sqrt_s: float = 0.05   # random walk of the ground plane height (terrain is not flat)
    gimbal_azimuth_deg: float = 0.0
    gimbal_elevation_deg: float = -90.0      # nadir
    mount_from_frames: bool = True           # offline: no attitude measured and the frames show another mount
    #                                          than the gimbal angles (pose_check.py): the run restarts with theirs
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # body frame, GNSS antenna -> optical centre
    gps_sigma_h_m: float = 2.5               # used when a fix's covariance is unknown
    gps_sigma_v_m: float = 5.0
    imu_sigma_deg: float = 0.5               # used when an Imu orientation covariance is unknown
    gyro_sigma_rad_s: float = 0.005          # white noise of one angular velocity sample
    gyro_bias_sigma_rad_s: float = 0.002     # allowance for an uncalibrated gyro bias
    gyro_max_gap_s: float = 0.1              # longer gaps between Imu samples: no gyro update for that frame
    accel_sigma_m_s2: float = 2.0            # motion model: horizontal acceleration noise
    vertical_accel_sigma_m_s2: float = 1.0
    angular_accel_sigma_deg_s2: float = 20.0
    initial_speed_sigma_m_s: float = 15.0    # velocity prior at the first frame
    initial_rate_sigma_deg_s: float = 30.0
    homography_sigma_gain: float = 1.0       # no covariance: corner sigma = gain * inlier rms (px)
    homography_min_sigma_px: float = 0.2     # model-error floor added to every homography measurement
    min_agl_m: float = 5.0                   # below this height the flat-ground model is not used
    gate_probability: float = 0.99999        # chi-square gate of every update
    max_gated_in_a_row: int = 5              # then the filter re-acquires (fixes, attitude)
    telemetry_buffer_s: float = 10.0         # telemetry kept while waiting for frames
    max_step_s: float = 10.0                 # longer gaps between frames are bridged by filter-only steps
    #                                          (their registration not fused)
    max_attitude_step_sigma_deg: float = 20.0  # bound of the motion model's attitude noise per step
    ut_alpha: float = 1.0                    # sigma points: Merwe scaled (alpha, beta, kappa); see ukf.py
    ut_beta: float = 2.0
    ut_kappa: float = 0.0
    ut_iterations: int = 5                   # passes of the homography and gyro updates (posterior
    #                                          linearisation, see ukf._batch_update); 1: plain UKF update
    gsd_m_per_px: float = float('nan')       # raster ground sampling; NaN: the first frame's GSD
    drift_chain_sigma_px: float = 0.3        # drift control: random walk of chained corners per frame
    drift_pose_time_constant_s: float = float('nan')  # drift control: pose-error correlation time (s, >= 0; 0:
    #                                                  independent poses); NaN: from the filter, see drift.py
    history_frames: int = 20000              # filter moments kept for smoothed_poses() (0: none)

    def __post_init__(self) -> None:
        object.__setattr__(self, 'lever_arm_m', tuple(float(v) for v in self.lever_arm_m))
        pos = ('nominal_agl_m', 'ground_altitude_sigma_m', 'nominal_agl_sigma_m', 'gps_sigma_h_m', 'gps_sigma_v_m',
               'imu_sigma_deg', 'accel_sigma_m_s2', 'vertical_accel_sigma_m_s2', 'angular_accel_sigma_deg_s2',
               'initial_speed_sigma_m_s', 'initial_rate_sigma_deg_s', 'homography_sigma_gain', 'telemetry_buffer_s',
               'ut_alpha')
        checks = {name: math.isfinite(getattr(self, name)) and getattr(self, name) > 0 for name in pos}
        checks.update({
            'homography_min_sigma_px': self.homography_min_sigma_px >= 0,
            'min_agl_m': self.min_agl_m >= 0,
            'drift_chain_sigma_px': self.drift_chain_sigma_px >= 0,
            'drift_pose_time_constant_s': math.isnan(self.drift_pose_time_constant_s)
            or 0.0 <= self.drift_pose_time_constant_s < math.inf,
            'ground_walk_m_per_sqrt_s': self.ground_walk_m_per_sqrt_s >= 0,
            'gyro_sigma_rad_s': self.gyro_sigma_rad_s > 0,
            'gyro_bias_sigma_rad_s': self.gyro_bias_sigma_rad_s >= 0,
            'gyro_max_gap_s': self.gyro_max_gap_s > 0,
            'gate_probability': 0.0 < self.gate_probability < 1.0,
            'max_gated_in_a_row': self.max_gated_in_a_row >= 1,
            'history_frames': self.history_frames >= 0,
            'gimbal_elevation_deg': -90.0 <= self.gimbal_elevation_deg < 0.0,
            'lever_arm_m': len(self.lever_arm_m) == 3 and all(map(math.isfinite, self.lever_arm_m)),
            'gsd_m_per_px': math.isnan(self.gsd_m_per_px) or self.gsd_m_per_px > 0,
            'ut_kappa': 13 + self.ut_kappa > 0,
            'max_step_s': 0.0 < self.max_step_s <= 10.0,
            'max_attitude_step_sigma_deg': 0.0 < self.max_attitude_step_sigma_deg <= 90.0,
            'ut_iterations': self.ut_iterations == int(self.ut_iterations) and 1 <= self.ut_iterations <= 50,
        })
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            values = ', '.join(f'{name}={getattr(self, name)!r}' for name in bad)
            msg = f'invalid georef settings: {values}; see params/default.yaml for the valid ranges.'
            raise ValueError(msg)

    @classmethod
    def keys(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    @property
    def mount(self) -> CameraMount:
        return CameraMount(math.radians(self.gimbal_azimuth_deg), math.radians(self.gimbal_elevation_deg),
                           self.lever_arm_m)

    @property
    def ukf_params(self) -> UkfParams:
        return UkfParams(
            accel_sigma_h_m_s2=self.accel_sigma_m_s2, accel_sigma_v_m_s2=self.vertical_accel_sigma_m_s2,
            angular_accel_sigma_rad_s2=math.radians(self.angular_accel_sigma_deg_s2),
            initial_speed_sigma_m_s=self.initial_speed_sigma_m_s,
            initial_rate_sigma_rad_s=math.radians(self.initial_rate_sigma_deg_s),
            ground_walk_m_per_sqrt_s=self.ground_walk_m_per_sqrt_s,
            max_attitude_step_sigma_rad=math.radians(self.max_attitude_step_sigma_deg),
            gate_probability=self.gate_probability, max_gated_in_a_row=self.max_gated_in_a_row,
            alpha=self.ut_alpha, beta=self.ut_beta, kappa=self.ut_kappa, iterations=int(self.ut_iterations))
