"""write_flight(): a simulated flight as a rosbag2 folder with its ground_truth.json.

Topics (stamps are the sensor stamps; log time = header stamp):

| topic                         | type                          | rate            |
|-------------------------------|-------------------------------|-----------------|
| /camera/image_raw             | sensor_msgs/msg/Image (rgb8 or mono8), transport 'raw' | frames |
| /camera/image_raw/compressed  | sensor_msgs/msg/CompressedImage (JPEG), transport 'compressed' | frames |
| /camera/camera_info           | sensor_msgs/msg/CameraInfo    | one per frame   |
| /fix                          | sensor_msgs/msg/NavSatFix     | fix_rate_hz     |
| /imu/data                     | sensor_msgs/msg/Imu           | imu_rate_hz     |

The bag is written in a hidden sibling folder and renamed into place when complete, so a failed
run leaves no half-written bag under the final name.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import BagError, ConfigError
from .truth import save_truth

if TYPE_CHECKING:
    from collections.abc import Callable

    from .flight import SimulatedFlight

__all__ = ['write_flight', 'write_stills_folder', 'STORAGES', 'TRANSPORTS', 'IMAGE_TOPIC', 'COMPRESSED_TOPIC', 'CAMERA_INFO_TOPIC',
           'FIX_TOPIC', 'IMU_TOPIC', 'TRUTH_FILE']

STORAGES = ('sqlite3', 'mcap')
TRANSPORTS = ('raw', 'compressed')
IMAGE_TOPIC = '/camera/image_raw'
COMPRESSED_TOPIC = '/camera/image_raw/compressed'
CAMERA_INFO_TOPIC = '/camera/camera_info'
FIX_TOPIC = '/fix'
IMU_TOPIC = '/imu/data'
TRUTH_FILE = 'ground_truth.json'


_Item = tuple[int, int, str, 'Callable[[], Any]']


def _messages(flight: SimulatedFlight, transport: str, jpeg_quality: int) -> list[_Item]:
    """(stamp_ns, tie-break order, topic, builder) of every message, sorted by time."""
    import msg_adapters as ma  # ROS message code only when writing bags

    flavor = 'rosbags'
    items: list[_Item] = []
    for frame in flight.frames:
        stamp, fid, image = frame.stamp_ns, frame.frame_id, frame.image
        if transport == 'compressed':
            items.append((stamp, 0, COMPRESSED_TOPIC,
                          lambda im=image, s=stamp, f=fid: ma.numpy_to_compressed(
                              im, fmt='jpeg', quality=jpeg_quality, stamp_ns=s, frame_id=f, flavor=flavor)))
        else:
            encoding = 'mono8' if image.ndim == 2 else 'rgb8'
            items.append((stamp, 0, IMAGE_TOPIC,
                          lambda im=image, e=encoding, s=stamp, f=fid: ma.numpy_to_image(
                              im, e, stamp_ns=s, frame_id=f, flavor=flavor)))
        items.append((stamp, 1, CAMERA_INFO_TOPIC,
                      lambda s=stamp, f=fid, c=frame.camera or flight.camera: ma.intrinsics_to_camera_info(
                          c, stamp_ns=s, frame_id=f, flavor=flavor)))
    for fix in flight.fixes:
        items.append((fix.stamp_ns, 2, FIX_TOPIC, lambda x=fix: ma.fix_to_navsat(x, flavor=flavor)))
    for imu in flight.imus:
        items.append((imu.stamp_ns, 3, IMU_TOPIC, lambda x=imu: ma.sample_to_imu(x, flavor=flavor)))
    items.sort(key=lambda it: (it[0], it[1]))
    return items


def write_flight(flight: SimulatedFlight, out_dir: str | os.PathLike[str], *, storage: str = 'sqlite3',
                 transport: str = 'raw', overwrite: bool = False, jpeg_quality: int = 92) -> Path:
    """Write ``flight`` as a rosbag2 folder ``out_dir`` holding also ``ground_truth.json``.

    Args:
        flight: output of :func:`srmosaic_ros.sim.simulate`.
        out_dir: the bag folder to create.
        storage: 'sqlite3' or 'mcap'.
        transport: 'raw' (sensor_msgs/Image on /camera/image_raw) or 'compressed'
            (sensor_msgs/CompressedImage, JPEG, on /camera/image_raw/compressed).
        overwrite: replace an existing ``out_dir``.
        jpeg_quality: JPEG quality for 'compressed'.

    Returns:
        The bag folder.

    Raises:
        ConfigError: unknown storage or transport. BagError: ``out_dir`` exists (without
            overwrite) or the bag cannot be written.

    """
    from ..io.bags import BagWriter  # bag code only when writing bags

    if storage not in STORAGES:
        raise ConfigError(f'storage {storage!r} is not supported; use one of {STORAGES} (--storage).')
    if transport not in TRANSPORTS:
        raise ConfigError(f'transport {transport!r} is not supported; use one of {TRANSPORTS} (--transport).')
    out = Path(out_dir)
    if (out.exists() or out.is_symlink()) and not overwrite:
        msg = f'{str(out)!r} exists already; choose another --out or pass --overwrite.'
        raise BagError(msg)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = out.parent / f'.{out.name}.partial-{os.getpid()}'
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir()
    bag = staging / out.name  # the storage file is named after the folder: keep the final name
    try:
        with BagWriter(bag, storage=storage, overwrite=False) as writer:
            for stamp, _, topic, build in _messages(flight, transport, jpeg_quality):
                writer.write(topic, build(), stamp)
        save_truth(flight.truth, bag / TRUTH_FILE)
        if out.is_symlink() or out.is_file():
            out.unlink()
        elif out.exists():
            shutil.rmtree(out)
        os.replace(bag, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out


def write_stills_folder(flight: SimulatedFlight, folder: str | os.PathLike[str]) -> Path:
    """A simulated flight as a folder of geotagged stills, as survey cameras leave them: images/
    (PNG, in name order) and telemetry_from_exif.csv (file, datetime, lat, lon, alt_msl; the fix at
    each frame's stamp, so ``fix_rate_hz`` must be a multiple of ``rate_hz``), with no intrinsics
    (io/image_folder.py reads it). Returns the folder."""
    import csv
    import datetime as dt

    import cv2

    folder = Path(folder)
    (folder / 'images').mkdir(parents=True)
    fix_at = {f.stamp_ns: f for f in flight.fixes}
    missing = [fr.stamp_ns for fr in flight.frames if fr.stamp_ns not in fix_at]
    if missing:
        msg = (f'{len(missing)} frames have no fix at their stamp (first at {missing[0]} ns): simulate with a '
               'fix rate that is a multiple of the frame rate.')
        raise ConfigError(msg)
    with open(folder / 'telemetry_from_exif.csv', 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(['file', 'datetime', 'lat', 'lon', 'alt_msl'])
        for k, fr in enumerate(flight.frames):
            name = f'IMG_{k:04d}.png'
            image = fr.image if fr.image.ndim == 2 else cv2.cvtColor(fr.image, cv2.COLOR_RGB2BGR)
            cv2.imwrite(str(folder / 'images' / name), image)
            fix = fix_at[fr.stamp_ns]
            when = dt.datetime.fromtimestamp(fr.stamp_ns // 1_000_000_000, tz=dt.timezone.utc)
            writer.writerow([name, when.strftime('%Y:%m:%d %H:%M:%S'), f'{fix.latitude_deg:.8f}',
                             f'{fix.longitude_deg:.8f}', f'{fix.altitude_m:.2f}'])
    return folder


#: The DJI XMP namespace a drone's stills carry their gimbal angles and height above take-off in.
_DJI_XMP = ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
            '<rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" '
            'drone-dji:AbsoluteAltitude="{abs:+.2f}" drone-dji:RelativeAltitude="{rel:+.2f}" '
            'drone-dji:GimbalRollDegree="{groll:+.2f}" drone-dji:GimbalYawDegree="{gyaw:+.2f}" '
            'drone-dji:GimbalPitchDegree="{gpitch:+.2f}" drone-dji:FlightRollDegree="{froll:+.2f}" '
            'drone-dji:FlightYawDegree="{fyaw:+.2f}" drone-dji:FlightPitchDegree="{fpitch:+.2f}"/>'
            '</rdf:RDF></x:xmpmeta>')


def write_drone_stills(flight: SimulatedFlight, folder: str | os.PathLike[str], *, focal_length_mm: float = 8.8,
                       gimbal_sigma_deg: float = 0.5, baro_sigma_m: float = 0.3, seed: int = 0) -> Path:
    """A simulated flight as a DJI drone leaves its survey: images/ of JPEG stills carrying their
    metadata in EXIF (time with offset, GPS position and altitude from the flight's fixes, make and
    model, focal length and focal-plane resolution) and DJI XMP (height above take-off, gimbal and
    flight angles: the true camera and body attitude plus ``gimbal_sigma_deg`` of noise), and no
    sidecar file. ``fix_rate_hz`` must be a multiple of ``rate_hz``. Returns the folder."""
    import datetime as dt

    import numpy as np
    from PIL import Image

    from ..core.georef.frames import aviation_angles_from_R_enu_from_cam, matrix_from_rotvec

    folder = Path(folder)
    (folder / 'images').mkdir(parents=True)
    fix_at = {f.stamp_ns: f for f in flight.fixes}
    rng = np.random.default_rng(seed)
    cam = flight.camera
    for k, (fr, truth) in enumerate(zip(flight.frames, flight.truth.frames)):
        fix = fix_at.get(fr.stamp_ns)
        if fix is None:
            msg = f'frame {k} has no fix at its stamp: simulate with a fix rate that is a multiple of the frame rate.'
            raise ConfigError(msg)
        image = Image.fromarray(fr.image if fr.image.ndim == 3 else np.repeat(fr.image[..., None], 3, axis=2))
        exif = Image.Exif()
        exif[0x010F], exif[0x0110] = 'DJI', 'FC6310'
        when = dt.datetime.fromtimestamp(fr.stamp_ns // 1_000_000_000, tz=dt.timezone.utc)
        sub = exif.get_ifd(0x8769)
        sub[0x9003] = when.strftime('%Y:%m:%d %H:%M:%S')
        sub[0x9291] = f'{(fr.stamp_ns % 1_000_000_000) // 1_000_000:03d}'
        sub[0x9011] = '+00:00'
        # a zoomed frame (sim zoom): a longer focal length on the same sensor
        sub[0x920A] = focal_length_mm * (fr.camera.fx / cam.fx if fr.camera is not None else 1.0)
        sub[0xA20E] = sub[0xA20F] = cam.fx / focal_length_mm  # pixels per mm
        sub[0xA210] = 4  # millimetres
        sub[0xA002], sub[0xA003] = cam.width, cam.height
        gps = exif.get_ifd(0x8825)
        gps[1], gps[3] = ('N' if fix.latitude_deg >= 0 else 'S'), ('E' if fix.longitude_deg >= 0 else 'W')
        gps[2], gps[4] = _dms(fix.latitude_deg), _dms(fix.longitude_deg)
        gps[5], gps[6] = (0 if fix.altitude_m >= 0 else 1), abs(fix.altitude_m)
        R = matrix_from_rotvec(rng.normal(0.0, np.radians(gimbal_sigma_deg), 3)) @ truth.R_enu_from_cam
        gyaw, gpitch, groll = aviation_angles_from_R_enu_from_cam(R)
        xmp = _DJI_XMP.format(abs=fix.altitude_m, rel=float(truth.camera_enu_m[2]) + rng.normal(0.0, baro_sigma_m),
                              gyaw=gyaw, gpitch=gpitch, groll=groll, froll=truth.roll_deg, fpitch=-truth.pitch_deg,
                              fyaw=(90.0 - truth.yaw_deg + 180.0) % 360.0 - 180.0)
        image.save(folder / 'images' / f'DJI_{k:04d}.JPG', quality=95, exif=exif, xmp=xmp.encode())
    return folder


def _dms(deg: float) -> tuple[float, float, float]:
    d = abs(deg)
    minutes = (d - int(d)) * 60.0
    return float(int(d)), float(int(minutes)), (minutes - int(minutes)) * 60.0
