"""`srmosaic simulate`: render a synthetic flight into a rosbag2 folder with ground truth.

Defaults come from :class:`SimConfig` (one source); an option left out keeps its default.
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

from ..errors import BagError
from .config import MODES, TRAJECTORIES, SimConfig
from .record import STORAGES, TRANSPORTS

__all__ = ['add_arguments', 'run', 'config_from_args']

_DEFAULTS = {f.name: f.default for f in dataclasses.fields(SimConfig)}

# (flag, SimConfig field, type, help); the default is appended to the help from SimConfig.
_OPTIONS: list[tuple[str, str, Any, str]] = [
    ('--world', 'world', str, 'orthophoto treated as a flat, north-up ground plane'),
    ('--world-gsd', 'world_gsd_m', float, 'metres per world pixel'),
    ('--origin-alt', 'origin_alt_m', float, 'ellipsoidal height (m) of the ground plane'),
    ('--trajectory', 'trajectory', str, 'flight pattern'),
    ('--frames', 'frames', int, 'number of frames (default: 60 for a line, the whole lawnmower pattern or orbit)'),
    ('--rate', 'rate_hz', float, 'frame rate (Hz)'),
    ('--altitude', 'altitude_m', float, 'height above the ground (m)'),
    ('--speed', 'speed_m_s', float, 'ground speed (m/s)'),
    ('--heading', 'heading_deg', float, 'direction of flight (first leg), degrees counter-clockwise from east'),
    ('--legs', 'legs', int, 'lawnmower: number of parallel legs'),
    ('--leg-length', 'leg_length_m', float, 'lawnmower: length of a leg (m)'),
    ('--leg-spacing', 'leg_spacing_m', float, 'lawnmower: distance between legs (m); legs step to the right'),
    ('--orbit-radius', 'orbit_radius_m', float, 'orbit: radius (m) of the counter-clockwise circle about --start '
     '(default there: the world centre); the camera looks at its centre'),
    ('--laps', 'laps', float, 'orbit: how far round (1.25 flies a quarter lap over ground seen before)'),
    ('--gust-deg', 'gust_deg', float, 'RMS of the roll, pitch and yaw gust disturbances (deg)'),
    ('--gust-pos', 'gust_pos_m', float, 'RMS of the position wander (m)'),
    ('--gimbal-azimuth', 'gimbal_azimuth_deg', float, 'gimbal azimuth, counter-clockwise from the nose (deg)'),
    ('--gimbal-elevation', 'gimbal_elevation_deg', float, 'gimbal elevation above the horizon (deg); -90 is nadir'),
    ('--hfov', 'hfov_deg', float, 'horizontal field of view (deg) at zoom 1'),
    ('--zoom', 'zoom', float, 'the lens zooms in to this many times its shortest focal length and back out '
     '(CameraInfo per frame)'),
    ('--zoom-period', 'zoom_period_s', float, 'seconds of one zoom in and out'),
    ('--rolling-shutter', 'rolling_shutter_s', float, 'readout time (s) from the first row to the last: each row '
     'is exposed at its own pose (0: global shutter); the stamp and the truth are the middle row\'s'),
    ('--width', 'width', int, 'sensor width (px) before decimation'),
    ('--height', 'height', int, 'sensor height (px) before decimation'),
    ('--decimate', 'decimate', int, 'integer decimation of the sensor image; frames are width/N x height/N'),
    ('--psf-sigma', 'psf_sigma_px', float, 'Gaussian optical PSF sigma in sensor pixels'),
    ('--noise', 'noise_sigma', float, 'Gaussian sensor noise sigma (0..255 units)'),
    ('--mode', 'mode', str, 'eo: RGB; ir: single-channel thermal-like grey'),
    ('--fix-rate', 'fix_rate_hz', float, 'GNSS fix rate (Hz)'),
    ('--imu-rate', 'imu_rate_hz', float, 'IMU rate (Hz)'),
    ('--gps-sigma-h', 'gps_sigma_h_m', float, 'GNSS horizontal noise sigma (m)'),
    ('--gps-sigma-v', 'gps_sigma_v_m', float, 'GNSS vertical noise sigma (m)'),
    ('--imu-sigma-deg', 'imu_sigma_deg', float, 'IMU orientation noise sigma per axis (deg)'),
    ('--vehicles', 'vehicles', int, 'cars driving straight over the ground (their true masks in ground_truth.json)'),
    ('--vehicle-speed', 'vehicle_speed_m_s', float, 'speed of the cars (m/s)'),
    ('--buildings', 'buildings', int, 'boxes with flat roofs on the ground, so frames disagree by parallax '
     '(their footprints and heights in ground_truth.json)'),
    ('--building-height', 'building_height_m', float, 'height of the tallest building (m)'),
    ('--seed', 'seed', int, 'random seed: the same seed gives the same bytes'),
]
_CHOICES = {'trajectory': TRAJECTORIES, 'mode': MODES}
_METAVARS = {'world': 'PATH', 'frames': 'N', 'legs': 'N', 'width': 'W', 'height': 'H', 'decimate': 'N',
             'seed': 'N', 'noise_sigma': 'SIGMA', 'speed_m_s': 'M/S', 'psf_sigma_px': 'PX',
             'trajectory': '{line,lawnmower,orbit}', 'mode': '{eo,ir}'}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `srmosaic simulate` to ``parser``."""
    for flag, name, typ, text in _OPTIONS:
        default = _DEFAULTS[name]
        shown = f' (default: {default})' if default is not None else ''
        kwargs: dict[str, Any] = {'type': typ, 'default': None, 'dest': name, 'help': text + shown,
                                  'metavar': _METAVARS.get(name, name.rsplit('_', 1)[-1].upper())}
        if name in _CHOICES:
            kwargs['choices'] = _CHOICES[name]
        parser.add_argument(flag, **kwargs)
    parser.add_argument('--origin', nargs=2, type=float, metavar=('LAT', 'LON'), default=None,
                        help='geodetic position of the world centre (default: known for the bundled worlds)')
    parser.add_argument('--start', nargs=2, type=float, metavar=('EAST', 'NORTH'), default=None,
                        help='start of the flight, metres from the world centre (default: path centred)')
    parser.add_argument('--turn-bank', action='store_true', default=None,
                        help='bank in lawnmower turns like a fixed-wing (coordinated turn)')
    parser.add_argument('--storage', choices=STORAGES, default='sqlite3', help='rosbag2 storage (default: sqlite3)')
    parser.add_argument('--transport', choices=TRANSPORTS, default='raw',
                        help='raw: sensor_msgs/Image; compressed: JPEG CompressedImage (default: raw)')
    parser.add_argument('--jpeg-quality', type=int, default=92, help='JPEG quality for --transport compressed')
    parser.add_argument('--out', type=Path, required=True, help='bag folder to create (holds ground_truth.json)')
    parser.add_argument('--overwrite', action='store_true', help='replace an existing --out')
    parser.add_argument('--video', type=Path, default=None,
                        help='also write the frames as an H.264 video (e.g. flight.mp4) with a telemetry sidecar '
                             '(flight.csv: time_s from the first frame, noisy fix and IMU attitude)')
    parser.add_argument('--gop', type=int, default=12, help='--video: I-frame every N frames (default: 12)')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')


def config_from_args(args: argparse.Namespace) -> SimConfig:
    """SimConfig from parsed arguments; options left out keep SimConfig's defaults."""
    values: dict[str, Any] = {}
    for _, name, _, _ in _OPTIONS:
        value = getattr(args, name, None)
        if value is not None:
            values[name] = value
    if getattr(args, 'origin', None) is not None:
        values['origin_lat_deg'], values['origin_lon_deg'] = args.origin
    if getattr(args, 'start', None) is not None:
        values['start_east_m'], values['start_north_m'] = args.start
    if getattr(args, 'turn_bank', None):
        values['turn_bank'] = True
    return SimConfig.from_dict(values)


def run(args: argparse.Namespace) -> int:
    """Simulate, write the bag and ground truth, print a summary. SrMosaicError propagates."""
    from .flight import simulate
    from .record import write_flight

    config = config_from_args(args)
    out_path = Path(args.out)
    if (out_path.exists() or out_path.is_symlink()) and not args.overwrite:  # fail before rendering
        msg = f'{str(out_path)!r} exists already; choose another --out or pass --overwrite.'
        raise BagError(msg)
    t0 = time.perf_counter()
    flight = simulate(config, progress=not getattr(args, 'no_progress', False))
    out = write_flight(flight, args.out, storage=args.storage, transport=args.transport, overwrite=args.overwrite,
                       jpeg_quality=args.jpeg_quality)
    if getattr(args, 'video', None) is not None:
        _write_video_and_sidecar(flight, args.video, args.gop)
    cam = flight.camera
    print(f'{len(flight.frames)} frames {cam.width}x{cam.height} ({config.mode}), {len(flight.fixes)} fixes, '
          f'{len(flight.imus)} IMU samples, camera gsd {flight.truth.camera_gsd_m:.3f} m/px, '
          f'{time.perf_counter() - t0:.1f} s -> {out} ({args.storage}, {args.transport}) + ground_truth.json')
    return 0


def _write_video_and_sidecar(flight: Any, path: Path, gop: int) -> None:
    """H.264 video of the frames (I-frame every `gop`) and its telemetry CSV beside it."""
    import numpy as np

    from ..core.georef.frames import matrix_from_quat_xyzw, rpy_from_R_enu_from_body
    from ..errors import SimulationError
    from ..io.telemetry_csv import write_telemetry_csv
    from ..io.video import write_video

    if gop < 1:
        msg = f'--gop must be >= 1, got {gop}.'
        raise SimulationError(msg)
    write_video(path, (f.image for f in flight.frames), fps=flight.config.rate_hz, gop=gop)
    t0 = flight.frames[0].stamp_ns
    imu_t = np.array([s.stamp_ns for s in flight.imus])
    rows = []
    for fix in flight.fixes:
        imu = flight.imus[int(np.argmin(np.abs(imu_t - fix.stamp_ns)))]
        roll, pitch, yaw = np.degrees(rpy_from_R_enu_from_body(matrix_from_quat_xyzw(imu.orientation_xyzw)))
        rows.append(((fix.stamp_ns - t0) * 1e-9, fix.latitude_deg, fix.longitude_deg, fix.altitude_m,
                     roll, pitch, yaw))
    write_telemetry_csv(Path(path).with_suffix('.csv'), rows)
