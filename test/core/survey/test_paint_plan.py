"""The survey's paint plan: stills painted only where they can matter leave the best-view
composite and the coverage as painting every still everywhere does."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.mosaic import CanvasError, TiledCanvas
from srmosaic_ros.core.survey.paint_plan import tiles_to_paint

W, H = 320, 240  # frame size
T = 32  # tile size: a frame spans 10 x 7.5 tiles, as a 12 MP still does 256 px tiles


def lawnmower(legs: int = 4, per_leg: int = 7, seed: int = 0) -> list[np.ndarray]:
    """mosaic_H_frame of a small lawnmower: stills every 80 px along legs 100 px apart (75 % forward
    and 58 % side overlap), each turned by up to 8 deg and scaled by up to 10 %."""
    rng = np.random.default_rng(seed)
    out = []
    for leg in range(legs):
        for i in range(per_leg):
            x = 200.0 + 80.0 * (i if leg % 2 == 0 else per_leg - 1 - i)
            y = 200.0 + 100.0 * leg
            a = np.radians(rng.uniform(-8, 8))
            s = rng.uniform(0.9, 1.1)
            R = np.array([[s * np.cos(a), -s * np.sin(a), 0], [s * np.sin(a), s * np.cos(a), 0], [0, 0, 1.0]])
            out.append(np.array([[1.0, 0, x], [0, 1, y], [0, 0, 1]]) @ R
                       @ np.array([[1.0, 0, -(W - 1) / 2], [0, 1, -(H - 1) / 2], [0, 0, 1]]))
    return out


def frames(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(1)
    return [cv2.GaussianBlur(rng.random((H, W, 3)).astype(np.float32), (0, 0), 1.5) for _ in range(n)]


def paint(Hs: list[np.ndarray], images: list[np.ndarray], tiles: list | None) -> TiledCanvas:
    c = TiledCanvas(3, tile_size=T, blend='multiband')
    for k, (Hk, img) in enumerate(zip(Hs, images)):
        c.paint(img, Hk, tiles=None if tiles is None else tiles[k])
    return c


def test_planned_painting_keeps_the_winners_and_the_coverage() -> None:
    Hs = lawnmower()
    images = frames(len(Hs))
    plan = tiles_to_paint(Hs, [(W, H)] * len(Hs), T, rank=2)
    painted = sum(len(p) for p in plan.tiles)
    assert painted < 0.75 * plan.touched  # the plan leaves out a good part (a small survey: much edge)
    full, planned = paint(Hs, images, None), paint(Hs, images, plan.tiles)
    region = full.bounds()
    assert planned.bounds() == region
    lab_full, lab_plan = full.labels(region), planned.labels(region)
    cov_full, cov_plan = lab_full >= 0, lab_plan >= 0
    # no hole: what painting everything covers, the plan covers too, but for rounding at the very edge
    inner = cv2.erode(cov_full.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert cov_plan[inner].all()
    assert (cov_plan & ~cov_full).sum() <= 0.001 * cov_full.sum()
    # the same still wins each pixel (eq. 4.7), but for ties at the seams
    same = (lab_full == lab_plan)[inner]
    assert same.mean() > 0.998
    img_full, _ = full.render(region)
    img_plan, _ = planned.render(region)
    err = np.abs(img_full - img_plan)[inner]
    assert np.median(err) < 0.01  # only the feather average under the coarsest band changes


def test_every_still_ranked_paints_every_tile_it_touches() -> None:
    Hs = lawnmower(legs=2, per_leg=4)
    plan = tiles_to_paint(Hs, [(W, H)] * len(Hs), T, rank=len(Hs))
    c = TiledCanvas(3, tile_size=T, blend='multiband')
    for k, Hk in enumerate(Hs):
        touched = set(c.paint(frames(1)[0], Hk).touched_tiles)
        # the tiles the canvas touches by itself (and at most a few its footprint's edge only grazes)
        assert touched <= plan.tiles[k]
        assert len(plan.tiles[k] - touched) <= 0.03 * len(touched)
    assert sum(len(p) for p in plan.tiles) == plan.touched


def test_a_still_alone_over_ground_is_painted_there() -> None:
    # a still far out on its own ranks first wherever it is: all its tiles
    Hs = lawnmower(legs=1, per_leg=5) + [np.array([[1.0, 0, 1500], [0, 1, 100], [0, 0, 1]])]
    plan = tiles_to_paint(Hs, [(W, H)] * len(Hs), T, rank=1)
    c = TiledCanvas(3, tile_size=T, blend='multiband')
    assert set(c.paint(frames(1)[0], Hs[-1]).touched_tiles) <= plan.tiles[-1]


def test_bad_plans_are_refused() -> None:
    Hs = lawnmower(legs=1, per_leg=2)
    with pytest.raises(ValueError, match='rank'):
        tiles_to_paint(Hs, [(W, H)] * 2, T, rank=0)
    with pytest.raises(ValueError, match='profile'):
        tiles_to_paint(Hs, [(W, H)] * 2, T, profile='gauss')
    with pytest.raises(ValueError, match='2 homographies for 1 sizes'):
        tiles_to_paint(Hs, [(W, H)], T)
    assert tiles_to_paint([], [], T).tiles == []


def test_canvas_paints_only_the_tiles_given() -> None:
    c = TiledCanvas(3, tile_size=T, blend='multiband')
    Hk = np.array([[1.0, 0, 10], [0, 1, 10], [0, 0, 1]])
    res = c.paint(frames(1)[0], Hk, tiles=[(1, 1), (2, 1), (99, 99)])
    assert set(res.touched_tiles) == {(1, 1), (2, 1)}
    assert (c.labels((0, 0, 32, 32)) == -1).all()
    assert (c.labels((32, 32, 64, 64)) == 0).all()
    empty = c.paint(frames(1)[0], Hk, tiles=set())
    assert empty.touched_tiles == () and empty.frame_index == 1 and c.frames_painted == 2
    with pytest.raises(CanvasError, match='pairs of integers'):
        c.paint(frames(1)[0], Hk, tiles=[(1, 'a')])
    # a mapping: the pixels (x0, y0, x1, y1) painted in each tile
    d = TiledCanvas(3, tile_size=T, blend='multiband')
    res = d.paint(frames(1)[0], Hk, tiles={(1, 1): (40, 36, 50, 60), (3, 1): (96, 32, 128, 64), (5, 5): (0, 0, 1, 1)})
    assert set(res.touched_tiles) == {(1, 1), (3, 1)}
    lab = d.labels((0, 0, 160, 96))
    want = np.zeros(lab.shape, bool)
    want[36:60, 40:50] = want[32:64, 96:128] = True
    assert ((lab == 0) == want).all()
    with pytest.raises(CanvasError, match='x0, y0, x1, y1'):
        d.paint(frames(1)[0], Hk, tiles={(1, 1): (1, 2, 3)})
