"""A folder of still images (survey photos taken seconds apart) as a flight.

Images (*.jpg, *.jpeg, *.png, *.tif, *.tiff) are taken in file-name order. Stamps and fixes come
from a `telemetry_from_exif.csv` in the folder or its parent when present (columns file,
datetime 'YYYY:MM:DD HH:MM:SS', lat, lon, alt_msl, as written by exiftool-based exports), else
stamps are one second apart.
"""
from __future__ import annotations

import csv
import datetime as dt
from collections.abc import Iterator
from pathlib import Path

import cv2

from ..core.types import Frame, GeoFix
from ..errors import InputError

__all__ = ['IMAGE_SUFFIXES', 'ImageFolderReader', 'is_image_folder']

IMAGE_SUFFIXES = {'.jpg', '.jpeg', '.png', '.tif', '.tiff'}
TELEMETRY_NAME = 'telemetry_from_exif.csv'


def _images(path: Path) -> list[Path]:
    folder = path / 'images' if (path / 'images').is_dir() else path
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def is_image_folder(path: Path) -> bool:
    path = Path(path)
    return path.is_dir() and not (path / 'metadata.yaml').exists() and bool(_images(path))


class ImageFolderReader:
    """Frames (and fixes, when a telemetry CSV exists) of an image folder, in name order."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.files = _images(self.path)
        if not self.files:
            msg = f'{self.path} holds no images ({", ".join(sorted(IMAGE_SUFFIXES))}).'
            raise InputError(msg)
        self.telemetry: dict[str, dict[str, str]] = {}
        for candidate in (self.path / TELEMETRY_NAME, self.path.parent / TELEMETRY_NAME):
            if candidate.is_file():
                with open(candidate, newline='') as handle:
                    self.telemetry = {row['file']: row for row in csv.DictReader(handle)}
                break
        self.skipped: dict[str, int] = {}

    @property
    def frame_count(self) -> int:
        return len(self.files)

    def _stamp_ns(self, index: int, name: str) -> int:
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
            bgr = cv2.imread(str(file), cv2.IMREAD_COLOR)
            if bgr is None:
                self.skipped[f'{file.name}: unreadable image'] = 1
                continue
            stamp = self._stamp_ns(index, file.name)
            row = self.telemetry.get(file.name)
            if row:
                try:
                    yield GeoFix(stamp, float(row['lat']), float(row['lon']), float(row['alt_msl']), status=0)
                except (KeyError, ValueError):
                    pass
            yield Frame(stamp, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), None, file.name)
