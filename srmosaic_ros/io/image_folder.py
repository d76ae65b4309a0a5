"""A folder of still images (survey photos taken seconds apart) as a flight.

Images (*.jpg, *.jpeg, *.png, *.tif, *.tiff) are taken in file-name order. Their metadata is read
from each file's EXIF and XMP (io/exif.py): time, GPS position, the camera's intrinsics (focal
length and sensor size, io/camera_db.py) and, where the XMP has them, the gimbal's angles, which
become a camera attitude per frame. A `telemetry_from_exif.csv` in the folder or its parent
(columns file, datetime 'YYYY:MM:DD HH:MM:SS', lat, lon, alt_msl, as exiftool-based exports write)
overrides the EXIF's time and position when present. Without times, stamps are one second apart.

A still that cannot be a frame is left out with its name, in the log once and in ``left_out`` (file
name -> why; report.json ``images_left_out``, counted per kind in ``metadata.problems``): found when
the folder is opened, an empty file, a header no reader understands, a picture below
core/image_decode.MIN_IMAGE_SIDE_PX, a file with the same bytes as an earlier one; found when it is
decoded (core/image_decode.py), a truncated or damaged JPEG and a picture with no content.
"""
from __future__ import annotations

import csv
import datetime as dt
import hashlib
import logging
import math
import warnings
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from ..core.georef.frames import R_enu_from_cam_aviation
from ..core.image_decode import MIN_IMAGE_SIDE_PX, ImageRefused, decode_file
from ..core.types import CameraAttitude, CameraIntrinsics, Frame, GeoFix
from ..errors import InputError
from .metadata import NADIR_TOLERANCE_DEG, RECORDED_ATTITUDE_SIGMA_DEG, MetadataSummary

__all__ = ['IMAGE_SUFFIXES', 'ImageFolderReader', 'is_image_folder']

_LOG = logging.getLogger(__name__)

IMAGE_SUFFIXES = {'.jpg', '.jpeg', '.png', '.tif', '.tiff'}
TELEMETRY_NAME = 'telemetry_from_exif.csv'
#: Horizontal standard deviation of a still's GPS tag (m): a consumer receiver.
STILLS_GPS_SIGMA_H_M = 2.5
#: A still's GPS fix is stamped at its own GPS time when that is within this (s) of the capture.
GPS_TAG_MAX_LAG_S = 5.0
#: Vertical standard deviation of a GPS altitude without a height above take-off to vouch for it (m).
CAMERA_GPS_SIGMA_V_M = 30.0


def _images(path: Path) -> list[Path]:
    folder = path / 'images' if (path / 'images').is_dir() else path
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def is_image_folder(path: Path) -> bool:
    path = Path(path)
    return path.is_dir() and not (path / 'metadata.yaml').exists() and bool(_images(path))


class ImageFolderReader:
    """Frames, fixes and camera attitudes of an image folder, in name order (see the module docstring)."""

    def __init__(self, path: str | Path, *, use_exif: bool = True) -> None:
        self.path = Path(path)
        self.files = _images(self.path)
        if not self.files:
            msg = f'{self.path} holds no images ({", ".join(sorted(IMAGE_SUFFIXES))}).'
            raise InputError(msg)
        self.left_out: dict[str, str] = {}
        self.warned_about: set[str] = set()  # 'name: the decoder's warning' heard
        self.summary = MetadataSummary(source='none', frames=len(self.files))
        self.sizes = self._screen()
        if not self.files:
            said = '; '.join(f'{name}: {why}' for name, why in self.left_out.items())
            msg = f'{self.path} holds no usable image ({said}).'
            raise InputError(msg)
        self.telemetry: dict[str, dict[str, str]] = {}
        for candidate in (self.path / TELEMETRY_NAME, self.path.parent / TELEMETRY_NAME):
            if candidate.is_file():
                with open(candidate, newline='') as handle:
                    self.telemetry = {row['file']: row for row in csv.DictReader(handle)}
                break
        self.skipped: dict[str, int] = {}
        self.summary.source = 'telemetry CSV' if self.telemetry else 'none'
        self.summary.frames = len(self.files)
        self.meta: list = [None] * len(self.files)
        self._exif_stamps: list[int | None] = [None] * len(self.files)
        self._clock_offset_ns: int | None = None
        if use_exif:
            self._read_exif()

    def leave_out(self, name: str, kind: str, why: str) -> None:
        """Leave still ``name`` out of the run: said in the log once, kept in ``left_out``, counted in
        ``summary.problems[kind]``."""
        if name in self.left_out:
            return
        self.left_out[name] = why
        self.summary.problems[kind] += 1
        _LOG.warning('%s: %s', name, why)

    def refused(self, exc: ImageRefused) -> None:
        """A still the decoding guard refused (core/image_decode.py), left out."""
        self.leave_out(exc.name, exc.kind, exc.why)

    def decoder_warning(self, name: str, message: str) -> None:
        """A decoder's warning about a still it decoded whole: named in the log once, counted."""
        key = f'{name}: {message}'
        if key in self.warned_about:
            return
        self.warned_about.add(key)
        self.summary.problems['image_decoder_warning'] += 1
        _LOG.warning('%s: the decoder says "%s" (the still is used: every pixel was read).', name, message)

    def _screen(self) -> list[tuple[int, int]]:
        """Leave out the files that cannot be frames, as far as their headers tell (module docstring);
        returns the (width, height) of the files kept, from their headers."""
        from PIL import Image

        kept, sizes = [], []
        by_size: dict[int, list[Path]] = {}
        for file in self.files:
            try:
                nbytes = file.stat().st_size
            except OSError as exc:
                self.leave_out(file.name, 'image_unreadable', f'the file cannot be read ({exc.strerror}); left out.')
                continue
            if nbytes == 0:
                self.leave_out(file.name, 'image_empty', 'the file is empty (0 bytes); left out. Copy it again, '
                               'or remove it.')
                continue
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter('ignore', Image.DecompressionBombWarning)  # no pixels are decoded here
                    with Image.open(file) as im:
                        size = im.size
            except (OSError, ValueError, Image.DecompressionBombError) as exc:
                self.leave_out(file.name, 'image_unreadable', f'its header cannot be read ({exc}): it is damaged, '
                               'truncated or not an image; left out. Copy it again, or remove it.')
                continue
            if min(size) < MIN_IMAGE_SIDE_PX:
                self.leave_out(file.name, 'image_too_small', f'the image is {size[0]}x{size[1]} px, below the '
                               f'{MIN_IMAGE_SIDE_PX} px a side that registration needs; left out. Remove it.')
                continue
            same = [f for f in by_size.get(nbytes, []) if _digest(f) == _digest(file)]
            if same:
                self.leave_out(file.name, 'image_duplicate', f'the same bytes as {same[0].name} (a copy of one '
                               'still); left out. Remove one of the two.')
                continue
            by_size.setdefault(nbytes, []).append(file)
            kept.append(file)
            sizes.append(size)
        self.files = kept
        return sizes

    def _read_exif(self) -> None:
        """Every file's EXIF/XMP (headers only, no decoding), summarised for the report."""
        from .exif import intrinsics_from_metadata, read_still_metadata

        s = self.summary
        s.source = 'telemetry CSV + EXIF' if self.telemetry else 'EXIF/XMP'
        ground: list[float] = []
        sources: Counter[str] = Counter()
        for i, file in enumerate(self.files):
            try:
                meta = read_still_metadata(file)
            except InputError as exc:
                s.problem('exif_unreadable', f'{file.name}: {exc}')
                continue
            self.meta[i] = meta
            if not (math.isfinite(meta.latitude_deg) and math.isfinite(meta.longitude_deg)) \
                    and file.name not in self.telemetry:  # the telemetry CSV's position stands for it
                gps_notes = [n for n in meta.notes if n.startswith(('GPS ', 'GPSStatus', 'no GPS'))]
                if any(n.startswith(('GPS latitude', 'GPS longitude')) and n.endswith('out of range')
                       for n in gps_notes):
                    s.problem('exif_gps_out_of_range', f'{file.name}: its EXIF GPS position is out of range '
                              f'({"; ".join(gps_notes)}); the position is ignored and the frame is placed by '
                              'registration only. Fix the geotag (exiftool) or give telemetry_from_exif.csv')
                elif gps_notes and not all(n.startswith('no GPS') for n in gps_notes):
                    s.problem('exif_gps_unusable', f'{file.name}: its EXIF GPS position is unusable '
                              f'({"; ".join(gps_notes)}); the frame is placed by registration only')
                else:
                    s.problem('exif_no_gps', f'{file.name}: no GPS position in its EXIF; the frame is placed by '
                              'registration only')
            if meta.gimbal_ypr_deg is not None:
                s.frames_with_attitude += 1
            if math.isfinite(meta.altitude_m) and math.isfinite(meta.relative_altitude_m):
                ground.append(meta.altitude_m - meta.relative_altitude_m)
            camera, why = intrinsics_from_metadata(meta)
            sources[why] += 1
            if camera is not None:
                s.frames_with_intrinsics += 1
            else:
                s.problem('exif_no_intrinsics', f'{file.name}: no camera intrinsics ({why})')
        s.frames_with_position = sum(1 for m in self.meta if m is not None and math.isfinite(m.latitude_deg))
        if s.frames_with_position:
            s.use('gps position')
        if s.frames_with_attitude:
            s.use('gimbal attitude (XMP)')
        if s.frames_with_intrinsics:
            s.use('intrinsics')
        if sources:
            s.intrinsics_source = sources.most_common(1)[0][0]
        if any(m is not None and m.stamp_ns is not None for m in self.meta):
            s.use('time')
        if ground:
            s.ground_altitude_m = float(np.median(ground))
            s.ground_altitude_sigma_m = 5.0
            s.ground_altitude_source = 'EXIF GPS altitude minus XMP relative altitude (the take-off point)'
        for m in self.meta:
            for note in (m.notes if m is not None else ()):
                s.note(note)
        known = [(i, m.stamp_ns) for i, m in enumerate(self.meta) if m is not None and m.stamp_ns is not None]
        if known and len(known) < len(self.meta):
            # a still without its time between stills with theirs: the survey's median interval from a neighbour
            gaps = [(b - a) / (j - i) for (i, a), (j, b) in zip(known, known[1:]) if j > i]
            step = int(np.median(gaps)) if gaps else 1_000_000_000
            for i, m in enumerate(self.meta):
                if m is None or m.stamp_ns is None:
                    j, t = min(known, key=lambda k: abs(k[0] - i))
                    self._exif_stamps[i] = t + (i - j) * step
                    s.problem('exif_no_time', f'{self.files[i].name}: no capture time in its EXIF; placed at the '
                              'survey\'s median interval from its neighbours')
        offsets = [m.stamp_ns - m.gps_stamp_ns for m in self.meta
                   if m is not None and m.stamp_ns is not None and m.gps_stamp_ns is not None]
        self._clock_offset_ns = int(np.median(offsets)) if offsets else None
        last = None
        for i, m in enumerate(self.meta):
            t = m.stamp_ns if m is not None and m.stamp_ns is not None else self._exif_stamps[i]
            if t is not None:
                # the capture time; one not after the previous still's (a clock of 1 s) just after it
                stamp = int(t) if last is None or t > last else last + 1
                if last is not None and t < last:
                    s.problem('exif_time_backwards', f'{self.files[i].name}: capture time before the previous still\'s '
                              '(in name order); placed just after it')
                self._exif_stamps[i] = last = stamp
        if s.frames_with_intrinsics and not s.frames_with_attitude:
            s.note('intrinsics known but no gimbal angles: the camera attitude is unknown, so the mosaic is fitted '
                   'to the geotags (a similarity) instead of placed by the filter')

    @property
    def frame_count(self) -> int:
        return len(self.files)

    def stamp_ns(self, index: int, name: str) -> int:
        """Capture time of still ``index`` (named ``name``) on the survey's clock, ns."""
        if not self.telemetry.get(name) and self._exif_stamps[index] is not None:
            return self._exif_stamps[index]
        row = self.telemetry.get(name)
        if row and row.get('datetime'):
            try:
                t = dt.datetime.strptime(row['datetime'], '%Y:%m:%d %H:%M:%S').replace(tzinfo=dt.timezone.utc)
                return int(t.timestamp()) * 1_000_000_000 + index  # + index: equal seconds stay ordered
            except ValueError:
                pass
        return index * 1_000_000_000

    def __iter__(self) -> Iterator[Frame | GeoFix]:
        for index, file in enumerate(self.files):
            # the sensor as it recorded (no EXIF rotation): intrinsics and gimbal angles refer to it
            try:
                decoded = decode_file(file, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
            except ImageRefused as exc:
                self.refused(exc)
                self.skipped[f'{file.name}: {exc.kind}'] = 1
                continue
            for message in decoded.warnings:
                self.decoder_warning(file.name, message)
            bgr = decoded.pixels
            stamp = self.stamp_ns(index, file.name)
            row = self.telemetry.get(file.name)
            meta = self.meta[index]
            latlon = None
            if row:
                try:
                    fix = GeoFix(stamp, float(row['lat']), float(row['lon']), float(row['alt_msl']), status=0)
                    latlon = (fix.latitude_deg, fix.longitude_deg)
                    yield fix
                except (KeyError, ValueError):
                    pass
            elif meta is not None and math.isfinite(meta.latitude_deg) and math.isfinite(meta.longitude_deg):
                alt = meta.altitude_m if math.isfinite(meta.altitude_m) else meta.relative_altitude_m
                if math.isfinite(alt):
                    yield GeoFix(self.fix_stamp_ns(index, stamp), meta.latitude_deg, meta.longitude_deg, alt, status=0,
                                 position_covariance_m2=self._fix_covariance(meta), covariance_type=2)
                latlon = (meta.latitude_deg, meta.longitude_deg)
            camera = None
            if meta is not None:
                if meta.gimbal_ypr_deg is not None:
                    yaw, pitch, roll = meta.gimbal_ypr_deg
                    yield CameraAttitude(stamp, R_enu_from_cam_aviation(yaw, pitch, roll),
                                         math.radians(RECORDED_ATTITUDE_SIGMA_DEG))
                    if abs(pitch + 90.0) > NADIR_TOLERANCE_DEG:
                        latlon = None  # an oblique still's GPS position is not its frame centre
                    # the filter places stills whose camera attitude is known; without it (no gimbal
                    # angles) the mosaic is fitted to the geotags (core/georef/geotag_fit.py)
                    camera = self.camera(meta, bgr.shape[1], bgr.shape[0])
            if latlon is not None:
                self.summary.centres[stamp] = latlon
            yield Frame(stamp, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), camera, file.name)

    def size(self, index: int) -> tuple[int, int]:
        """(width, height) of still ``index`` as its header states it."""
        return self.sizes[index]

    def fix_stamp_ns(self, index: int, stamp: int) -> int:
        """When a still's GPS position was fixed, on the capture clock: its GPS time tag moved by the
        median offset between the two clocks over the survey (a camera clock set by hand is seconds
        off; a camera writes its last fix, which can trail the capture), else the capture time.

        The interpolation between fixes (the filter, the geotag fit) then puts each still where it was
        when taken; a tag repeating the previous still's fix has its time too, and is dropped.
        """
        meta = self.meta[index]
        if meta is None or meta.gps_stamp_ns is None or self._clock_offset_ns is None:
            return stamp
        fixed = int(meta.gps_stamp_ns) + self._clock_offset_ns
        return fixed if abs(fixed - stamp) <= GPS_TAG_MAX_LAG_S * 1e9 else stamp

    @staticmethod
    def _fix_covariance(meta) -> np.ndarray:
        """ENU covariance (m^2) of a still's GPS tag: a consumer receiver horizontally; vertically the
        same when the XMP's height above take-off vouches for the altitude, else CAMERA_GPS_SIGMA_V_M
        (cameras with their own GPS drift in altitude: the caliterra survey's climbs 114 m while the
        stills keep their scale), so the height comes from the registrations and the ground prior."""
        sigma_v = STILLS_GPS_SIGMA_H_M * 2.0 if math.isfinite(meta.relative_altitude_m) else CAMERA_GPS_SIGMA_V_M
        return np.diag([STILLS_GPS_SIGMA_H_M**2, STILLS_GPS_SIGMA_H_M**2, sigma_v**2])

    def camera(self, meta, width: int, height: int) -> CameraIntrinsics | None:
        """The still's intrinsics from its EXIF, for the image as decoded (None when unknown)."""
        from .exif import intrinsics_from_metadata

        camera, _ = intrinsics_from_metadata(meta)
        if camera is None:
            return None
        if (camera.width, camera.height) != (width, height):
            sx, sy = width / camera.width, height / camera.height
            camera = CameraIntrinsics(width, height, camera.fx * sx, camera.fy * sy,
                                      (camera.cx + 0.5) * sx - 0.5, (camera.cy + 0.5) * sy - 0.5)
        return camera


def _digest(file: Path) -> str:
    """SHA-1 of a file's bytes (to find copies among files of one size)."""
    h = hashlib.sha1()
    with open(file, 'rb') as handle:
        for block in iter(lambda: handle.read(1 << 20), b''):
            h.update(block)
    return h.hexdigest()
