"""simulate(): a synthetic UAS flight over an orthophoto, with exact ground truth.

Deterministic: the same SimConfig (seed included) gives identical frames and telemetry. Random
streams are separate (trajectory gusts, image noise per frame, GNSS, IMU), so changing e.g. the
noise level leaves the trajectory unchanged.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..core.georef.frames import CameraPose, camera_pose
from ..core.georef.ground_homography import apply_H, ground_H_image, normalize_H
from ..core.types import CameraIntrinsics, Frame, GeoFix, ImuSample
from ..errors import SimulationError
from .config import DEFAULT_LINE_FRAMES, SimConfig
from .buildings import make_buildings, paint_roofs
from .render import Relief, hr_H_lr, quantize, render_frame
from .telemetry import sample_stamps, simulate_fixes, simulate_imu
from .traffic import make_traffic, paint_vehicles, restore_world
from .trajectory import BodyState, Path2D, Trajectory, lawnmower_path, line_path, orbit_path
from .truth import FrameTruth, Truth
from .world import World, load_world, relative_to_repo

__all__ = ['SimulatedFlight', 'simulate', 'sensor_intrinsics', 'frame_intrinsics', 'build_trajectory',
           'frame_count', 'zoom_at']

_STREAM_TRAJECTORY, _STREAM_IMAGE, _STREAM_GPS, _STREAM_IMU, _STREAM_TRAFFIC, _STREAM_BUILDINGS = 1, 2, 3, 4, 5, 6


@dataclass
class SimulatedFlight:
    """Everything a simulation produced: frames, telemetry, intrinsics, truth.

    frames: uint8 RGB (h, w, 3) or mono (h, w), with ``camera`` set; fixes at ``fix_rate_hz``;
    imus at ``imu_rate_hz``; camera: intrinsics of the published (decimated) frames.
    """

    config: SimConfig
    frames: list[Frame]
    fixes: list[GeoFix]
    imus: list[ImuSample]
    camera: CameraIntrinsics
    truth: Truth
    world: World = field(repr=False)


def zoom_at(config: SimConfig, t_s: float) -> float:
    """The focal length at ``t_s`` s from the first frame over the zoom-1 one: 1 at t = 0, ``zoom`` half a
    period later, back to 1 after a whole period."""
    return 1.0 + (config.zoom - 1.0) * 0.5 * (1.0 - math.cos(2.0 * math.pi * t_s / config.zoom_period_s))


def sensor_intrinsics(config: SimConfig, zoom: float = 1.0) -> CameraIntrinsics:
    """Pinhole of the sensor before decimation: fx = fy = zoom (W / 2) / tan(hfov / 2), centre ((W-1)/2, (H-1)/2)."""
    f = zoom * (config.width / 2.0) / math.tan(math.radians(config.hfov_deg) / 2.0)
    return CameraIntrinsics(width=config.width, height=config.height, fx=f, fy=f,
                            cx=(config.width - 1) / 2.0, cy=(config.height - 1) / 2.0)


def frame_intrinsics(config: SimConfig, zoom: float = 1.0) -> CameraIntrinsics:
    """Intrinsics of the published frames: the sensor's, through lr_H_hr of the decimation (no distortion)."""
    hr = sensor_intrinsics(config, zoom)
    K = np.linalg.inv(hr_H_lr(config.decimate)) @ hr.K
    return CameraIntrinsics(width=config.width // config.decimate, height=config.height // config.decimate,
                            fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
                            distortion_model='plumb_bob', distortion=(0.0, 0.0, 0.0, 0.0, 0.0))


def frame_count(config: SimConfig, path: Path2D | None = None) -> int:
    """Number of frames: config.frames, else 60 (line) or as many as the lawnmower pattern or orbit lasts."""
    if config.frames is not None:
        return int(config.frames)
    if config.trajectory == 'line' or path is None:
        return DEFAULT_LINE_FRAMES
    step_m = config.speed_m_s / config.rate_hz
    if step_m <= 0.0:
        return DEFAULT_LINE_FRAMES
    return int(math.floor(path.length_m / step_m + 1e-9)) + 1


def build_trajectory(config: SimConfig) -> tuple[Trajectory, int]:
    """The trajectory (path placed in the world) and the number of frames."""
    heading = math.radians(config.heading_deg)
    if config.trajectory == 'line':
        n = frame_count(config)
        path = line_path((0.0, 0.0), heading, config.speed_m_s * (n - 1) / config.rate_hz)
    elif config.trajectory == 'orbit':
        centre = (0.0, 0.0) if config.start_east_m is None else (config.start_east_m, config.start_north_m)
        path = orbit_path(centre, config.orbit_radius_m, config.laps, heading)
        n = frame_count(config, path)
        if config.speed_m_s * (n - 1) / config.rate_hz > path.length_m + 1e-6:
            msg = (f'--frames {n} outlasts the orbit ({config.laps:g} laps of radius {config.orbit_radius_m:g} m at '
                   f'--speed {config.speed_m_s:g} and --rate {config.rate_hz:g}); lower --frames or raise --laps.')
            raise SimulationError(msg)
    else:
        path = lawnmower_path((0.0, 0.0), heading, config.legs, config.leg_length_m, config.leg_spacing_m)
        n = frame_count(config, path)
        duration_s = (n - 1) / config.rate_hz
        if config.speed_m_s * duration_s > path.length_m + 1e-6:
            fit = frame_count(config.replace(frames=None), path)
            msg = (f'--frames {n} outlasts the lawnmower pattern ({config.legs} legs of {config.leg_length_m:g} m: '
                   f'{fit} frames at --speed {config.speed_m_s:g} and --rate {config.rate_hz:g}); '
                   'lower --frames or raise --legs / --leg-length.')
            raise SimulationError(msg)
    if config.trajectory == 'orbit':
        pass  # placed about its centre already
    elif config.start_east_m is None:
        lo, hi = path.bbox()
        path = path.translated(-(lo + hi) / 2.0)
    else:
        path = path.translated(np.array([config.start_east_m, config.start_north_m]))
    rng = np.random.default_rng([config.seed, _STREAM_TRAJECTORY])
    traj = Trajectory(path, speed_m_s=config.speed_m_s, altitude_m=config.altitude_m, rng=rng,
                      gust_deg=config.gust_deg, gust_pos_m=config.gust_pos_m, turn_bank=config.turn_bank)
    return traj, n


def gimbal_deg(config: SimConfig) -> tuple[float, float]:
    """(azimuth, elevation) of the camera on the body, degrees: the options', or on an orbit with
    ``orbit_look_at`` the direction of the circle's centre (left of the nose, atan(h / r) down)."""
    if config.trajectory == 'orbit' and config.orbit_look_at:
        return 90.0, -math.degrees(math.atan2(config.altitude_m, config.orbit_radius_m))
    return config.gimbal_azimuth_deg, config.gimbal_elevation_deg


def _footprint(config: SimConfig, k: int, world_px_H_hr: np.ndarray, R_enu_from_cam: np.ndarray,
               K_hr: np.ndarray) -> np.ndarray:
    """World-pixel corners (4, 2) of frame k's footprint; SimulationError if a corner misses the ground."""
    w, h = config.width, config.height
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    rays = (R_enu_from_cam @ np.linalg.inv(K_hr) @ np.c_[corners, np.ones(4)].T).T
    if np.any(rays[:, 2] >= -1e-3 * np.linalg.norm(rays, axis=1)):
        msg = (f'frame {k} sees the horizon (a corner ray does not reach the ground); point the camera further '
               'down (--gimbal-elevation nearer -90) or lower --hfov / --gust-deg.')
        raise SimulationError(msg)
    return apply_H(world_px_H_hr, corners)


def _check_inside(config: SimConfig, world: World, footprints: list[np.ndarray]) -> None:
    """SimulationError, naming the option to change, if a footprint leaves the world image."""
    for k, pts in enumerate(footprints):
        inside = ((pts[:, 0] >= 0.0) & (pts[:, 0] <= world.width - 1.0) & (pts[:, 1] >= 0.0)
                  & (pts[:, 1] <= world.height - 1.0))
        if np.all(inside):
            continue
        bad = pts[~inside][0]
        span = max(float(np.ptp(p[:, 0]) / world.width) for p in footprints), \
            max(float(np.ptp(p[:, 1]) / world.height) for p in footprints)
        if max(span) > 0.9:
            hint = 'one frame alone nearly covers the world: lower --altitude or --hfov, or raise --world-gsd'
        elif config.trajectory == 'line':
            hint = 'the flight is too long for the world: lower --frames or --speed (or raise --rate)'
        elif config.trajectory == 'orbit':
            hint = 'the orbit sees too far: lower --orbit-radius or --hfov, or raise --altitude'
        else:
            hint = 'the pattern is too large for the world: lower --legs, --leg-length, --leg-spacing or --frames'
        alternative = 'move --start / --heading' if config.start_east_m is not None else 'lower --altitude'
        msg = (f'frame {k} footprint leaves the world at world pixel ({bad[0]:.0f}, {bad[1]:.0f}) of a '
               f'{world.width}x{world.height} world ({world.size_m[0]:g} m x {world.size_m[1]:g} m at --world-gsd '
               f'{world.gsd_m:g}); {hint}, or {alternative}.')
        raise SimulationError(msg)


def _camera_at(config: SimConfig, traj: Trajectory, t_s: float, azimuth_deg: float,
               elevation_deg: float) -> tuple[BodyState, CameraPose, np.ndarray, np.ndarray]:
    """(body state, camera pose, sensor K (3, 3), enu_H_hr (3, 3): sensor pixel -> ground metres) of the
    camera at ``t_s`` s from the first frame (zoom included)."""
    st = traj.state(t_s)
    pose = camera_pose(st.position_enu_m, st.roll_rad, st.pitch_rad, st.yaw_rad,
                       gimbal_azimuth_rad=math.radians(azimuth_deg), gimbal_elevation_rad=math.radians(elevation_deg),
                       lever_arm_body_m=config.lever_arm_m)
    K_hr = sensor_intrinsics(config, zoom_at(config, t_s)).K
    return st, pose, K_hr, ground_H_image(K_hr, pose.R_enu_from_cam, pose.center_enu_m)


def _rolling_rows(config: SimConfig, traj: Trajectory, world: World, t_s: float, azimuth_deg: float,
                  elevation_deg: float) -> Callable[[np.ndarray], np.ndarray]:
    """Rolling shutter: sensor rows y (n,) -> (n, 3, 3) homographies of the pose when each row was exposed.

    Row y is exposed at t_s + (y - (H - 1) / 2) / (H - 1) x ``rolling_shutter_s``: the frame's stamp is
    its middle row's (whose homography is the truth's). Poses are computed at 17 instants over the
    readout and the homographies interpolated between them (the motion over a readout is smooth).
    """
    h = config.height
    ys = np.linspace(-0.1 * h, 1.1 * h, 17)  # the render grid extends a blur margin beyond the sensor
    times = t_s + (ys - (h - 1) / 2.0) / (h - 1) * config.rolling_shutter_s
    Hs = np.stack([normalize_H(world.world_px_H_enu @ _camera_at(config, traj, float(t), azimuth_deg, elevation_deg)[3])
                   for t in times])

    def at(y: np.ndarray) -> np.ndarray:
        y = np.clip(np.asarray(y, dtype=np.float64), ys[0], ys[-1])
        flat = Hs.reshape(len(ys), 9)
        return np.stack([np.interp(y, ys, flat[:, i]) for i in range(9)], axis=-1).reshape(-1, 3, 3)

    return at


def simulate(config: SimConfig, *, progress: bool = False) -> SimulatedFlight:
    """Render a synthetic flight. See :class:`SimConfig` for the options and their defaults.

    Raises:
        SimulationError: a footprint leaves the world or the camera sees the horizon (names the
            option to change); InputError / ConfigError: unusable world or options.

    """
    world = load_world(config.world, config.world_gsd_m, mode=config.mode, origin_lat_deg=config.origin_lat_deg,
                       origin_lon_deg=config.origin_lon_deg, origin_alt_m=config.origin_alt_m)
    cam = frame_intrinsics(config)  # at zoom 1: the truth's nominal camera
    hr_from_lr = hr_H_lr(config.decimate)
    traj, n_frames = build_trajectory(config)
    t0 = int(config.start_stamp_ns)
    stamps = [t0 + int(round(k * 1e9 / config.rate_hz)) for k in range(n_frames)]

    # Geometry of every frame first: fail before spending time on rendering.
    truths: list[FrameTruth] = []
    hr_homographies = []
    corners_all = []
    prev_ground_H = None
    azimuth_deg, elevation_deg = gimbal_deg(config)
    cameras = []
    for k, stamp in enumerate(stamps):
        t_s = (stamp - t0) * 1e-9
        cameras.append(frame_intrinsics(config, zoom_at(config, t_s)) if config.zoom != 1.0 else cam)
        st, pose, K_hr, enu_H_hr = _camera_at(config, traj, t_s, azimuth_deg, elevation_deg)
        world_px_H_hr = normalize_H(world.world_px_H_enu @ enu_H_hr)
        corners_all.append(_footprint(config, k, world_px_H_hr, pose.R_enu_from_cam, K_hr))
        enu_H_frame = enu_H_hr @ hr_from_lr
        world_px_H_frame = normalize_H(world.world_px_H_enu @ enu_H_frame)
        prev_H_cur = (None if prev_ground_H is None
                      else normalize_H(np.linalg.inv(prev_ground_H) @ enu_H_frame))
        prev_ground_H = enu_H_frame
        lat, lon, alt = world.origin.geodetic_from_enu(st.position_enu_m)
        truths.append(FrameTruth(
            index=k, stamp_ns=stamp, position_enu_m=st.position_enu_m.copy(), camera_enu_m=pose.center_enu_m.copy(),
            latitude_deg=float(lat), longitude_deg=float(lon), altitude_m=float(alt),
            roll_deg=math.degrees(st.roll_rad), pitch_deg=math.degrees(st.pitch_rad), yaw_deg=math.degrees(st.yaw_rad),
            R_enu_from_cam=pose.R_enu_from_cam.copy(), world_px_H_frame=world_px_H_frame, prev_H_cur=prev_H_cur))
        hr_homographies.append(world_px_H_hr)
    _check_inside(config, world, corners_all)
    pts = np.concatenate(corners_all)
    bbox = (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max()))
    vehicles = make_traffic(config.vehicles, config.vehicle_speed_m_s, world.gsd_m, bbox, (stamps[-1] - t0) * 1e-9,
                            np.random.default_rng([config.seed, _STREAM_TRAFFIC])) if config.vehicles else []
    duration_s = (stamps[-1] - t0) * 1e-9
    tracks = [(np.asarray(v.start_px), np.asarray(v.start_px) + duration_s * np.asarray(v.velocity_px_s)) for v in vehicles]
    buildings = make_buildings(config.buildings, config.building_height_m, world.gsd_m, bbox,
                               np.random.default_rng([config.seed, _STREAM_BUILDINGS]), keep_clear=tracks,
                               clearance_px=2.0 / world.gsd_m) if config.buildings else []
    scene = world.image
    if buildings:
        scene = paint_roofs(scene, buildings, world.gsd_m)  # the true orthophoto
    elif vehicles:
        scene = scene.copy()  # vehicles are painted frame by frame, restored after each

    frames: list[Frame] = []
    iterator = range(n_frames)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc='rendering', unit='frame')
    for k in iterator:
        saved = paint_vehicles(scene, vehicles, (stamps[k] - t0) * 1e-9) if vehicles else []
        rows = None
        if config.rolling_shutter_s > 0.0:
            rows = _rolling_rows(config, traj, world, (stamps[k] - t0) * 1e-9, azimuth_deg, elevation_deg)
        relief = None
        if buildings:
            cam_px = world.world_px_H_enu @ np.array([*truths[k].camera_enu_m[:2], 1.0])
            relief = Relief(buildings, (float(cam_px[0] / cam_px[2]), float(cam_px[1] / cam_px[2])),
                            float(truths[k].camera_enu_m[2]), world.gsd_m)
        clean = render_frame(scene, hr_homographies[k], (config.width, config.height),
                             decimate=config.decimate, psf_sigma_px=config.psf_sigma_px,
                             max_supersample=config.max_supersample, relief=relief, row_homographies=rows)
        restore_world(scene, saved)
        rng = np.random.default_rng([config.seed, _STREAM_IMAGE, k])
        frames.append(Frame(stamp_ns=stamps[k], image=quantize(clean, config.noise_sigma, rng), camera=cameras[k],
                            frame_id=config.frame_id))

    end = stamps[-1]
    fixes = simulate_fixes(traj, sample_stamps(t0, end, config.fix_rate_hz), t0, world.origin,
                           sigma_h_m=config.gps_sigma_h_m, sigma_v_m=config.gps_sigma_v_m,
                           rng=np.random.default_rng([config.seed, _STREAM_GPS]))
    imus = simulate_imu(traj, sample_stamps(t0, end, config.imu_rate_hz), t0,
                        orientation_sigma_deg=config.imu_sigma_deg, gyro_sigma_rad_s=config.gyro_sigma_rad_s,
                        accel_sigma_m_s2=config.accel_sigma_m_s2,
                        rng=np.random.default_rng([config.seed, _STREAM_IMU]))

    truth = Truth(
        config=config.to_dict(),
        world_path=relative_to_repo(world.path),
        world_size_px=(world.width, world.height),
        world_gsd_m=world.gsd_m,
        origin=(world.origin.lat0_deg, world.origin.lon0_deg, world.origin.alt0_m),
        camera=cam,
        camera_gsd_m=config.altitude_m / cam.fx,
        covered_bbox_world_px=(float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()),
                               float(pts[:, 1].max())),
        frames=truths,
        vehicles=vehicles,
        buildings=buildings,
    )
    return SimulatedFlight(config=config, frames=frames, fixes=fixes, imus=imus, camera=cam, truth=truth, world=world)
