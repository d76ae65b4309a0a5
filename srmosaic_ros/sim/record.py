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
    import msg_adapters as ma  # noqa: PLC0415 - ROS message code only when writing bags

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
                      lambda s=stamp, f=fid: ma.intrinsics_to_camera_info(flight.camera, stamp_ns=s, frame_id=f,
                                                                        flavor=flavor)))
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
    from ..io.bags import BagWriter  # noqa: PLC0415 - bag code only when writing bags

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
