"""Buildings on the simulated ground: 3-D structure, so that frames disagree by parallax as real ones do.

A building is a box standing on the ground plane: a rectangular footprint (centre, length along its
heading, width; world pixels) and a height in metres, with a flat roof. Its roof is painted into the
world image (:func:`paint_roofs`): that image is then the true orthophoto, what a camera looking
straight down from infinitely far away would see, and the truth a mosaic is measured against. Its
four walls are not in any orthophoto; they get a facade colour, shaded by which way they face, with
rows of windows every ``FLOOR_M`` metres so that they carry texture as real facades do.

The renderer traces, for every sample of the sensor plane, the ray from the camera centre to its
ground point through the boxes (:func:`trace`): where a box is hit first the sample takes the roof
(the world image at the hit's footprint position) or the wall's colour instead of the ground
behind it. So roofs are displaced by their height (relief displacement: a roof at height h seen from
height Z is where the ground point h / (Z - h) further out from the nadir would be), walls appear
on the far side of oblique views, and ground behind a building is hidden.

Units: x, y in world pixels (x east, y south, pixel centres at integers), heights in metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ['Building', 'FLOOR_M', 'make_buildings', 'paint_roofs', 'footprint_mask', 'trace',
           'building_view_mask']

#: Storey height (m): one row of windows per storey.
FLOOR_M = 3.0
#: Window spacing along a wall (m).
BAY_M = 2.5
#: Roof colours (RGB): terracotta, light grey, dark grey, beige, green-grey.
ROOF_PALETTE = ((170, 80, 55), (185, 185, 180), (85, 85, 90), (205, 190, 160), (110, 125, 110))
#: Facade colours (RGB): render, brick, concrete.
FACADE_PALETTE = ((215, 205, 185), (150, 80, 60), (160, 160, 155))
#: Brightness of the four walls, by the outward normal: +u, -u, +v, -v (a low sun on one side).
WALL_SHADE = (0.95, 0.55, 0.75, 0.45)
_SHIFT = 4  # fractional bits of polygon vertices


@dataclass(frozen=True)
class Building:
    """centre_px (x, y), length_px along ``heading_rad`` (from world +x towards +y), width_px, height_m,
    roof and facade colours (RGB 0..255), and ``texture_seed`` for the roof's grain."""

    centre_px: tuple[float, float]
    length_px: float
    width_px: float
    heading_rad: float
    height_m: float
    roof: tuple[int, int, int]
    facade: tuple[int, int, int]
    texture_seed: int

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors (u along the length, v across), world pixels."""
        c, s = math.cos(self.heading_rad), math.sin(self.heading_rad)
        return np.array([c, s]), np.array([-s, c])

    def polygon(self) -> np.ndarray:
        """(4, 2) world-pixel corners of the footprint, in order."""
        u, v = self.axes
        a, b = 0.5 * self.length_px, 0.5 * self.width_px
        c = np.asarray(self.centre_px, float)
        return np.array([c + a * u + b * v, c - a * u + b * v, c - a * u - b * v, c + a * u - b * v])

    def to_dict(self) -> dict[str, object]:
        return {'centre_px': list(self.centre_px), 'length_px': self.length_px, 'width_px': self.width_px,
                'heading_rad': self.heading_rad, 'height_m': self.height_m, 'roof': list(self.roof),
                'facade': list(self.facade), 'texture_seed': self.texture_seed}

    @classmethod
    def from_dict(cls, d: dict) -> Building:  # type: ignore[type-arg]
        return cls((float(d['centre_px'][0]), float(d['centre_px'][1])), float(d['length_px']),
                   float(d['width_px']), float(d['heading_rad']), float(d['height_m']),
                   tuple(int(v) for v in d['roof']), tuple(int(v) for v in d['facade']),  # type: ignore[arg-type]
                   int(d['texture_seed']))


def make_buildings(count: int, max_height_m: float, gsd_m: float, bbox_px: tuple[float, float, float, float],
                   rng: np.random.Generator, *, keep_clear: list[tuple[np.ndarray, np.ndarray]] = (),  # type: ignore[assignment]
                   clearance_px: float = 0.0) -> list[Building]:
    """Up to ``count`` non-overlapping buildings inside ``bbox_px`` (x0, y0, x1, y1).

    Footprints 8-24 m by 8-16 m at random headings, heights uniform in [0.3, 1] x ``max_height_m``.
    ``keep_clear``: segments (p0, p1) in world px no footprint may come within ``clearance_px`` of
    (the vehicles' tracks: cars drive on the ground, not through houses). Fewer than ``count`` are
    returned when the area is full (50 tries per building).
    """
    x0, y0, x1, y1 = bbox_px
    placed: list[Building] = []
    for _ in range(int(count)):
        for _try in range(50):
            length = rng.uniform(8.0, 24.0) / gsd_m
            width = rng.uniform(8.0, min(16.0, length * gsd_m)) / gsd_m
            heading = rng.uniform(0.0, math.pi)
            cx, cy = rng.uniform(x0 + 0.1 * (x1 - x0), x1 - 0.1 * (x1 - x0)), rng.uniform(y0 + 0.1 * (y1 - y0), y1 - 0.1 * (y1 - y0))
            radius = 0.5 * math.hypot(length, width)
            if any(math.hypot(cx - b.centre_px[0], cy - b.centre_px[1]) < radius + 0.5 * math.hypot(b.length_px, b.width_px) + 2.0 / gsd_m
                   for b in placed):
                continue
            if any(_point_segment_px((cx, cy), p0, p1) < radius + clearance_px for p0, p1 in keep_clear):
                continue
            placed.append(Building((cx, cy), length, width, heading, rng.uniform(0.3, 1.0) * max_height_m,
                                   ROOF_PALETTE[int(rng.integers(len(ROOF_PALETTE)))],
                                   FACADE_PALETTE[int(rng.integers(len(FACADE_PALETTE)))], int(rng.integers(2**31))))
            break
    return placed


def _point_segment_px(p: tuple[float, float], a: np.ndarray, b: np.ndarray) -> float:
    p_, a_, b_ = np.asarray(p, float), np.asarray(a, float), np.asarray(b, float)
    d = b_ - a_
    t = 0.0 if not np.any(d) else float(np.clip(np.dot(p_ - a_, d) / np.dot(d, d), 0.0, 1.0))
    return float(np.hypot(*(p_ - a_ - t * d)))


def paint_roofs(world: np.ndarray, buildings: list[Building], gsd_m: float) -> np.ndarray:
    """The true orthophoto: a copy of ``world`` (H, W, C) or (H, W) uint8 with every roof painted.

    A roof is its colour with a fine grain (+-8 %, blurred noise: shingles, gravel) and a darker
    parapet 0.5 m wide, anti-aliased at its edges.
    """
    out = world.copy()
    h, w = out.shape[:2]
    for b in buildings:
        poly = b.polygon()
        bx0, by0 = max(0, math.floor(poly[:, 0].min()) - 2), max(0, math.floor(poly[:, 1].min()) - 2)
        bx1, by1 = min(w, math.ceil(poly[:, 0].max()) + 3), min(h, math.ceil(poly[:, 1].max()) + 3)
        if bx1 <= bx0 or by1 <= by0:
            continue
        mask = np.zeros((by1 - by0, bx1 - bx0), np.uint8)
        pts = np.round((poly - [bx0, by0]) * (1 << _SHIFT)).astype(np.int32)
        cv2.fillConvexPoly(mask, pts, 255, lineType=cv2.LINE_AA, shift=_SHIFT)
        alpha = mask.astype(np.float32) / 255.0
        inner = cv2.erode(mask, np.ones((3, 3), np.uint8), iterations=max(1, round(0.5 / gsd_m)))
        grain = np.random.default_rng(b.texture_seed).standard_normal(mask.shape).astype(np.float32)
        grain = cv2.GaussianBlur(grain, (0, 0), 1.0)
        shade = 1.0 + 0.08 * grain / max(float(grain.std()), 1e-6)
        shade = np.where(inner > 127, shade, 0.7 * shade)  # the parapet
        colour = np.asarray(b.roof, np.float32)
        if out.ndim == 2:
            colour = np.float32(0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2])
            roof = colour * shade
        else:
            roof = colour[None, None, :] * shade[..., None]
            alpha = alpha[..., None]
        patch = out[by0:by1, bx0:bx1].astype(np.float32)
        out[by0:by1, bx0:bx1] = np.clip(np.rint(patch + alpha * (roof - patch)), 0, 255).astype(np.uint8)
    return out


def footprint_mask(buildings: list[Building], size: tuple[int, int], px_H_world: np.ndarray | None = None) -> np.ndarray:
    """bool (height, width) of an image of ``size`` (width, height): pixels whose centre is on a footprint.

    ``px_H_world`` maps world px to the image's pixels (None: the image is the world).
    """
    w, h = size
    mask = np.zeros((h, w), np.uint8)
    H = np.eye(3) if px_H_world is None else np.asarray(px_H_world, float)
    for b in buildings:
        p = np.c_[b.polygon(), np.ones(4)] @ H.T
        if np.any(p[:, 2] <= 0):
            continue
        pts = np.round(p[:, :2] / p[:, 2:3] * (1 << _SHIFT)).astype(np.int32)
        cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=_SHIFT)
    return mask > 0


@dataclass(frozen=True)
class TraceResult:
    """What each ray sees: ``x, y`` world px to sample the (roof-painted) world at (the ground point, or
    the roof point hit), ``wall`` bool where a wall is hit first, ``wall_rgb`` (N_wall, 3) float32 0..255
    the facade seen there (in the order of ``x[wall]``), ``building`` bool where any building is hit."""

    x: np.ndarray
    y: np.ndarray
    wall: np.ndarray
    wall_rgb: np.ndarray
    building: np.ndarray


def trace(buildings: list[Building], camera_xy_px: np.ndarray, camera_height_m: float, ground_x: np.ndarray,
          ground_y: np.ndarray, gsd_m: float, image_px: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> TraceResult:
    """Trace the rays from the camera to the ground points ``ground_x, ground_y`` (any shape, world px)
    through the buildings.

    The ray is P(t) = C + t (G - C), t in [0, 1], with C = (camera x, y px, height m), G = (x, y, 0).
    Each box is intersected exactly (slab method in its own axes: u along, v across, z up); the hit
    of smallest t wins. ``image_px``: optional (px, py, img_H_world) giving each ground point's own
    image coordinates (px, py, same shape) and the map world px -> image px of the ground plane;
    with it only the rays inside each box's image bounding box are tested (fast), without it all.
    """
    gx, gy = np.asarray(ground_x, np.float64), np.asarray(ground_y, np.float64)
    out_x, out_y = gx.copy(), gy.copy()
    best_t = np.full(gx.shape, np.inf)
    wall = np.zeros(gx.shape, bool)
    wall_rgb = np.zeros(gx.shape + (3,), np.float32)
    hit_any = np.zeros(gx.shape, bool)
    cx, cy = float(camera_xy_px[0]), float(camera_xy_px[1])
    zc = float(camera_height_m)
    for b in buildings:
        if b.height_m >= zc:
            continue  # the camera is never inside or below a roof
        sel = _candidates(b, cx, cy, zc, gx, image_px)
        if sel is None:
            continue
        sx, sy = gx[sel], gy[sel]
        u_ax, v_ax = b.axes
        ox, oy = cx - b.centre_px[0], cy - b.centre_px[1]
        ou, ov = ox * u_ax[0] + oy * u_ax[1], ox * v_ax[0] + oy * v_ax[1]
        dx, dy = sx - cx, sy - cy
        du, dv = dx * u_ax[0] + dy * u_ax[1], dx * v_ax[0] + dy * v_ax[1]
        a, c = 0.5 * b.length_px, 0.5 * b.width_px
        with np.errstate(divide='ignore', invalid='ignore'):
            tu1, tu2 = (-a - ou) / du, (a - ou) / du
            tv1, tv2 = (-c - ov) / dv, (c - ov) / dv
        # a ray parallel to a slab is inside it everywhere or nowhere
        tu_in = np.where(du == 0, np.where(abs(ou) <= a, -np.inf, np.inf), np.minimum(tu1, tu2))
        tu_out = np.where(du == 0, np.where(abs(ou) <= a, np.inf, -np.inf), np.maximum(tu1, tu2))
        tv_in = np.where(dv == 0, np.where(abs(ov) <= c, -np.inf, np.inf), np.minimum(tv1, tv2))
        tv_out = np.where(dv == 0, np.where(abs(ov) <= c, np.inf, -np.inf), np.maximum(tv1, tv2))
        t_roof = 1.0 - b.height_m / zc  # z = zc (1 - t) falls through the roof's height
        t_in = np.maximum(np.maximum(tu_in, tv_in), t_roof)
        t_out = np.minimum(np.minimum(tu_out, tv_out), 1.0)
        hit = (t_in <= t_out) & (t_in < best_t[sel])
        if not np.any(hit):
            continue
        idx = tuple(i[hit] for i in np.nonzero(sel))
        t = t_in[hit]
        best_t[idx] = t
        hit_any[idx] = True
        out_x[idx] = cx + t * dx[hit]
        out_y[idx] = cy + t * dy[hit]
        is_wall = (tu_in[hit] > t_roof) | (tv_in[hit] > t_roof)  # a side slab entered after the roof's height
        wall[idx] = is_wall
        if np.any(is_wall):
            # which wall: the slab that was entered last, and from which side
            along_u = tu_in[hit] >= tv_in[hit]
            face = np.where(along_u, np.where(du[hit] < 0, 0, 1), np.where(dv[hit] < 0, 2, 3))
            s = np.where(along_u, ov + t * dv[hit], ou + t * du[hit]) * gsd_m  # along the wall, m
            z = zc * (1.0 - t)
            rgb = _facade(b, face, s, z)
            cur = wall_rgb[idx]
            cur[is_wall] = rgb[is_wall]
            wall_rgb[idx] = cur
    return TraceResult(out_x, out_y, wall, wall_rgb[wall], hit_any)


def _candidates(b: Building, cx: float, cy: float, zc: float, gx: np.ndarray,
                image_px: tuple[np.ndarray, np.ndarray, np.ndarray] | None) -> np.ndarray | None:
    """Boolean mask of the rays that may hit ``b`` (None: none), from its image bounding box."""
    if image_px is None:
        return np.ones(gx.shape, bool)
    px, py, img_H_world = image_px
    poly = b.polygon()
    # a point at height h over X projects where the ground point C + (X - C) zc / (zc - h) does
    k = zc / (zc - b.height_m)
    pts = np.concatenate([poly, np.array([cx, cy]) + (poly - [cx, cy]) * k])
    q = np.c_[pts, np.ones(len(pts))] @ np.asarray(img_H_world, float).T
    if np.any(q[:, 2] <= 0):
        return np.ones(gx.shape, bool)  # behind the camera's horizon: test every ray
    q = q[:, :2] / q[:, 2:3]
    (x0, y0), (x1, y1) = q.min(axis=0) - 1.0, q.max(axis=0) + 1.0
    sel = (px >= x0) & (px <= x1) & (py >= y0) & (py <= y1)
    return sel if np.any(sel) else None


def _facade(b: Building, face: np.ndarray, s_m: np.ndarray, z_m: np.ndarray) -> np.ndarray:
    """(N, 3) float32 RGB of the walls at along-wall position ``s_m`` and height ``z_m``: the facade colour,
    shaded by the face, with dark windows in the middle of each bay and storey (ground floor too)."""
    shade = np.asarray(WALL_SHADE, np.float32)[face]
    fz = np.mod(z_m, FLOOR_M) / FLOOR_M
    fs = np.mod(s_m, BAY_M) / BAY_M
    window = (fz > 0.35) & (fz < 0.8) & (fs > 0.25) & (fs < 0.75)
    shade = shade * np.where(window, 0.4, 1.0).astype(np.float32)
    return np.asarray(b.facade, np.float32)[None, :] * shade[:, None]


def building_view_mask(buildings: list[Building], world_px_H_frame: np.ndarray, camera_xy_px: np.ndarray,
                       camera_height_m: float, size: tuple[int, int], gsd_m: float) -> np.ndarray:
    """bool (height, width): the frame pixels whose centre sees a building (roof or wall)."""
    w, h = size
    px, py = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    H = np.asarray(world_px_H_frame, float)
    den = H[2, 0] * px + H[2, 1] * py + H[2, 2]
    gx = (H[0, 0] * px + H[0, 1] * py + H[0, 2]) / den
    gy = (H[1, 0] * px + H[1, 1] * py + H[1, 2]) / den
    return trace(buildings, camera_xy_px, camera_height_m, gx, gy, gsd_m, (px, py, np.linalg.inv(H))).building
