"""Ground truth of a simulated flight and its JSON file (ground_truth.json).

File layout (format_version 1), all numbers in SI units except angles in degrees:

    format_version, generator
    config:               every SimConfig option
    world:                {path (relative to the repository when inside it), width_px, height_px,
                           gsd_m, origin: {latitude_deg, longitude_deg, altitude_m},
                           enu_H_world_px (3x3)}
    camera:               intrinsics of the published (decimated) frames {width, height, fx, fy, cx, cy,
                          distortion_model, distortion} (no distortion: plumb_bob, zeros); with a zoom
                          (config zoom > 1) those at zoom 1, each frame's own are in its CameraInfo
    camera_gsd_m:         nominal ground sampling of the published frames at the nominal altitude
    covered_bbox_world_px [x_min, y_min, x_max, y_max] of all frame footprints
    vehicles:             [{start_px [2], velocity_px_s [2], length_px, width_px, colour [3]}] in world
                          pixels, t in seconds from the first frame (sim/traffic.py; [] without traffic)
    buildings:            [{centre_px [2], length_px, width_px, heading_rad, height_m, roof [3], facade [3],
                           texture_seed}] (sim/buildings.py; [] on flat ground); the true orthophoto is
                          the world image with their roofs painted (buildings.paint_roofs)
    frames: [{index, stamp_ns, position_enu_m [3], camera_enu_m [3], latitude_deg, longitude_deg,
              altitude_m, roll_deg, pitch_deg, yaw_deg (body in ENU, REP 103),
              R_enu_from_cam (3x3), world_px_H_frame (3x3), prev_H_cur (3x3 or null)}]

Homographies map pixel coordinates (x right, y down, pixel centres at integers), normalised to
h33 = 1: world_px_H_frame takes frame pixels to world image pixels, prev_H_cur takes frame k
pixels to frame k-1 pixels. position_enu_m is the body origin (where the GNSS fix is), camera_enu_m
the optical centre.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.types import CameraIntrinsics
from ..errors import InputError
from .buildings import Building, building_view_mask
from .traffic import Vehicle, vehicle_mask

__all__ = ['TRUTH_FORMAT_VERSION', 'FrameTruth', 'Truth', 'save_truth', 'load_truth']

TRUTH_FORMAT_VERSION = 1


@dataclass(frozen=True)
class FrameTruth:
    """Truth of one frame (see the module docstring for units and conventions)."""

    index: int
    stamp_ns: int
    position_enu_m: np.ndarray
    camera_enu_m: np.ndarray
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    R_enu_from_cam: np.ndarray
    world_px_H_frame: np.ndarray
    prev_H_cur: np.ndarray | None

    def to_dict(self) -> dict[str, Any]:
        return {
            'index': self.index,
            'stamp_ns': self.stamp_ns,
            'position_enu_m': [float(v) for v in self.position_enu_m],
            'camera_enu_m': [float(v) for v in self.camera_enu_m],
            'latitude_deg': self.latitude_deg,
            'longitude_deg': self.longitude_deg,
            'altitude_m': self.altitude_m,
            'roll_deg': self.roll_deg,
            'pitch_deg': self.pitch_deg,
            'yaw_deg': self.yaw_deg,
            'R_enu_from_cam': np.asarray(self.R_enu_from_cam).tolist(),
            'world_px_H_frame': np.asarray(self.world_px_H_frame).tolist(),
            'prev_H_cur': None if self.prev_H_cur is None else np.asarray(self.prev_H_cur).tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FrameTruth:
        return cls(
            index=int(d['index']),
            stamp_ns=int(d['stamp_ns']),
            position_enu_m=np.array(d['position_enu_m'], dtype=np.float64),
            camera_enu_m=np.array(d['camera_enu_m'], dtype=np.float64),
            latitude_deg=float(d['latitude_deg']),
            longitude_deg=float(d['longitude_deg']),
            altitude_m=float(d['altitude_m']),
            roll_deg=float(d['roll_deg']),
            pitch_deg=float(d['pitch_deg']),
            yaw_deg=float(d['yaw_deg']),
            R_enu_from_cam=np.array(d['R_enu_from_cam'], dtype=np.float64),
            world_px_H_frame=np.array(d['world_px_H_frame'], dtype=np.float64),
            prev_H_cur=None if d['prev_H_cur'] is None else np.array(d['prev_H_cur'], dtype=np.float64),
        )


@dataclass(frozen=True)
class Truth:
    """Ground truth of a whole flight (see the module docstring)."""

    config: dict[str, Any]
    world_path: str
    world_size_px: tuple[int, int]
    world_gsd_m: float
    origin: tuple[float, float, float]  # (latitude_deg, longitude_deg, altitude_m) of the ENU origin
    camera: CameraIntrinsics
    camera_gsd_m: float
    covered_bbox_world_px: tuple[float, float, float, float]
    frames: list[FrameTruth] = field(default_factory=list)
    format_version: int = TRUTH_FORMAT_VERSION
    vehicles: list[Vehicle] = field(default_factory=list)
    buildings: list[Building] = field(default_factory=list)

    def building_mask(self, index: int) -> np.ndarray:
        """bool (height, width) of frame ``index``: its pixels that see a building, roof or wall (parallax)."""
        f = self.frames[index]
        if not self.buildings:
            return np.zeros((self.camera.height, self.camera.width), bool)
        cam = np.linalg.inv(self.enu_H_world_px) @ np.array([f.camera_enu_m[0], f.camera_enu_m[1], 1.0])
        return building_view_mask(self.buildings, f.world_px_H_frame, cam[:2] / cam[2], float(f.camera_enu_m[2]),
                                  (self.camera.width, self.camera.height), self.world_gsd_m)

    def vehicle_mask(self, index: int) -> np.ndarray:
        """bool (height, width) of frame ``index``: its pixels on a vehicle (all False without traffic)."""
        f = self.frames[index]
        return vehicle_mask(self.vehicles, self.time_s(index), f.world_px_H_frame, (self.camera.width, self.camera.height))

    def time_s(self, index: int) -> float:
        """Seconds of frame ``index`` since the first frame (the vehicles' clock)."""
        return (self.frames[index].stamp_ns - self.frames[0].stamp_ns) * 1e-9

    def vehicles_shown(self, labels: np.ndarray, painted: list[int], world_px_H_mosaic: np.ndarray) -> np.ndarray:
        """bool (h, w): the mosaic pixels taken from a frame in which a vehicle covers that ground (the
        truth's count of vehicle ghosts, without a comparison's floor).

        ``labels``: int (h, w), the frame each mosaic pixel comes from (TiledCanvas.labels over the
        region, -1: none); ``painted``: this flight's frame index of each label (label k is the k-th
        frame painted, Segment.frames); ``world_px_H_mosaic``: world pixel of each pixel of the region."""
        shown = np.zeros(labels.shape, bool)
        size = (labels.shape[1], labels.shape[0])
        for k, frame in enumerate(painted):
            here = labels == k
            if here.any():
                shown |= here & vehicle_mask(self.vehicles, self.time_s(frame), world_px_H_mosaic, size)
        return shown

    @property
    def enu_H_world_px(self) -> np.ndarray:
        """(3, 3) world pixel -> ground (east, north) in metres."""
        g = self.world_gsd_m
        cx, cy = (self.world_size_px[0] - 1) / 2.0, (self.world_size_px[1] - 1) / 2.0
        return np.array([[g, 0.0, -g * cx], [0.0, -g, g * cy], [0.0, 0.0, 1.0]])

    @property
    def stamps_ns(self) -> list[int]:
        return [f.stamp_ns for f in self.frames]

    def to_dict(self) -> dict[str, Any]:
        cam = self.camera
        return {
            'format_version': self.format_version,
            'generator': 'srmosaic simulate',
            'config': self.config,
            'world': {
                'path': self.world_path,
                'width_px': int(self.world_size_px[0]),
                'height_px': int(self.world_size_px[1]),
                'gsd_m': self.world_gsd_m,
                'origin': {'latitude_deg': self.origin[0], 'longitude_deg': self.origin[1],
                           'altitude_m': self.origin[2]},
                'enu_H_world_px': self.enu_H_world_px.tolist(),
            },
            'camera': {'width': cam.width, 'height': cam.height, 'fx': cam.fx, 'fy': cam.fy, 'cx': cam.cx,
                       'cy': cam.cy, 'distortion_model': cam.distortion_model,
                       'distortion': [float(v) for v in cam.distortion]},
            'camera_gsd_m': self.camera_gsd_m,
            'covered_bbox_world_px': [float(v) for v in self.covered_bbox_world_px],
            'frames': [f.to_dict() for f in self.frames],
            'vehicles': [v.to_dict() for v in self.vehicles],
            'buildings': [b.to_dict() for b in self.buildings],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Truth:
        version = d.get('format_version')
        if version != TRUTH_FORMAT_VERSION:
            msg = (f'ground truth format_version {version!r} is not supported (this srmosaic reads '
                   f'{TRUTH_FORMAT_VERSION}); regenerate it with `srmosaic simulate`.')
            raise InputError(msg)
        world, cam, origin = d['world'], d['camera'], d['world']['origin']
        return cls(
            config=dict(d['config']),
            world_path=str(world['path']),
            world_size_px=(int(world['width_px']), int(world['height_px'])),
            world_gsd_m=float(world['gsd_m']),
            origin=(float(origin['latitude_deg']), float(origin['longitude_deg']), float(origin['altitude_m'])),
            camera=CameraIntrinsics(width=int(cam['width']), height=int(cam['height']), fx=float(cam['fx']),
                                    fy=float(cam['fy']), cx=float(cam['cx']), cy=float(cam['cy']),
                                    distortion_model=str(cam.get('distortion_model', '')),
                                    distortion=tuple(float(v) for v in cam.get('distortion', ()))),
            camera_gsd_m=float(d['camera_gsd_m']),
            covered_bbox_world_px=tuple(float(v) for v in d['covered_bbox_world_px']),  # type: ignore[arg-type]
            frames=[FrameTruth.from_dict(f) for f in d['frames']],
            format_version=int(version),
            vehicles=[Vehicle.from_dict(v) for v in d.get('vehicles', [])],  # absent in files before traffic
            buildings=[Building.from_dict(b) for b in d.get('buildings', [])],  # absent in files before buildings
        )


def save_truth(truth: Truth, path: str | os.PathLike[str]) -> None:
    """Write ground_truth.json atomically (a temporary file renamed into place)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix='.' + path.name, suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as f:
            json.dump(truth.to_dict(), f, indent=1)
            f.write('\n')
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_truth(path: str | os.PathLike[str]) -> Truth:
    """Read a ground_truth.json (or the bag folder that holds one) written by ``srmosaic simulate``."""
    p = Path(path)
    if p.is_dir():
        p = p / 'ground_truth.json'
    try:
        with p.open(encoding='utf-8') as f:
            data = json.load(f)
    except FileNotFoundError:
        msg = (f'ground truth {str(p)!r} not found; `srmosaic simulate --out DIR` writes it as '
               'DIR/ground_truth.json.')
        raise InputError(msg) from None
    except (OSError, ValueError) as exc:
        msg = f'cannot read ground truth {str(p)!r}: {exc}; regenerate it with `srmosaic simulate`.'
        raise InputError(msg) from None
    try:
        return Truth.from_dict(data)
    except (KeyError, TypeError, ValueError) as exc:
        msg = f'ground truth {str(p)!r} is malformed ({exc!r}); regenerate it with `srmosaic simulate`.'
        raise InputError(msg) from None
