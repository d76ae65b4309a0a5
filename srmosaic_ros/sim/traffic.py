"""Vehicles moving over the simulated ground, with their true masks: what a static-scene mosaic and
SR must keep out, and the truth to measure it.

A vehicle is a rectangle of ``VEHICLE_SIZE_M`` (length along its heading, width) in one colour,
driving in a straight line at constant speed; its position at time t (seconds from the flight's
first frame) is ``start + velocity t`` in world pixels. Vehicles are painted into the world image
(anti-aliased, 1/16 px vertices) for each frame before it is rendered, and the world is restored
after, so everything else of the rendering (PSF, pixel integration, noise) applies to them as to
the ground. Their true mask in a frame is the rectangle mapped through ``inv(world_px_H_frame)``.

World pixels: x right (east), y down (south), pixel centres at integers (the world image's).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ['VEHICLE_SIZE_M', 'Vehicle', 'make_traffic', 'paint_vehicles', 'restore_world', 'vehicle_mask']

#: Length and width of a simulated vehicle (m): a car.
VEHICLE_SIZE_M = (4.5, 1.8)
#: Colours (RGB 0..255) vehicles are drawn from: white, black, silver, red, blue.
PALETTE = ((240, 240, 235), (25, 25, 28), (170, 172, 175), (180, 30, 30), (30, 60, 160))
_SHIFT = 4  # fractional bits of the polygon vertices


@dataclass(frozen=True)
class Vehicle:
    """start_px (x, y) world px at t = 0; velocity_px_s (vx, vy); length_px, width_px; colour RGB 0..255."""

    start_px: tuple[float, float]
    velocity_px_s: tuple[float, float]
    length_px: float
    width_px: float
    colour: tuple[int, int, int]

    def polygon(self, t_s: float) -> np.ndarray:
        """(4, 2) world-pixel corners of the vehicle at time ``t_s``."""
        cx = self.start_px[0] + self.velocity_px_s[0] * t_s
        cy = self.start_px[1] + self.velocity_px_s[1] * t_s
        speed = math.hypot(*self.velocity_px_s)
        ux, uy = (self.velocity_px_s[0] / speed, self.velocity_px_s[1] / speed) if speed > 0 else (1.0, 0.0)
        a, b = 0.5 * self.length_px, 0.5 * self.width_px
        return np.array([[cx + a * ux - b * uy, cy + a * uy + b * ux], [cx + a * ux + b * uy, cy + a * uy - b * ux],
                         [cx - a * ux + b * uy, cy - a * uy - b * ux], [cx - a * ux - b * uy, cy - a * uy + b * ux]])

    def to_dict(self) -> dict[str, object]:
        return {'start_px': list(self.start_px), 'velocity_px_s': list(self.velocity_px_s),
                'length_px': self.length_px, 'width_px': self.width_px, 'colour': list(self.colour)}

    @classmethod
    def from_dict(cls, d: dict) -> Vehicle:  # type: ignore[type-arg]
        return cls(tuple(float(v) for v in d['start_px']), tuple(float(v) for v in d['velocity_px_s']),  # type: ignore[arg-type]
                   float(d['length_px']), float(d['width_px']), tuple(int(v) for v in d['colour']))  # type: ignore[arg-type]


def make_traffic(count: int, speed_m_s: float, gsd_m: float, bbox_px: tuple[float, float, float, float],
                 duration_s: float, rng: np.random.Generator) -> list[Vehicle]:
    """``count`` vehicles at ``speed_m_s`` in random headings and colours, placed so that each is inside
    ``bbox_px`` (x0, y0, x1, y1: the flight's covered world pixels) halfway through ``duration_s``."""
    x0, y0, x1, y1 = bbox_px
    speed_px = speed_m_s / gsd_m
    out = []
    for _ in range(int(count)):
        heading = rng.uniform(0.0, 2.0 * math.pi)
        vx, vy = speed_px * math.cos(heading), speed_px * math.sin(heading)
        mx, my = rng.uniform(x0 + 0.2 * (x1 - x0), x1 - 0.2 * (x1 - x0)), rng.uniform(y0 + 0.2 * (y1 - y0), y1 - 0.2 * (y1 - y0))
        half = 0.5 * duration_s
        out.append(Vehicle((mx - vx * half, my - vy * half), (vx, vy), VEHICLE_SIZE_M[0] / gsd_m,
                           VEHICLE_SIZE_M[1] / gsd_m, PALETTE[int(rng.integers(len(PALETTE)))]))
    return out


Saved = list[tuple[int, int, np.ndarray]]


def paint_vehicles(world: np.ndarray, vehicles: list[Vehicle], t_s: float) -> Saved:
    """Paint the vehicles at ``t_s`` into ``world`` (H, W, C) or (H, W) uint8, in place; returns what
    :func:`restore_world` needs to undo it (the patches under them, painted in order)."""
    saved: Saved = []
    h, w = world.shape[:2]
    for v in vehicles:
        poly = v.polygon(t_s)
        bx0, by0 = max(0, math.floor(poly[:, 0].min()) - 2), max(0, math.floor(poly[:, 1].min()) - 2)
        bx1, by1 = min(w, math.ceil(poly[:, 0].max()) + 3), min(h, math.ceil(poly[:, 1].max()) + 3)
        if bx1 <= bx0 or by1 <= by0:
            continue
        saved.append((bx0, by0, world[by0:by1, bx0:bx1].copy()))
        patch = np.ascontiguousarray(world[by0:by1, bx0:bx1])
        pts = np.round((poly - [bx0, by0]) * (1 << _SHIFT)).astype(np.int32)
        colour = v.colour if world.ndim == 3 else int(round(0.299 * v.colour[0] + 0.587 * v.colour[1] + 0.114 * v.colour[2]))
        cv2.fillConvexPoly(patch, pts, colour, lineType=cv2.LINE_AA, shift=_SHIFT)
        world[by0:by1, bx0:bx1] = patch
    return saved


def restore_world(world: np.ndarray, saved: Saved) -> None:
    """Undo :func:`paint_vehicles` (patches restored in reverse order)."""
    for bx0, by0, patch in reversed(saved):
        world[by0:by0 + patch.shape[0], bx0:bx0 + patch.shape[1]] = patch


def vehicle_mask(vehicles: list[Vehicle], t_s: float, world_px_H_frame: np.ndarray,
                 size: tuple[int, int]) -> np.ndarray:
    """bool (height, width): the frame pixels whose centre lies on a vehicle at ``t_s``; size = (width, height)."""
    w, h = size
    mask = np.zeros((h, w), np.uint8)
    frame_H_world = np.linalg.inv(world_px_H_frame)
    for v in vehicles:
        p = np.c_[v.polygon(t_s), np.ones(4)] @ frame_H_world.T
        if np.any(p[:, 2] <= 0):
            continue
        pts = np.round(p[:, :2] / p[:, 2:3] * (1 << _SHIFT)).astype(np.int32)
        cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=_SHIFT)
    return mask > 0
