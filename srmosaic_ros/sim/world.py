"""The simulated world: an orthophoto as a flat, north-up ground plane.

World pixel (0, 0) is the north-west corner, +x east, +y south, pixel centres at integers. The
world's centre pixel ((W - 1) / 2, (H - 1) / 2) is the ENU origin, which sits at the geodetic
origin (lat, lon, alt); one pixel is ``gsd_m`` metres on the ground.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..core.image_decode import ImageRefused, decode_file
from ..core.georef.geodetic import LocalTangentPlane
from ..errors import ConfigError, InputError

__all__ = ['World', 'KNOWN_ORIGINS', 'REPO_ROOT', 'load_world', 'resolve_world_path', 'ir_from_rgb',
           'relative_to_repo']

REPO_ROOT = Path(__file__).resolve().parents[2]

#: Where the bundled photographs were taken (lat_deg, lon_deg), by file name.
KNOWN_ORIGINS: dict[str, tuple[float, float]] = {
    'caliterra_IMG_9360.jpg': (30.17115, -98.08987),
    'brighton_DJI_0025.jpg': (46.8427, -91.9944),
}


def resolve_world_path(path: str | os.PathLike[str]) -> Path:
    """The world image file: as given, or relative to the repository root; InputError if absent."""
    p = Path(path)
    for candidate in (p, REPO_ROOT / p) if not p.is_absolute() else (p,):
        if candidate.is_file():
            return candidate.resolve()
    msg = f'world image {str(path)!r} not found (also looked under {REPO_ROOT}); pass --world PATH.'
    raise InputError(msg)


def relative_to_repo(path: Path) -> str:
    """POSIX path relative to the repository root when inside it, else absolute."""
    try:
        return path.resolve().relative_to(REPO_ROOT).as_posix()
    except ValueError:
        return path.resolve().as_posix()


def ir_from_rgb(rgb: np.ndarray) -> np.ndarray:
    """A plausible thermal-looking grey image (H, W) uint8 from RGB (H, W, 3) uint8.

    White-hot mapping of a sunny day: dark surfaces absorb more sunlight and look warm, vegetation
    is cooled by transpiration, and a gamma > 1 on the inverted luminance stretches the mid-tones,
    so contrast differs from EO: L = luminance (Rec. 601), veg = clip(3 (2G - R - B) / (R + G + B),
    0, 1), ir = 0.05 + 0.9 (1 - L)^1.5 (1 - 0.5 veg) (all in [0, 1], then 8 bits).
    Pointwise, so it is applied once to the world and the renderer sees a mono world.
    """
    x = rgb.astype(np.float32) / 255.0
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    lum = 0.299 * r + 0.587 * g + 0.114 * b
    veg = np.clip(3.0 * (2.0 * g - r - b) / (r + g + b + 1e-3), 0.0, 1.0)
    ir = 0.05 + 0.9 * np.power(np.clip(1.0 - lum, 0.0, 1.0), 1.5) * (1.0 - 0.5 * veg)
    return np.clip(np.rint(ir * 255.0), 0, 255).astype(np.uint8)


@functools.lru_cache(maxsize=4)
def _read_image(path: str, mtime_ns: int, mode: str) -> np.ndarray:  # mtime keys the cache
    try:
        bgr = decode_file(path, cv2.IMREAD_COLOR, content=False).pixels
    except ImageRefused as exc:
        msg = f'cannot use world image {path!r}: {exc.what}; pass another --world.'
        raise InputError(msg) from None
    rgb = np.ascontiguousarray(bgr[..., ::-1])
    image = ir_from_rgb(rgb) if mode == 'ir' else rgb
    image.setflags(write=False)
    return image


@dataclass(frozen=True)
class World:
    """An orthophoto ground plane. ``image``: (H, W, 3) RGB or (H, W) mono uint8, read-only."""

    path: Path
    image: np.ndarray
    gsd_m: float
    origin: LocalTangentPlane

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def size_m(self) -> tuple[float, float]:
        """(east extent, north extent) in metres."""
        return self.width * self.gsd_m, self.height * self.gsd_m

    @property
    def enu_H_world_px(self) -> np.ndarray:
        """(3, 3) world pixel (x, y, 1) -> ground (east, north, 1) in metres."""
        g = self.gsd_m
        cx, cy = (self.width - 1) / 2.0, (self.height - 1) / 2.0
        return np.array([[g, 0.0, -g * cx], [0.0, -g, g * cy], [0.0, 0.0, 1.0]])

    @property
    def world_px_H_enu(self) -> np.ndarray:
        """(3, 3) ground (east, north, 1) in metres -> world pixel (x, y, 1)."""
        return np.linalg.inv(self.enu_H_world_px)


def load_world(path: str | os.PathLike[str], gsd_m: float, *, mode: str = 'eo',
               origin_lat_deg: float | None = None, origin_lon_deg: float | None = None,
               origin_alt_m: float = 0.0) -> World:
    """Read the world image (cached) and place it on the Earth.

    Without an explicit origin the file name must be one of :data:`KNOWN_ORIGINS`.
    """
    resolved = resolve_world_path(path)
    if origin_lat_deg is None or origin_lon_deg is None:
        if resolved.name not in KNOWN_ORIGINS:
            msg = (f'no geodetic origin is known for world {resolved.name!r}; '
                   'pass --origin LAT LON (the coordinates of the image centre).')
            raise ConfigError(msg)
        origin_lat_deg, origin_lon_deg = KNOWN_ORIGINS[resolved.name]
    image = _read_image(str(resolved), resolved.stat().st_mtime_ns, mode)
    return World(resolved, image, float(gsd_m), LocalTangentPlane(origin_lat_deg, origin_lon_deg, origin_alt_m))
