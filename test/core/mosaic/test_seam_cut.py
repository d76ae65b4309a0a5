"""Seams where frames agree (core/mosaic/seam_cut.py): the graph cut between a new frame and the
best-view winners under it."""
from __future__ import annotations

import numpy as np
import pytest

from imagery import translation, view
from srmosaic_ros.core.mosaic import TiledCanvas
from srmosaic_ros.core.mosaic.config import MosaicConfig
from srmosaic_ros.core.mosaic.seam_cut import SEAM_SLACK, combine, cut_nodes, expand

W, H = 240, 180


def frame_at(x: float, y: float, *, seed: int = 0) -> np.ndarray:
    """float32 (H, W, 3) view of the world with frame pixel (u, v) at world (x + u, y + v), noise 2 grey levels."""
    return view(translation(x, y), W, H, noise=2.0, seed=seed).astype(np.float32) / 255.0


def _two_frames_and_a_car(seams: str, blend: str) -> tuple[np.ndarray, np.ndarray]:
    """Frame 0 at mosaic x 0, frame 1 at x 60 with a 30 x 30 px car at mosaic (135..165, 75..105),
    across the line where their view scores cross (x 150). Returns the labels and the render over
    the car."""
    a = frame_at(100, 200, seed=1)
    b = frame_at(160, 200, seed=2)
    b[75:105, 75:105] = (0.9, 0.1, 0.1)  # the car, in frame 1's pixels (mosaic x - 60)
    canvas = TiledCanvas(3, tile_size=64, blend=blend, recency_frames=0, seams=seams)
    canvas.paint(a, np.eye(3))
    canvas.paint(b, translation(60, 0))
    labels = canvas.labels((0, 0, 300, H))
    image, _ = canvas.render((135, 75, 165, 105))
    return labels, image


@pytest.mark.parametrize('blend', ['bestview', 'multiband'])
def test_a_seam_is_moved_around_what_the_frames_disagree_on(blend: str) -> None:
    """By score the seam runs through the car (half of it shown); the cut takes the whole car from
    one frame (either: both cost the same), and away from the corridor the scores still decide."""
    def red(image: np.ndarray) -> float:
        return float(((image[..., 0] > 0.6) & (image[..., 1] < 0.3)).mean())

    by_score, half = _two_frames_and_a_car('score', blend)
    car = (slice(75, 105), slice(135, 165))
    assert 0.3 < (by_score[car] == 1).mean() < 0.7  # split by the straight seam
    assert blend != 'bestview' or 0.3 < red(half) < 0.6
    cut, image = _two_frames_and_a_car('cut', blend)
    share = (cut[car] == 1).mean()
    assert share in (0.0, 1.0), share
    if blend == 'bestview':  # multiband takes its low bands from the average of every frame (Table 2)
        assert red(image) > 0.9 if share == 1.0 else red(image) < 0.05  # the car whole, or not at all
    # each frame keeps the ground only it sees well: frame 0 left of x 90, frame 1 right of 210
    assert (cut[:, 5:90] == 0).all() and (cut[:, 210:295] == 1).all()
    # the seam is no longer the score's straight line elsewhere either, but stays near it
    rows = [np.flatnonzero(np.diff(cut[y, :])) for y in range(10, H - 10, 20)]
    assert all(len(r) >= 1 and 90 < r[0] < 210 for r in rows), rows


def test_unseen_pixels_never_lead_unpainted_ones_always() -> None:
    """Frame 1 overlaps frame 0 by half and reaches over ground nobody painted: it takes all of that,
    and the cut never gives it a pixel outside its own footprint."""
    canvas = TiledCanvas(3, tile_size=64, blend='bestview', recency_frames=0, seams='cut')
    canvas.paint(frame_at(100, 200, seed=1), np.eye(3))
    canvas.paint(frame_at(220, 260, seed=2), translation(120, 60))
    labels = canvas.labels((0, 0, 360, 240))
    assert (labels[:60, :120] == 0).all()  # frame 0's alone (frame 1 does not see it)
    assert (labels[H + 1:, :] != 0).all() and (labels[:, W + 1:] != 0).all()  # frame 0 does not see it either
    assert (labels[H + 1:, 121:] == 1).all() and (labels[61:, W + 1:] == 1).all()  # only frame 1 painted it


def test_far_scores_leave_nothing_to_the_cut() -> None:
    """Blocks whose scores differ by more than SEAM_SLACK are not free: the scores decide."""
    rng = np.random.default_rng(0)
    best = rng.normal(0.0, 1.0, (30, 40))
    score = best + np.where(np.arange(40) < 20, -2.0, 2.0) * SEAM_SLACK
    free, take = cut_nodes(score, best, rng.random((30, 40, 3)), 4)
    assert not free.any() and not take.any()
    by_score = rng.random((120, 160)) < 0.5
    seen = rng.random((120, 160)) < 0.9
    np.testing.assert_array_equal(combine(by_score, seen, expand(free, 4, (120, 160)), expand(take, 4, (120, 160))), by_score)


def test_seams_setting_is_checked() -> None:
    with pytest.raises(ValueError, match=r'mosaic\.seams=.*must be one of cut, score'):
        MosaicConfig(seams='graphcut')
    with pytest.raises(ValueError, match='seams must be one of'):
        TiledCanvas(3, blend='bestview', seams='voronoi')
