"""GeorefConfig: the georeferencing settings (the ``georef.`` parameters) and the filter settings
derived from them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

from ..settings import Bounds, check_settings, setting
from .ukf_models import CameraMount, UkfParams

__all__ = ['GeorefConfig']


@dataclass(frozen=True)
class GeorefConfig:
    """Georeferencing settings; the field names are the keys under ``georef.`` in params/*.yaml.

    Angles in degrees, lengths in metres, NaN means "not set" (ROS parameters have no None).
    """

    ground_altitude_m: float = setting(float('nan'), nan=True)  # ellipsoidal height of the ground plane; NaN: first fix - nominal_agl_m
    ground_altitude_sigma_m: float = setting(1.0, gt=0.0)     # prior uncertainty of ground_altitude_m when it is given
    nominal_agl_m: float = setting(100.0, gt=0.0)             # height of the first fix above the ground, when ground_altitude_m is NaN
    nominal_agl_sigma_m: float = setting(30.0, gt=0.0)        # prior uncertainty of nominal_agl_m
    ground_walk_m_per_sqrt_s: float = setting(0.05, lo=0.0)   # random walk of the ground plane height (terrain is not flat)
    gimbal_azimuth_deg: float = setting(0.0)
    gimbal_elevation_deg: float = setting(-90.0, lo=-90.0, lt=0.0)      # nadir
    mount_from_frames: bool = True           # offline: no attitude measured and the frames show another mount
    #                                          than the gimbal angles (pose_check.py): the run restarts with theirs
    lever_arm_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), items=Bounds(), length=3)  # body frame, GNSS antenna -> optical centre
    gps_sigma_h_m: float = setting(2.5, gt=0.0)               # used when a fix's covariance is unknown
    gps_sigma_v_m: float = setting(5.0, gt=0.0)
    imu_sigma_deg: float = setting(0.5, gt=0.0)               # used when an Imu orientation covariance is unknown
    gyro_sigma_rad_s: float = setting(0.005, gt=0.0)          # white noise of one angular velocity sample
    gyro_bias_sigma_rad_s: float = setting(0.002, lo=0.0)     # allowance for an uncalibrated gyro bias
    gyro_max_gap_s: float = setting(0.1, gt=0.0)              # longer gaps between Imu samples: no gyro update for that frame
    accel_sigma_m_s2: float = setting(2.0, gt=0.0)            # motion model: horizontal acceleration noise
    vertical_accel_sigma_m_s2: float = setting(1.0, gt=0.0)
    angular_accel_sigma_deg_s2: float = setting(20.0, gt=0.0)
    initial_speed_sigma_m_s: float = setting(15.0, gt=0.0)    # velocity prior at the first frame
    initial_rate_sigma_deg_s: float = setting(30.0, gt=0.0)
    homography_sigma_gain: float = setting(1.0, gt=0.0)       # no covariance: corner sigma = gain * inlier rms (px)
    homography_min_sigma_px: float = setting(0.2, lo=0.0)     # model-error floor added to every homography measurement
    min_agl_m: float = setting(5.0, lo=0.0)                   # below this height the flat-ground model is not used
    gate_probability: float = setting(0.99999, gt=0.0, lt=1.0)        # chi-square gate of every update
    max_gated_in_a_row: int = setting(5, lo=1)              # then the filter re-acquires (fixes, attitude)
    telemetry_buffer_s: float = setting(10.0, gt=0.0)         # telemetry kept while waiting for frames
    max_step_s: float = setting(10.0, gt=0.0, hi=10.0)                 # longer gaps between frames are bridged by filter-only steps
    #                                          (their registration not fused)
    max_attitude_step_sigma_deg: float = setting(20.0, gt=0.0, hi=90.0)  # bound of the motion model's attitude noise per step
    ut_alpha: float = setting(1.0, gt=0.0)                    # sigma points: Merwe scaled (alpha, beta, kappa); see ukf.py
    ut_beta: float = setting(2.0)
    ut_kappa: float = setting(0.0, gt=-13.0)
    ut_iterations: int = setting(5, lo=1, hi=50)                   # passes of the homography and gyro updates (posterior
    #                                          linearisation, see ukf_updates._batch_update); 1: plain UKF update
    gsd_m_per_px: float = setting(float('nan'), gt=0.0, nan=True)       # raster ground sampling; NaN: the first frame's GSD
    drift_chain_sigma_px: float = setting(0.3, lo=0.0)        # drift control: random walk of chained corners per frame
    drift_pose_time_constant_s: float = setting(float('nan'), lo=0.0, nan=True)  # drift control: pose-error correlation time (s, >= 0; 0:
    #                                                  independent poses); NaN: from the filter, see drift.py
    history_frames: int = setting(20000, lo=0)              # filter moments kept for smoothed_poses() (0: none)

    def __post_init__(self) -> None:
        object.__setattr__(self, 'lever_arm_m', tuple(float(v) for v in self.lever_arm_m))
        check_settings(self, 'georef')

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
