"""SimConfig: every option of a synthetic flight, with its default and the reason for it.

The defaults make the bundled demo: a 640x480 camera with a 60 deg horizontal field of view at
100 m above the ground sees 0.18 m per pixel (1.8 world pixels at the default world gsd of
0.1 m/px, so rendering must prefilter), a 115 m x 87 m footprint; at 10 m/s and 4 frames/s the
ground moves 2.5 m = about 14 px between frames, and 60 frames of a line flight (150 m) stay well
inside the 400 m x 300 m world. The default lawnmower (3 legs of 100 m, 60 m apart: about 48 %
side overlap on the 115 m wide footprint, joined by half-circle turns; 196 frames) fits too. Its
turns are flown level by default (a multirotor whose gimbal holds the camera level through the
manoeuvre; gusts still act): a fixed-wing's coordinated-turn bank (``turn_bank=True``, 19 deg at
10 m/s in a 30 m radius) tilts the camera outward by that much and needs more room (e.g. a lower
altitude). Gusts of 2 deg RMS per axis (0.02 to 0.15 Hz) keep the motion between frames within
about 8 to 22 px while making every homography a genuinely projective one.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from ..errors import ConfigError

__all__ = ['SimConfig', 'DEFAULT_WORLD', 'TRAJECTORIES', 'MODES', 'DEFAULT_LINE_FRAMES', 'DEFAULT_START_STAMP_NS']

DEFAULT_WORLD = 'data/worlds/caliterra_IMG_9360.jpg'
TRAJECTORIES = ('line', 'lawnmower', 'orbit')
MODES = ('eo', 'ir')
DEFAULT_LINE_FRAMES = 60
DEFAULT_START_STAMP_NS = 1_700_000_000_000_000_000  # 2023-11-14T22:13:20Z, any fixed epoch would do


@dataclass(frozen=True)
class SimConfig:
    """Options of :func:`srmosaic_ros.sim.simulate`. Angles in degrees, lengths in metres.

    Frames: ENU world centred on the world image's centre (east = world +x, north = world -y),
    body x forward / y left / z up, yaw counter-clockwise from east (REP 103).
    """

    # world
    world: str = DEFAULT_WORLD
    world_gsd_m: float = 0.1
    origin_lat_deg: float | None = None  # None: the world's known location (see world.KNOWN_ORIGINS)
    origin_lon_deg: float | None = None
    origin_alt_m: float = 0.0  # ellipsoidal height of the ground plane
    # trajectory
    trajectory: str = 'line'
    frames: int | None = None  # None: 60 for a line, the whole pattern for a lawnmower
    rate_hz: float = 4.0
    altitude_m: float = 100.0
    speed_m_s: float = 10.0
    heading_deg: float = 0.0  # direction of the first leg, counter-clockwise from east
    start_east_m: float | None = None  # None: the path's bounding box centred on the world
    start_north_m: float | None = None
    legs: int = 3
    leg_length_m: float = 100.0
    leg_spacing_m: float = 60.0  # legs step to the right of the first leg's heading
    orbit_radius_m: float = 60.0  # orbit: a counter-clockwise circle about the start point (--start) or the world centre
    laps: float = 1.0  # orbit: how far round it flies (1.25: a quarter of the ground seen again)
    # orbit: the camera looks at the circle's centre (gimbal 90 deg left, below the horizon by
    # atan(altitude / radius)), the gimbal options ignored
    orbit_look_at: bool = True
    turn_bank: bool = False  # True: coordinated-turn bank atan(v^2 kappa / g), eased in over 1 s
    gust_deg: float = 2.0  # RMS of each of the roll, pitch, yaw disturbances
    gust_pos_m: float = 1.0  # RMS of the east, north, up position wander
    gimbal_azimuth_deg: float = 0.0
    gimbal_elevation_deg: float = -90.0  # nadir
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # body frame, body origin -> camera
    # camera and rendering
    width: int = 640  # sensor size before decimation
    height: int = 480
    hfov_deg: float = 60.0  # at zoom 1
    zoom: float = 1.0  # the longest focal length over the shortest: the lens zooms in and back out
    zoom_period_s: float = 20.0  # one zoom in and out: f(t) = f0 (1 + (zoom - 1) (1 - cos(2 pi t / period)) / 2)
    decimate: int = 1
    rolling_shutter_s: float = 0.0  # readout from the first row to the last (0: global shutter); the stamp is the middle row's
    psf_sigma_px: float = 0.7  # optical Gaussian PSF, sensor pixels (before decimation)
    noise_sigma: float = 2.0  # Gaussian sensor noise, 0..255 units
    mode: str = 'eo'
    max_supersample: int = 4
    # traffic (sim/traffic.py)
    vehicles: int = 0  # cars driving straight over the ground, painted into every frame
    vehicle_speed_m_s: float = 8.0
    # 3-D structure (sim/buildings.py): boxes with flat roofs standing on the ground, so frames disagree by parallax
    buildings: int = 0
    building_height_m: float = 15.0  # the tallest; heights are uniform in [0.3, 1] of it
    # telemetry
    fix_rate_hz: float = 5.0
    imu_rate_hz: float = 50.0
    gps_sigma_h_m: float = 2.5
    gps_sigma_v_m: float = 5.0
    imu_sigma_deg: float = 0.5
    gyro_sigma_rad_s: float = 0.002
    accel_sigma_m_s2: float = 0.05
    # run
    seed: int = 0
    start_stamp_ns: int = DEFAULT_START_STAMP_NS
    frame_id: str = field(default='camera_optical_frame')

    def __post_init__(self) -> None:
        object.__setattr__(self, 'lever_arm_m', tuple(float(v) for v in self.lever_arm_m))
        self.validate()

    def validate(self) -> None:
        """Raise ConfigError naming the first invalid option."""
        def need(ok: bool, what: str) -> None:
            if not ok:
                raise ConfigError(f'invalid simulation option: {what}.')

        need(self.trajectory in TRAJECTORIES, f'trajectory {self.trajectory!r} (use one of {TRAJECTORIES})')
        need(self.mode in MODES, f'mode {self.mode!r} (use one of {MODES})')
        need(self.world_gsd_m > 0, f'world_gsd_m {self.world_gsd_m} must be > 0')
        need(self.frames is None or self.frames >= 1, f'frames {self.frames} must be >= 1')
        for name in ('rate_hz', 'altitude_m', 'fix_rate_hz', 'imu_rate_hz', 'leg_length_m', 'leg_spacing_m',
                     'orbit_radius_m', 'laps'):
            need(getattr(self, name) > 0, f'{name} {getattr(self, name)} must be > 0')
        need(self.speed_m_s >= 0, f'speed_m_s {self.speed_m_s} must be >= 0')
        need(self.legs >= 1, f'legs {self.legs} must be >= 1')
        need(0 < self.hfov_deg < 170, f'hfov_deg {self.hfov_deg} must be in (0, 170)')
        need(self.width >= 2 and self.height >= 2, f'frame size {self.width}x{self.height} is too small')
        need(self.decimate >= 1, f'decimate {self.decimate} must be >= 1')
        need(math.isfinite(self.rolling_shutter_s) and 0.0 <= self.rolling_shutter_s <= 0.2,
             f'rolling_shutter_s {self.rolling_shutter_s} must be in [0, 0.2] (a readout, not a frame interval)')
        need(math.isfinite(self.zoom) and 1.0 <= self.zoom <= 30.0, f'zoom {self.zoom} must be in [1, 30]')
        need(math.isfinite(self.zoom_period_s) and self.zoom_period_s > 0, f'zoom_period_s {self.zoom_period_s} must be > 0')
        need(self.width // self.decimate >= 2 and self.height // self.decimate >= 2,
             f'decimate {self.decimate} leaves no frame of {self.width}x{self.height}')
        need(self.max_supersample >= 1, f'max_supersample {self.max_supersample} must be >= 1')
        for name in ('psf_sigma_px', 'noise_sigma', 'gust_deg', 'gust_pos_m', 'gps_sigma_h_m', 'gps_sigma_v_m',
                     'imu_sigma_deg', 'gyro_sigma_rad_s', 'accel_sigma_m_s2'):
            value = getattr(self, name)
            need(math.isfinite(value) and value >= 0, f'{name} {value} must be >= 0')
        need(-90.0 <= self.gimbal_elevation_deg < 0.0,
             f'gimbal_elevation_deg {self.gimbal_elevation_deg} must look down: in [-90, 0)')
        need((self.origin_lat_deg is None) == (self.origin_lon_deg is None),
             'origin_lat_deg and origin_lon_deg go together')
        need(self.origin_lat_deg is None or -90 < self.origin_lat_deg < 90,
             f'origin_lat_deg {self.origin_lat_deg} must be in (-90, 90)')
        need((self.start_east_m is None) == (self.start_north_m is None),
             'start_east_m and start_north_m go together')
        need(len(self.lever_arm_m) == 3, 'lever_arm_m needs 3 values')
        need(isinstance(self.vehicles, int) and 0 <= self.vehicles <= 1000, f'vehicles {self.vehicles} must be in 0..1000')
        need(isinstance(self.buildings, int) and 0 <= self.buildings <= 500, f'buildings {self.buildings} must be in 0..500')
        need(math.isfinite(self.building_height_m) and 0 < self.building_height_m <= 0.8 * self.altitude_m,
             f'building_height_m {self.building_height_m} must be > 0 and at most 0.8 x altitude_m '
             f'({0.8 * self.altitude_m:g}): the camera flies above the roofs')
        need(math.isfinite(self.vehicle_speed_m_s) and self.vehicle_speed_m_s >= 0,
             f'vehicle_speed_m_s {self.vehicle_speed_m_s} must be >= 0')

    def to_dict(self) -> dict[str, Any]:
        """All options as JSON-ready values."""
        out = dataclasses.asdict(self)
        out['lever_arm_m'] = list(self.lever_arm_m)
        return out

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> SimConfig:
        """Build from a mapping of option names; unknown names are refused."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            msg = f'unknown simulation option(s) {unknown}; known: {sorted(known)}.'
            raise ConfigError(msg)
        kwargs = dict(values)
        if 'lever_arm_m' in kwargs:
            kwargs['lever_arm_m'] = tuple(kwargs['lever_arm_m'])
        return cls(**kwargs)

    def replace(self, **changes: Any) -> SimConfig:
        return dataclasses.replace(self, **changes)
