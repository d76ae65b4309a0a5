"""Buildings on the simulated ground (srmosaic_ros/sim/buildings.py): boxes traced by the renderer, so
frames disagree by parallax as real ones do, with their truth (footprints, heights, the orthophoto)."""
from __future__ import annotations

import argparse
import math

import cv2
import numpy as np
import pytest

from srmosaic_ros.errors import ConfigError
from srmosaic_ros.sim import SimConfig, load_truth, simulate
from srmosaic_ros.sim.buildings import Building, footprint_mask, make_buildings, paint_roofs, trace
from srmosaic_ros.sim.cli import add_arguments, config_from_args
from srmosaic_ros.sim.ortho_error import ortho_in_plane, region_errors, region_masks
from srmosaic_ros.sim.render import Relief, render_frame
from srmosaic_ros.sim.truth import save_truth

GSD = 0.1
ROOF, FACADE = (200, 30, 30), (40, 60, 200)


def _nadir(cam_xy: tuple[float, float], height_m: float, f_px: float, size: tuple[int, int]) -> np.ndarray:
    """world_px_H_img of a nadir camera (image x = world x, image y = world y) at ``cam_xy`` world px."""
    w, h = size
    s = height_m / f_px / GSD  # world px per image px on the ground
    return np.array([[s, 0.0, cam_xy[0] - s * (w - 1) / 2.0], [0.0, s, cam_xy[1] - s * (h - 1) / 2.0], [0.0, 0.0, 1.0]])


def _inside(poly: np.ndarray, size: tuple[int, int], erode: int) -> np.ndarray:
    mask = np.zeros((size[1], size[0]), np.uint8)
    cv2.fillConvexPoly(mask, np.round(poly * 16).astype(np.int32), 1, shift=4)
    if erode > 0:
        mask = cv2.erode(mask, np.ones((3, 3), np.uint8), iterations=erode)
    else:
        mask = cv2.dilate(mask, np.ones((3, 3), np.uint8), iterations=-erode)
    return mask > 0


def test_a_roof_is_where_its_height_puts_it_and_walls_show_between() -> None:
    """Nadir camera 60 m above, a 20 m tall box 30 m off the nadir: the roof is the footprint scaled by
    Z / (Z - h) about the nadir point (relief displacement), the walls fill the band between the
    footprint and the roof on the side away from the nadir, the ground is grey elsewhere."""
    world = np.full((1200, 1200, 3), 128, np.uint8)
    b = Building((700.0, 600.0), 150.0, 100.0, 0.3, 20.0, ROOF, FACADE, 1)
    world = paint_roofs(world, [b], GSD)
    cam, size, f = (400.0, 600.0), (320, 240), 200.0
    H = _nadir(cam, 60.0, f, size)
    img = render_frame(world, H, size, psf_sigma_px=0.3, relief=Relief([b], cam, 60.0, GSD))
    img_H_world = np.linalg.inv(H)
    base = cv2.perspectiveTransform(b.polygon()[None], img_H_world)[0]
    k = 60.0 / (60.0 - 20.0)
    roof = cv2.perspectiveTransform((np.asarray(cam) + (b.polygon() - cam) * k)[None], img_H_world)[0]
    on_roof = _inside(roof, size, 2)
    assert on_roof.sum() > 2000
    red = (img[..., 0] > 150) & (img[..., 2] < 80)
    assert red[on_roof].mean() > 0.97
    hull = cv2.convexHull(np.concatenate([base, roof]).astype(np.float32))[:, 0]
    outside = ~_inside(hull, size, -2)  # the grey ground
    assert np.abs(img[outside] - 128).max() < 3
    walls = _inside(hull, size, 2) & ~_inside(roof, size, -2)
    blue = img[..., 2] > img[..., 0] + 20
    assert walls.sum() > 300 and blue[walls].mean() > 0.9  # facade colour (its windows darker, still blue)
    # without the relief the same world renders the roof flat on its footprint
    flat = render_frame(world, H, size, psf_sigma_px=0.3)
    red_flat = (flat[..., 0] > 150) & (flat[..., 2] < 80)
    assert red_flat[_inside(base, size, 2)].mean() > 0.97 and not red_flat[_inside(roof, size, -2) & ~_inside(base, size, -2)].any()


def test_trace_hits_the_nearest_box_and_misses_beside_it() -> None:
    """Two boxes on one line of sight: the ray stops at the first; a ray beside both reaches the ground."""
    near = Building((100.0, 0.0), 20.0, 20.0, 0.0, 30.0, ROOF, FACADE, 1)
    far = Building((200.0, 0.0), 20.0, 20.0, 0.0, 10.0, ROOF, FACADE, 2)
    cam = np.array([0.0, 0.0])
    gx, gy = np.array([260.0, 260.0]), np.array([0.0, 50.0])
    res = trace([far, near], cam, 50.0, gx, gy, GSD)
    # ray 0: at x = 90 (the near box's wall) it is at z = 50 (1 - 90/260) = 32.7 m, over the 30 m roof;
    # it enters the roof's height at t = 0.4 (x = 104): a roof hit
    assert res.building[0] and not res.wall[0] and res.x[0] == pytest.approx(104.0)
    assert not res.building[1] and res.x[1] == 260.0 and res.y[1] == 50.0


def test_flights_with_buildings_keep_their_truth(tmp_path) -> None:
    cfg = SimConfig(frames=3, width=160, height=120, buildings=6, building_height_m=12.0, vehicles=4, seed=2,
                    rate_hz=2.0)
    flight = simulate(cfg)
    truth = flight.truth
    assert 1 <= len(truth.buildings) <= 6
    assert all(3.6 <= b.height_m <= 12.0 for b in truth.buildings)
    # footprints do not overlap, and cars never drive through a house
    masks = [footprint_mask([b], truth.world_size_px) for b in truth.buildings]
    assert not np.any(np.sum(masks, axis=0) > 1)
    for k in range(3):
        assert not np.any(truth.vehicle_mask(k) & truth.building_mask(k))
    # the frames differ from the flat flight only where the truth says a building is seen
    flat = simulate(cfg.replace(buildings=0))
    for k in range(3):
        seen = truth.building_mask(k)
        diff = np.abs(flight.frames[k].image.astype(int) - flat.frames[k].image.astype(int)).max(axis=2)
        near = cv2.dilate(seen.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        assert not (diff[~near] > 12).any()
    save_truth(truth, tmp_path / 'ground_truth.json')
    back = load_truth(tmp_path / 'ground_truth.json')
    assert back.buildings == truth.buildings
    assert np.array_equal(back.building_mask(1), truth.building_mask(1))


def test_building_options_are_checked_and_reach_the_cli() -> None:
    with pytest.raises(ConfigError, match='building_height_m 90.*camera flies above the roofs'):
        SimConfig(buildings=3, building_height_m=90.0)
    with pytest.raises(ConfigError, match='buildings -1'):
        SimConfig(buildings=-1)
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    cfg = config_from_args(parser.parse_args(['--buildings', '7', '--building-height', '20', '--out', 'x']))
    assert cfg.buildings == 7 and cfg.building_height_m == 20.0


def test_make_buildings_keeps_clear_of_tracks() -> None:
    rng = np.random.default_rng(0)
    track = (np.array([0.0, 500.0]), np.array([1000.0, 500.0]))
    placed = make_buildings(30, 15.0, GSD, (0.0, 0.0, 1000.0, 1000.0), rng, keep_clear=[track], clearance_px=20.0)
    assert len(placed) >= 5
    for b in placed:
        assert abs(b.centre_px[1] - 500.0) > 0.5 * math.hypot(b.length_px, b.width_px) + 20.0 - 1e-9


def test_region_errors_read_the_orthophoto_in_the_plane() -> None:
    """A plane at 2 world px per pixel: the orthophoto sampled in it scores far higher against itself
    than a copy shifted by one pixel, region by region; regions split the plane."""
    world = cv2.GaussianBlur(np.random.default_rng(1).integers(0, 255, (600, 600, 3), dtype=np.uint8), (0, 0), 3)
    b = Building((300.0, 300.0), 80.0, 60.0, 0.0, 10.0, ROOF, FACADE, 1)
    ortho = paint_roofs(world, [b], GSD)
    H = np.array([[2.0, 0.0, 50.0], [0.0, 2.0, 50.0], [0.0, 0.0, 1.0]])
    truth = ortho_in_plane(ortho, H, (200, 200))
    masks = region_masks([b], H, (200, 200), GSD, 5.0)
    assert sum(m.astype(int) for m in masks.values()).min() == 1  # every pixel in exactly one region
    assert masks['roofs'].sum() == pytest.approx(40 * 30, rel=0.1)  # 80 x 60 world px at 2 per pixel
    covered = np.ones((200, 200), bool)
    same = region_errors(truth, covered, truth, masks)
    shifted = region_errors(np.roll(truth, 1, axis=1), covered, truth, masks)
    for r in ('open', 'near', 'roofs'):
        assert same.psnr_db[r] > 100 and shifted.psnr_db[r] < 45
