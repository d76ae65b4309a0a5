"""Best-view compositing, the far-field cut and anti-aliased minification of the mosaic canvas
(srmosaic_ros/core/mosaic/best_view.py, minify.py) on real aerial texture with known homographies."""
from __future__ import annotations

import pickle

import cv2
import numpy as np
import pytest

from imagery import view, world_rgb
from srmosaic_ros.core.mosaic import CanvasError, TiledCanvas
from srmosaic_ros.core.mosaic.best_view import clip_depth, clipped_polygon
from srmosaic_ros.core.mosaic.minify import minify_level

W, H = 240, 180


def translation(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def frame_at(x: float, y: float, *, seed: int = 0) -> np.ndarray:
    """float32 (H, W, 3) view of the world with frame pixel (u, v) at world (x + u, y + v), noise 2 grey levels."""
    return view(translation(x, y), W, H, noise=2.0, seed=seed).astype(np.float32) / 255.0


def gradient_energy(img: np.ndarray) -> float:
    g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    return float(np.mean(gx * gx + gy * gy))


def sweep(blend: str, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A pass of 9 frames 20 px apart in x (frame k sees world x 100 + 20 k), frame k painted
    ``offsets[k]`` (dx, dy) px off where it belongs (misregistrations). Returns the rendered mosaic
    over (8, 8, 392, 172) and the noise-free truth there, float32 (164, 384, 3)."""
    canvas = TiledCanvas(3, tile_size=64, blend=blend)
    for k in range(9):
        canvas.paint(frame_at(100.0 + 20 * k, 200.0, seed=k), translation(20.0 * k + offsets[k][0], offsets[k][1]))
    image, covered = canvas.render((8, 8, 392, 172))
    assert covered.all()
    return image, view(translation(108.0, 208.0), 384, 164).astype(np.float32) / 255.0


@pytest.mark.parametrize(('case', 'feather_at_most', 'best_at_least'), [('one frame 6 px off', 0.95, 0.98),
                                                                        ('every frame 1.5 px off', 0.7, 0.8)])
def test_misregistered_frames_do_not_smear_the_best_view_mosaic(case: str, feather_at_most: float,
                                                                best_at_least: float) -> None:
    """Misregistered frames: the feather average of the overlapping frames ghosts every edge they
    cover; best view shows each ground pixel from one frame (two near a seam), so it stays as sharp
    as the frames (gradient energy over the noise-free truth's)."""
    # measured: one frame 6 px off: feather 0.917, multiband 0.977, best view 1.005; every frame
    # N(0, 1.5 px) off: feather 0.49, multiband 0.82, best view 0.87 (cells 20 px wide: seams, where two
    # misaligned frames meet, are never far); aligned: best view 1.016 (the frames' noise adds energy)
    offsets = np.zeros((9, 2))
    if case.startswith('one'):
        offsets[4, 0] = 6.0
    else:
        offsets = np.random.default_rng(3).normal(0.0, 1.5, (9, 2))
    feather, truth = sweep('feather', offsets)
    best, _ = sweep('bestview', offsets)
    e_truth = gradient_energy(truth)
    assert gradient_energy(feather) < feather_at_most * e_truth
    assert gradient_energy(best) > best_at_least * e_truth


def test_newer_frames_win_and_old_scores_never_decay() -> None:
    """Two views of the same ground with the same quality: the newer one is shown; with no
    preference for recency (recency_frames 0) the first stays (ties keep the earlier frame)."""
    a, b = frame_at(100, 200, seed=1), np.clip(frame_at(100, 200, seed=2) + 0.1, 0, 1)
    for recency, winner in ((90, b), (0, a)):
        canvas = TiledCanvas(3, tile_size=64, blend='bestview', recency_frames=recency)
        canvas.paint(a, np.eye(3))
        canvas.paint(b, np.eye(3))
        image, _ = canvas.render((0, 0, W, H))
        np.testing.assert_allclose(image[2:-2, 2:-2], winner[2:-2, 2:-2], atol=1e-5)


def test_a_closer_view_wins_over_a_coarser_newer_one() -> None:
    """Resolution on the ground: a frame zoomed out 3x (each pixel covering 3x3 mosaic pixels) loses
    to a finer view of the same ground painted one frame earlier, where both see it."""
    fine = frame_at(100, 200, seed=1)
    coarse = cv2.resize(view(translation(40, 140), 3 * W, 3 * H), (W, H), interpolation=cv2.INTER_AREA)
    canvas = TiledCanvas(3, tile_size=64, blend='bestview', recency_frames=90)
    canvas.paint(fine, translation(60, 60))
    canvas.paint(coarse.astype(np.float32) / 255.0, translation(0, 0) @ np.diag([3.0, 3.0, 1.0]))
    image, _ = canvas.render((60, 60, 60 + W, 60 + H))
    coarse_there = cv2.warpPerspective(coarse, np.linalg.inv(translation(60, 60)) @ np.diag([3.0, 3.0, 1.0]), (W, H),
                                       flags=cv2.INTER_LINEAR).astype(np.float32) / 255.0

    def rms(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.sqrt(np.mean((a[40:-40, 40:-40] - b[40:-40, 40:-40]) ** 2)))
    assert rms(image, fine) < 0.2 * rms(image, coarse_there), (rms(image, fine), rms(image, coarse_there))


def test_seams_blend_two_frames_only() -> None:
    """Two frames 60 px apart whose brightness differs by 0.1: away from the seam each shows its own
    pixels exactly; across it the step is spread (no jump of 0.1 between neighbouring pixels)."""
    a = frame_at(100, 200, seed=1)
    b = np.clip(frame_at(160, 200, seed=2) + 0.1, 0, 1)
    canvas = TiledCanvas(3, tile_size=64, blend='bestview', recency_frames=0)
    canvas.paint(a, np.eye(3))
    canvas.paint(b, translation(60, 0))
    image, _ = canvas.render((0, 0, 300, H))
    np.testing.assert_allclose(image[:, 5:30], a[:, 5:30], atol=5e-3)
    np.testing.assert_allclose(image[:, 270:295], b[:, 210:235], atol=5e-3)
    mid = image[40:140, 120:180].mean(axis=(0, 2))
    assert np.abs(np.diff(mid)).max() < 0.03


def test_far_field_and_sky_are_cut_not_refused() -> None:
    """A frame whose view reaches the horizon: refused without the cut; with max_stretch 4 the part
    of it more than 4x coarser than its finest pixel is left out (the kept part lies below a straight
    line of the frame) and the rest is painted."""
    frame = frame_at(100, 200)
    h = np.array([[1.0, 0, 0], [0, 1, 0], [0, -0.0062, 1]])  # depth 0 at frame row 161: the rows below it beyond the horizon
    with pytest.raises(CanvasError, match='horizon'):
        TiledCanvas(3, tile_size=64).paint(frame, h)
    canvas = TiledCanvas(3, tile_size=64, max_stretch=4.0, blend='bestview')
    d_min = clip_depth(h, W, H, 4.0)
    assert d_min is not None and 0 < d_min < 1
    # kept: depth 1 - 0.0062 v >= d_min, i.e. the rows above v_cut
    v_cut = (1.0 - d_min) / 0.0062
    poly = clipped_polygon(h, np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]]), d_min)
    assert np.allclose(sorted(poly[:, 1])[-2:], [v_cut, v_cut])
    result = canvas.paint(frame, h)
    x0, y0, x1, y1 = result.bbox
    assert y1 - y0 < 4 * H and x1 - x0 < 4 * W
    image, covered = canvas.render()
    assert covered.any()
    # every painted mosaic pixel comes from a kept frame row
    ys = np.nonzero(covered)[0] + y0
    v_of_y = ys / (1.0 + 0.0062 * ys)  # inverse of y = v / (1 - 0.0062 v)
    assert v_of_y.max() < v_cut + 1.5
    with pytest.raises(CanvasError, match='max_stretch'):
        TiledCanvas(3, max_stretch=0.5)


def test_a_shrinking_frame_is_reduced_before_it_is_warped() -> None:
    """A frame painted 6x smaller (a zoom out): reduced by pyramid levels first, its mosaic pixels
    are local means of the frame; point samples (warpPerspective alone) would alias: on white noise,
    every frequency, they keep the noise's whole variance."""
    frame = np.random.default_rng(0).random((H, W, 3)).astype(np.float32)
    m = np.diag([1 / 6, 1 / 6, 1.0])
    assert minify_level(m, W, H) == 2  # 6x: two pyrDown levels leave a 1.5x reduction to the warp
    assert minify_level(np.diag([0.6, 0.6, 1.0]), W, H) == 0
    canvas = TiledCanvas(3, tile_size=64, blend='feather')
    canvas.paint(frame, m)
    image, _ = canvas.render((2, 2, 38, 28))
    point_sampled = cv2.warpPerspective(frame, m, (W // 6, H // 6), flags=cv2.INTER_LINEAR)[2:28, 2:38]
    # measured: std 0.058 reduced first, 0.28 point-sampled (the noise's own: 0.29)
    assert float(image.std()) < 0.3 * float(point_sampled.std()), (image.std(), point_sampled.std())
    assert abs(float(image.mean()) - 0.5) < 0.02


@pytest.mark.parametrize('bound', [0, 2])
def test_best_view_tiles_spill_pickle_and_preview(bound: int, tmp_path) -> None:
    """The best-view layout spills and pickles byte for byte, and previews the winners' pixels."""
    canvas = TiledCanvas(3, tile_size=64, blend='bestview', max_tiles_in_memory=bound, spill_dir=tmp_path)
    for k in range(5):
        canvas.paint(frame_at(100 + 30 * k, 200, seed=k), translation(30.0 * k, 0.0))
    image, covered = canvas.render()
    again = pickle.loads(pickle.dumps(canvas))
    image2, covered2 = again.render()
    np.testing.assert_array_equal(image, image2)
    np.testing.assert_array_equal(covered, covered2)
    preview, pcov = canvas.render_preview(64)
    assert pcov.all() and preview.shape[1] <= 64 * 2
    small = cv2.resize(image, (preview.shape[1], preview.shape[0]), interpolation=cv2.INTER_AREA)
    assert float(np.abs(small - preview).mean()) < 0.03
    assert canvas.memory_bytes <= max(bound, len(canvas.tile_keys())) * 64 * 64 * 4 * (3 * 3 + 5)
    world_rgb()  # the imagery module's cache is warm for the other tests


def test_consensus_averages_aligned_frames() -> None:
    """mosaic.agree: nine aligned noisy frames are averaged where they agree with the winner, so the
    noise goes down as in a feather blend (off by default: on this low-contrast texture a frame 6 px
    off agrees too often, and the sweep's sharpness falls from 1.005 to 0.914, feather's 0.917)."""
    # measured: aligned, PSNR 42.1 dB one frame per pixel, 46.2 with agree 0.02 (feather 46.2)
    def run(agree: float, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        canvas = TiledCanvas(3, tile_size=64, blend='bestview', agree=agree)
        for k in range(9):
            canvas.paint(frame_at(100.0 + 20 * k, 200.0, seed=k), translation(20.0 * k + offsets[k][0], offsets[k][1]))
        image, _ = canvas.render((8, 8, 392, 172))
        return image, view(translation(108.0, 208.0), 384, 164).astype(np.float32) / 255.0

    def psnr(a: np.ndarray, b: np.ndarray) -> float:
        return float(10 * np.log10(1.0 / np.mean((a - b) ** 2)))

    single, truth = run(0.0, np.zeros((9, 2)))
    averaged, _ = run(0.02, np.zeros((9, 2)))
    assert psnr(averaged, truth) > psnr(single, truth) + 3.0
    with pytest.raises(CanvasError, match='agree'):
        TiledCanvas(3, blend='bestview', agree=-0.1)


def test_the_moving_vote_keeps_a_passing_car_out() -> None:
    """mosaic.moving: a car (a bright 12 x 12 px square) seen only by the newest of nine aligned
    frames over one spot wins that spot in plain best view (the newest frame scores highest); the
    vote sees the newest frame disagree with the pixels' background (the median of the frames
    before it) and keeps it out, while the static ground stays the newest frame's; moving_counts
    marks the car's ground and nothing else."""
    counts = {}

    def run(moving: float) -> tuple[np.ndarray, np.ndarray]:
        canvas = TiledCanvas(3, tile_size=64, blend='bestview', moving=moving)
        for k in range(9):
            img = frame_at(100.0 + 4 * k, 200.0, seed=k)
            if k == 8:
                img[84:96, 114:126] = 1.0  # the car, at the centre of the newest frame, where it sees best
            canvas.paint(img, translation(4.0 * k, 0.0))
        image, _ = canvas.render((120, 70, 160, 110))
        counts[moving] = canvas.moving_counts()
        assert canvas.tracks_moving == (moving > 0)
        return image, view(translation(220.0, 270.0), 40, 40).astype(np.float32) / 255.0

    def car_px(image: np.ndarray, truth: np.ndarray) -> int:
        return int((np.abs(image - truth).max(axis=-1) > 0.25).sum())

    plain, truth = run(0.0)
    voted, _ = run(0.1)
    assert car_px(plain, truth) > 100  # the car is in the plain mosaic
    assert car_px(voted, truth) < 5
    car = np.zeros(counts[0.1].shape, bool)
    car[84:96, 146:158] = True  # the car's mosaic pixels (frame 8 is painted 32 px on)
    assert (counts[0.1][car] == 1).all()  # one frame kept out there
    near = np.zeros(car.shape, bool)
    near[80:100, 142:162] = True  # and nothing beyond the outline grown twice by the 5 x 5 box (detection, dilation)
    assert not counts[0.1][~near].any()
    assert not counts[0.0].any()
    with pytest.raises(CanvasError, match='moving'):
        TiledCanvas(3, blend='bestview', moving=1.5)
    with pytest.raises(CanvasError, match='moving_history'):
        TiledCanvas(3, blend='bestview', moving=0.1, moving_history=4)


def test_a_car_that_won_its_spot_is_replaced_once_later_frames_agree_on_the_ground() -> None:
    """A car in the first of nine aligned frames, at its centre, where that frame sees best: plain best
    view keeps it (no later frame scores higher there); with the vote, the third frame over the spot
    makes the median (car, ground, ground) the ground, finds the winner off it and replaces it."""
    def run(moving: float) -> tuple[np.ndarray, np.ndarray]:
        canvas = TiledCanvas(3, tile_size=64, blend='bestview', moving=moving, recency_frames=0)
        for k in range(9):
            img = frame_at(100.0 + 4 * k, 200.0, seed=k)
            if k == 0:
                img[84:96, 114:126] = (0.9, 0.1, 0.1)  # a red car
            canvas.paint(img, translation(4.0 * k, 0.0))
        image, _ = canvas.render((104, 80, 136, 100))
        return image, view(translation(204.0, 280.0), 32, 20).astype(np.float32) / 255.0

    def car_px(image: np.ndarray, truth: np.ndarray) -> int:
        return int((np.abs(image - truth).max(axis=-1) > 0.25).sum())

    plain, truth = run(0.0)
    voted, _ = run(0.05)
    assert car_px(plain, truth) > 60  # the half of the car nearer frame 0's centre than frame 1's
    assert car_px(voted, truth) == 0


def test_the_vote_on_moving_objects_spills_and_pickles(tmp_path) -> None:
    """The history and counts of the vote travel with the tiles: spilled to disk and pickled, the
    canvas renders and counts the same, and goes on voting the same."""
    def paint(canvas: TiledCanvas, ks: range) -> None:
        for k in ks:
            img = frame_at(100 + 30 * k, 200, seed=k)
            img[80:90, 100:112] = 1.0  # a car at every frame's centre: it moves with the camera
            canvas.paint(img, translation(30.0 * k, 0.0))

    kept = TiledCanvas(3, tile_size=64, blend='bestview', moving=0.05)
    spilled = TiledCanvas(3, tile_size=64, blend='bestview', moving=0.05, max_tiles_in_memory=1, spill_dir=tmp_path)
    for canvas in (kept, spilled):
        paint(canvas, range(4))
    spilled = pickle.loads(pickle.dumps(spilled))
    for canvas in (kept, spilled):
        paint(canvas, range(4, 7))
    np.testing.assert_array_equal(kept.render()[0], spilled.render()[0])
    np.testing.assert_array_equal(kept.moving_counts(), spilled.moving_counts())
    assert kept.moving_counts().any()


def test_the_background_history_keeps_turning_after_255_samples() -> None:
    """The sample count saturates at 255 but the ring of samples goes on: ground that changes for good
    after 290 frames (a parked car leaving) becomes the background, and the mosaic shows it."""
    canvas = TiledCanvas(1, tile_size=16, blend='bestview', moving=0.05, moving_history=3)
    for k in range(300):
        canvas.paint(np.full((8, 8), 0.2 if k >= 290 else 0.5, np.float32), np.eye(3))
    tile = canvas._store.peek((0, 0))
    assert tile.hist_n[3, 3] >= 250
    assert (tile.hist[:, 3, 3] == 51).all()  # 0.2 * 255
    assert canvas.render((0, 0, 8, 8))[0][3, 3] == pytest.approx(0.2)
