"""Tests of the growing tiled mosaic canvas (srmosaic_ros.core.mosaic.canvas / blend)."""
from __future__ import annotations

import itertools
import pickle

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.mosaic import CanvasError, TiledCanvas, feather_weight
from srmosaic_ros.core.mosaic import canvas_reader as reader_mod
from srmosaic_ros.core.mosaic import resample
from srmosaic_ros.errors import SrMosaicError

BLENDS = ('feather', 'multiband', 'bestview')


def texture(h: int, w: int, c: int = 3, *, sigma: float = 2.0, seed: int = 0) -> np.ndarray:
    """Seeded smooth random texture, float32 (h, w, c) in [0.2, 0.8]."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w, c)).astype(np.float32), (0, 0), sigma).reshape(h, w, c)
    img = (img - img.min()) / (img.max() - img.min())
    return (0.2 + 0.6 * img).astype(np.float32)


def translation(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def rotation(deg: float, cx: float, cy: float, tx: float = 0.0, ty: float = 0.0) -> np.ndarray:
    """Rotation by deg about frame point (cx, cy), then translation (tx, ty)."""
    a = np.deg2rad(deg)
    r = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return translation(cx + tx, cy + ty) @ r @ translation(-cx, -cy)


def interior_mask(mosaic_h_frame: np.ndarray, region: tuple[int, int, int, int], w: int, h: int,
                  margin: float = 1.0) -> np.ndarray:
    """Bool (rh, rw): mosaic pixels whose frame point lies >= margin inside the pixel-centre hull."""
    x0, y0, x1, y1 = region
    xs, ys = np.meshgrid(np.arange(x0, x1, dtype=float), np.arange(y0, y1, dtype=float))
    p = np.stack([xs, ys, np.ones_like(xs)], -1) @ np.linalg.inv(mosaic_h_frame).T
    u, v = p[..., 0] / p[..., 2], p[..., 1] / p[..., 2]
    return (u >= margin) & (u <= w - 1 - margin) & (v >= margin) & (v <= h - 1 - margin)


def expected_tiles(bbox: tuple[int, int, int, int], t: int) -> set[tuple[int, int]]:
    x0, y0, x1, y1 = bbox
    return {(tx, ty) for ty in range(y0 // t, (y1 - 1) // t + 1) for tx in range(x0 // t, (x1 - 1) // t + 1)}


# ---------------------------------------------------------------- smoke, shapes, errors
@pytest.mark.parametrize('blend', BLENDS)
def test_empty_canvas(blend: str) -> None:
    c = TiledCanvas(3, tile_size=64, blend=blend)
    assert c.is_empty and c.bounds() == (0, 0, 0, 0) and c.tile_keys() == [] and c.memory_bytes == 0
    img, cov = c.render()
    assert img.shape == (0, 0, 3) and cov.shape == (0, 0)
    img, cov = c.render((-5, -5, 5, 5))
    assert img.shape == (10, 10, 3) and not cov.any() and (img == 0).all()


@pytest.mark.parametrize('blend', BLENDS)
@pytest.mark.parametrize('channels', [1, 3, 5])
def test_identity_reproduces_frame(blend: str, channels: int) -> None:
    frame = texture(70, 90, channels)
    c = TiledCanvas(channels, tile_size=32, blend=blend)
    res = c.paint(frame[:, :, 0] if channels == 1 else frame, np.eye(3))
    assert res.frame_index == 0 and res.bbox == (0, 0, 90, 70)
    assert c.bounds() == (0, 0, 90, 70)
    np.testing.assert_allclose(res.footprint_xy, [[-0.5, -0.5], [89.5, -0.5], [89.5, 69.5], [-0.5, 69.5]])
    out, cov = c.render()
    assert out.dtype == np.float32 and cov.dtype == bool and cov.all()
    assert out.shape == ((70, 90) if channels == 1 else (70, 90, channels))
    np.testing.assert_allclose(out.reshape(frame.shape), frame, atol=1e-6)
    assert set(c.tile_keys()) == expected_tiles((0, 0, 90, 70), 32) == set(res.touched_tiles)
    per_px = {'feather': channels + 1, 'multiband': 2 * channels + 3, 'bestview': 3 * channels + 5}[blend]
    assert c.memory_bytes == len(c.tile_keys()) * 32 * 32 * 4 * per_px


@pytest.mark.parametrize('blend', ['feather', 'multiband', 'bestview'])
def test_uint8_frames_paint_as_their_float_values_with_gains_after_the_warp(blend: str) -> None:
    """A uint8 frame is warped as integers and converted on the mosaic: the same mosaic as its
    float values (values / 255) within the warp's rounding (0.5 / 255), under a rotation, an
    oblique view cut by max_stretch and a reduced (shrinking) frame; ``scale`` multiplies each
    channel after the warp and clips at 1, as multiplying the float frame first does."""
    frame8 = (texture(90, 120) * 255).round().astype(np.uint8)
    oblique = np.array([[1.0, 0.1, 40.0], [0.05, 1.2, 30.0], [0.0, 0.004, 1.0]])
    views = (rotation(17.0, 60, 45, 30, 20), oblique, np.diag([0.3, 0.3, 1.0]) @ translation(40, 40))
    for m, gains in itertools.product(views, (np.array([1.0, 0.8, 0.6]), np.array([1.4, 1.0, 0.7]))):
        out = {}
        for kind in ('float', 'uint8'):
            c = TiledCanvas(3, 32, blend=blend, max_stretch=2.0)
            if kind == 'uint8':
                c.paint(frame8, m, scale=gains)
            else:
                c.paint(np.minimum(frame8.astype(np.float32) / 255 * gains.astype(np.float32), 1.0), m)
            out[kind] = c.render()
        np.testing.assert_array_equal(out['uint8'][1], out['float'][1])
        diff = np.abs(out['uint8'][0] - out['float'][0])[out['float'][1]]
        assert out['uint8'][0].max() <= 1.0
        if gains.max() <= 1.0:
            assert diff.max() <= 0.5 / 255 + 1e-6, (blend, diff.max())
            assert diff.mean() > 0 or m[0, 0] == 0.3  # integers were warped (rounded), not the floats
        else:  # clipped after the warp, not before: apart only next to saturated pixels
            assert np.median(diff) <= 0.5 / 255 * 1.4, (blend, np.median(diff))


@pytest.mark.parametrize('blend', ['feather', 'multiband', 'bestview'])
def test_tiles_painted_on_threads_give_the_same_mosaic(blend: str) -> None:
    """threads=2 (each tile's colour warped on its own, tiles on two threads) paints the mosaic of
    threads=1 (the frame's colour warped over its box at once): the same coverage, labels and
    tiles, colours within one integer step of the warp (OpenCV rounds a tile's own coordinates)."""
    frames = [((texture(90, 120, seed=k) * 255).round().astype(np.uint8), rotation(7.0 * k, 60, 45, 25 * k, 10 * k))
              for k in range(4)]
    out = {}
    for threads in (1, 2):
        c = TiledCanvas(3, 32, blend=blend, threads=threads)
        for k, (img, m) in enumerate(frames):
            if k == 2:  # a checkpoint between paints: pickled without its threads, which start again
                c = pickle.loads(pickle.dumps(c))
            c.paint(img, m, scale=np.array([1.2, 1.0, 0.9]))
        out[threads] = (c.render(), c.tile_keys(), None if blend == 'feather' else c.labels())
        c.close()
    np.testing.assert_allclose(out[2][0][0], out[1][0][0], rtol=0, atol=1.2 / 255 + 1e-6)
    assert np.mean(out[2][0][0] != out[1][0][0]) < 0.05
    np.testing.assert_array_equal(out[2][0][1], out[1][0][1])
    assert out[2][1] == out[1][1]
    if blend != 'feather':
        np.testing.assert_array_equal(out[2][2], out[1][2])
    for bad in (0, 1.5, True):
        with pytest.raises(CanvasError, match='threads'):
            TiledCanvas(3, 32, blend=blend, threads=bad)


def test_refuses_bad_images_and_settings() -> None:
    c = TiledCanvas(3)
    with pytest.raises(CanvasError, match='float32'):
        c.paint(np.zeros((10, 10, 3), np.int16), np.eye(3))
    for bad in ([1.0, 1.0], [1.0, 0.0, 1.0], [1.0, np.nan, 1.0]):
        with pytest.raises(CanvasError, match='scale'):
            c.paint(np.zeros((10, 10, 3), np.uint8), np.eye(3), scale=np.array(bad))
    with pytest.raises(CanvasError, match=r'\(H, W, 3\)'):
        c.paint(np.zeros((10, 10), np.float32), np.eye(3))
    with pytest.raises(CanvasError, match='mask shape'):
        c.paint(np.zeros((10, 10, 3), np.float32), np.eye(3), mask=np.ones((5, 5), bool))
    with pytest.raises(CanvasError, match='blend'):
        TiledCanvas(3, blend='poisson')
    with pytest.raises(CanvasError, match='tile_size'):
        TiledCanvas(3, tile_size=3)
    with pytest.raises(CanvasError, match='inverted'):
        c.render((10, 0, 0, 10))
    assert c.is_empty and c.frames_painted == 0


@pytest.mark.parametrize(
    ('name', 'matrix', 'match'),
    [
        ('nan', np.array([[1.0, 0, np.nan], [0, 1, 0], [0, 0, 1]]), 'non-finite'),
        ('zero', np.zeros((3, 3)), 'zero matrix'),
        ('singular', np.array([[1.0, 2.0, 0], [2.0, 4.0, 0], [0, 0, 1]]), 'singular'),
        ('horizon', np.array([[1.0, 0, 0], [0, 1, 0], [0, -0.02, 1]]), 'horizon'),
        ('near horizon', np.array([[1.0, 0, 0], [0, 1, 0], [0, -0.0095, 1]]), 'times the frame area'),
        ('huge zoom', np.diag([40.0, 40.0, 1.0]), 'times the frame area'),
        ('far away', translation(5e6, 0.0), 'max_canvas_side_px'),
    ],
)
def test_absurd_homography_is_refused(name: str, matrix: np.ndarray, match: str) -> None:
    c = TiledCanvas(3, tile_size=64, max_canvas_side_px=100000)
    frame = texture(100, 120)
    c.paint(frame, np.eye(3))
    with pytest.raises(CanvasError, match=match) as info:
        c.paint(frame, matrix)
    assert isinstance(info.value, ValueError) and isinstance(info.value, SrMosaicError)
    assert c.frames_painted == 1 and c.bounds() == (0, 0, 120, 100)


def test_flipped_sign_homography_is_the_same() -> None:
    frame = texture(40, 50)
    a, b = TiledCanvas(3, tile_size=32), TiledCanvas(3, tile_size=32)
    a.paint(frame, translation(3, 4))
    b.paint(frame, -2.0 * translation(3, 4))
    np.testing.assert_array_equal(a.render()[0], b.render()[0])


# ---------------------------------------------------------------- geometry
@pytest.mark.parametrize('blend', BLENDS)
@pytest.mark.parametrize('offset', [(0, 0), (37, 5), (-300, -129), (-1, 64), (1000, -2000)])
def test_integer_translation_reproduces_frame(blend: str, offset: tuple[int, int]) -> None:
    frame = texture(60, 80)
    c = TiledCanvas(3, tile_size=64, blend=blend)
    res = c.paint(frame, translation(*offset))
    ox, oy = offset
    box = (ox, oy, ox + 80, oy + 60)
    assert c.bounds() == box == res.bbox
    assert set(c.tile_keys()) == expected_tiles(box, 64)
    out, cov = c.render(box)
    assert cov.all()
    np.testing.assert_allclose(out, frame, atol=1e-4)
    # One pixel around the frame is uncovered.
    out, cov = c.render((ox - 1, oy - 1, ox + 81, oy + 61))
    assert cov[1:-1, 1:-1].all() and not cov[0].any() and not cov[-1].any()
    assert not cov[:, 0].any() and not cov[:, -1].any()


@pytest.mark.parametrize('blend', BLENDS)
@pytest.mark.parametrize(
    'mosaic_h_frame',
    [
        translation(10.25, -7.6),
        rotation(30.0, 40.0, 30.0, 500.3, -200.7),
        rotation(-97.0, 40.0, 30.0, -80.0, 20.0),
        np.array([[0.9, 0.1, -40.0], [-0.05, 1.1, 17.0], [2e-4, -1e-4, 1.0]]),
    ],
    ids=['subpixel', 'rot30', 'rot-97', 'projective'],
)
@pytest.mark.parametrize('interpolation', ['cubic', 'linear'])
def test_warped_frame_matches_cv2(blend: str, mosaic_h_frame: np.ndarray, interpolation: str) -> None:
    frame = texture(60, 80)
    c = TiledCanvas(3, tile_size=32, blend=blend, interpolation=interpolation)
    c.paint(frame, mosaic_h_frame)
    x0, y0, x1, y1 = region = c.bounds()
    box_h_frame = translation(-x0, -y0) @ mosaic_h_frame
    if interpolation == 'linear':  # OpenCV's own bilinear warp
        ref = cv2.warpPerspective(frame, box_h_frame, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT)
    else:  # the clamped bicubic of core/mosaic/resample.py
        ref = resample.warp(frame, box_h_frame, (x1 - x0, y1 - y0), interpolation)
    out, cov = c.render(region)
    inside = interior_mask(mosaic_h_frame, region, 80, 60, margin=0.0)
    assert cov[inside].all() and inside.sum() > 1000
    np.testing.assert_allclose(out[inside], ref[inside], atol=1e-4)
    # Covered pixels are those whose frame point falls within one pixel of the pixel-centre hull.
    assert not (cov & ~interior_mask(mosaic_h_frame, region, 80, 60, margin=-1.0)).any()
    # The rim colour is an edge colour, not faded to black.
    assert out[cov].min() >= 0.2 - 1e-4


def test_growth_in_all_directions_and_sparse_tiles() -> None:
    t = 64
    frame = texture(50, 70)
    c = TiledCanvas(3, tile_size=t)
    offsets = [(0, 0), (-500, 3), (400, -20), (10, -700), (-33, 900)]
    boxes = []
    for k, (ox, oy) in enumerate(offsets):
        res = c.paint(frame, translation(ox, oy))
        boxes.append((ox, oy, ox + 70, oy + 50))
        assert res.frame_index == k and set(res.touched_tiles) == expected_tiles(boxes[-1], t)
    assert c.bounds() == (-500, -700, 470, 950)
    assert set(c.tile_keys()) == set().union(*(expected_tiles(b, t) for b in boxes))
    assert c.frames_painted == 5
    # Nothing between the frames: the gap renders uncovered and holds no tiles.
    out, cov = c.render((100, 100, 300, 300))
    assert not cov.any() and (out == 0).all()
    assert (2, 2) not in c.tile_keys()
    for ox, oy in offsets:
        out, cov = c.render((ox, oy, ox + 70, oy + 50))
        assert cov.all()
        np.testing.assert_allclose(out, frame, atol=1e-5)
    # The whole mosaic renders over its bounds.
    out, cov = c.render()
    assert out.shape == (1650, 970, 3) and cov.sum() == 5 * 50 * 70


def test_tiles_created_only_where_the_footprint_touches() -> None:
    # A long thin strip rotated by 45 degrees: its bbox is mostly empty.
    t = 32
    frame = texture(8, 400)
    h = rotation(45.0, 200.0, 4.0, 100.0, 100.0)
    c = TiledCanvas(3, tile_size=t)
    res = c.paint(frame, h)
    x0, y0, x1, y1 = c.bounds()
    assert len(c.tile_keys()) < 0.3 * len(expected_tiles((x0, y0, x1, y1), t))
    wsum = c.weights((x0, y0, x1, y1))
    written = {((x0 + j) // t, (y0 + i) // t) for i, j in zip(*np.nonzero(wsum > 0))}
    assert written == set(c.tile_keys()) == set(res.touched_tiles)
    # The footprint polygon contains the whole strip.
    poly = res.footprint_xy.astype(np.float32)
    for u, v in ((0.0, 0.0), (399.0, 7.0), (200.0, 4.0), (50.0, 1.0)):
        p = h @ (u, v, 1.0)
        assert cv2.pointPolygonTest(poly, (p[0] / p[2], p[1] / p[2]), False) > 0
    assert cv2.pointPolygonTest(poly, (float(x0), float(y1 - 1)), False) < 0


def test_touched_tiles_record() -> None:
    c = TiledCanvas(3, tile_size=64)
    c.paint(texture(20, 20), translation(5, 5))
    assert c.pop_touched() == {(0, 0)}
    assert c.touched_tiles == frozenset()
    c.paint(texture(20, 20), translation(-10, 70))
    assert c.touched_tiles == {(-1, 1), (0, 1)}
    assert c.frames_per_tile() == {(0, 0): 1, (-1, 1): 1, (0, 1): 1}


# ---------------------------------------------------------------- blending
def two_crops(shift: float = 0.0, sigma: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Source (120, 300, 3) and two overlapping crops: columns [0, 180) and [120, 300)."""
    src = texture(120, 300, sigma=sigma, seed=3)
    return src, src[:, :180].copy(), np.clip(src[:, 120:] + shift, 0.0, 1.0)


@pytest.mark.parametrize('blend', BLENDS)
def test_overlapping_crops_blend_seamlessly(blend: str) -> None:
    src, a, b = two_crops()
    c = TiledCanvas(3, tile_size=64, blend=blend)
    c.paint(a, np.eye(3))
    c.paint(b, translation(120, 0))
    out, cov = c.render()
    assert c.bounds() == (0, 0, 300, 120) and cov.all()
    np.testing.assert_allclose(out, src, atol=1e-5)


@pytest.mark.parametrize('blend', BLENDS)
def test_overlapping_rotated_frames_blend_seamlessly(blend: str) -> None:
    """A second frame resampled from the source by a known rotation, placed by that rotation."""
    src = texture(200, 300, sigma=3.0, seed=5)
    a = src[:, :180].copy()
    mosaic_h_b = rotation(12.0, 60.0, 70.0, 130.0, 30.0)
    # Frame pixel (u, v) shows the source at mosaic_h_b @ (u, v, 1).
    b = cv2.warpPerspective(src, mosaic_h_b, (120, 140), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    c = TiledCanvas(3, tile_size=64, blend=blend)
    c.paint(a, np.eye(3))
    c.paint(b, mosaic_h_b)
    region = (0, 0, 300, 200)
    out, cov = c.render(region)
    inside_b = interior_mask(mosaic_h_b, region, 120, 140, margin=1.0)
    assert (inside_b[:, :178]).sum() > 2000  # a real overlap
    assert cov[inside_b].all()
    err = np.abs(out - src)[inside_b]
    assert err.max() < 0.02 and err.mean() < 0.003  # two bilinear resamplings of a smooth texture


@pytest.mark.parametrize('blend', BLENDS)
def test_brightness_step_is_smoothed(blend: str) -> None:
    step = 0.15
    src, a, b = two_crops(step)
    c = TiledCanvas(3, tile_size=64, blend=blend)
    c.paint(a, np.eye(3))
    c.paint(b, translation(120, 0))
    out, _ = c.render()
    d = (out - src).mean(axis=2)  # the brightness offset the mosaic adds to the true scene
    # Outside the overlap each crop shows as it is.
    np.testing.assert_allclose(d[:, :110], 0.0, atol=3e-3)
    np.testing.assert_allclose(d[:, 190:], step, atol=3e-3)
    # Across the overlap the offset ramps up: no hard edge anywhere (a pasted seam jumps by 0.15).
    jumps = np.abs(np.diff(d, axis=1))
    assert jumps.max() < 0.15 * step
    assert np.median(d[:, 150]) == pytest.approx(step / 2, abs=0.3 * step)
    # The ramp is monotone on average.
    profile = d.mean(axis=0)
    assert (np.diff(profile[110:190]) > -1e-3).all()


def test_multiband_keeps_detail_where_feather_ghosts() -> None:
    """Misregistered by 3 px, the feather average blurs fine detail in the overlap, multiband does not."""
    src, a, b = two_crops(sigma=1.0)
    detail = {}
    for blend in BLENDS:
        c = TiledCanvas(3, tile_size=64, blend=blend)
        c.paint(a, np.eye(3))
        c.paint(b, translation(123, 0))
        out, _ = c.render((0, 0, 300, 120))
        hp = out - cv2.GaussianBlur(out, (0, 0), 2.0)
        detail[blend] = float(np.abs(hp[:, 130:175]).mean())
    hp_src = float(np.abs((src - cv2.GaussianBlur(src, (0, 0), 2.0))[:, 130:175]).mean())
    assert detail['multiband'] > 0.9 * hp_src
    assert detail['feather'] < 0.85 * hp_src


def test_multiband_blocked_render_matches_whole(monkeypatch: pytest.MonkeyPatch) -> None:
    src, a, b = two_crops(0.1)
    c = TiledCanvas(3, tile_size=64, blend='multiband', bands=4)
    c.paint(a, np.eye(3))
    c.paint(b, rotation(3.0, 90.0, 60.0, 120.0, 10.0))
    whole, cov_whole = c.render()
    monkeypatch.setattr(reader_mod, 'RENDER_BLOCK_PX', 70)
    blocked, cov_blocked = c.render()
    np.testing.assert_array_equal(cov_whole, cov_blocked)
    np.testing.assert_allclose(blocked, whole, atol=2e-4)
    # A sub-region renders as the same pixels of the whole.
    part, _ = c.render((100, 20, 200, 90))
    np.testing.assert_allclose(part, whole[20:90, 100:200], atol=2e-4)


# ---------------------------------------------------------------- masks and weights
@pytest.mark.parametrize('blend', BLENDS)
def test_mask_is_honoured(blend: str) -> None:
    src, a, _ = two_crops()
    c = TiledCanvas(3, tile_size=64, blend=blend)
    c.paint(a, np.eye(3))
    garbage = np.ones_like(a)
    garbage[40:60, 50:70] = np.nan  # non-finite pixels are invalid even without a mask
    mask = np.zeros(a.shape[:2], bool)
    mask[:, 100:] = True  # garbage is only "valid" from column 100 on...
    garbage[:, 100:] = src[:, 100 + 40:180 + 40]  # ...where it shows the true scene (placed at +40)
    c.paint(garbage, translation(40, 0), mask=mask)
    out, cov = c.render((0, 0, 220, 120))
    assert np.isfinite(out).all() and cov.all()
    np.testing.assert_allclose(out, src[:, :220], atol=1e-5)


def test_fully_masked_frame_paints_nothing() -> None:
    c = TiledCanvas(1, tile_size=64)
    res = c.paint(np.ones((30, 30), np.float32), np.eye(3), mask=np.zeros((30, 30), bool))
    assert res.touched_tiles == () and c.is_empty and c.tile_keys() == []


def test_feather_weight_profiles() -> None:
    for profile in ('separable', 'distance'):
        w = feather_weight(5, 7, profile=profile)
        assert w.shape == (5, 7) and w.dtype == np.float32
        assert w.max() == pytest.approx(1.0) and w.min() > 0
        assert w[2, 3] == pytest.approx(1.0)
        np.testing.assert_allclose(w, w[::-1, ::-1])  # symmetric
    np.testing.assert_allclose(feather_weight(5, 7, profile='distance')[0], 1.0 / 3.0)
    sep = feather_weight(5, 7)
    np.testing.assert_allclose(sep[2], [0.25, 0.5, 0.75, 1.0, 0.75, 0.5, 0.25])
    np.testing.assert_allclose(feather_weight(5, 7, power=2.0), sep**2, rtol=1e-6)
    mask = np.ones((5, 7), bool)
    np.testing.assert_allclose(feather_weight(5, 7, mask=mask), sep)
    mask[2, 3] = False
    wm = feather_weight(5, 7, mask=mask)
    assert wm[2, 3] == 0 and wm[2, 2] < sep[2, 2] and wm[0, 0] == pytest.approx(sep[0, 0])


# ---------------------------------------------------------------- live preview
def _block_means(c: TiledCanvas, f: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference for render_preview: the full feather render, block sums of acc = image * W and of W."""
    x0, y0, x1, y1 = c.bounds()
    bx0, by0 = x0 // f * f, y0 // f * f
    bx1, by1 = -(-x1 // f) * f, -(-y1 // f) * f
    region = (bx0, by0, bx1, by1)
    acc_full, w = c._reader._gather(region, ('acc', 'wsum'))  # the feather accumulators, whatever the blend
    h, wd = (by1 - by0) // f, (bx1 - bx0) // f
    acc = acc_full.astype(np.float64).reshape(h, f, wd, f, -1).sum(axis=(1, 3))
    ws = w.astype(np.float64).reshape(h, f, wd, f).sum(axis=(1, 3))
    out = np.divide(acc, ws[..., None], out=np.zeros_like(acc), where=ws[..., None] > 0)
    return out, ws > 0


@pytest.mark.parametrize(('blend', 'channels', 'in_memory'), [('feather', 3, 0), ('multiband', 1, 2)])
def test_render_preview_is_the_block_mean_and_incremental(blend: str, channels: int, in_memory: int,
                                                          tmp_path) -> None:
    """render_preview = weighted block means of the feather blend, at the smallest tile-size divisor
    that fits max_side; after more frames (new tiles, a growing canvas, spilled tiles) it is again
    exact, though it only re-reads painted tiles."""
    spill = {'max_tiles_in_memory': in_memory, 'spill_dir': str(tmp_path)} if in_memory else {}
    c = TiledCanvas(channels, tile_size=64, blend=blend, **spill)
    frame = texture(60, 80, channels, seed=3)
    img = frame[:, :, 0] if channels == 1 else frame
    for k in range(4):
        c.paint(img, rotation(7.0 * k, 40, 30, 23.0 * k - 10.0, 11.0 * k))
    for max_side in (400, 60, 17):
        x0, y0, x1, y1 = c.bounds()
        f = next(d for d in (1, 2, 4, 8, 16, 32, 64) if max(x1 - x0, y1 - y0) / d <= max_side)
        prev, cov = c.render_preview(max_side)
        ref, ref_cov = _block_means(c, f)
        assert max(prev.shape[:2]) <= max_side and cov.shape == prev.shape[:2]
        rx, ry, rw, rh = c.last_preview_region  # the region the preview shows: f times its size
        assert (rx, ry, rw, rh) == (x0 // f * f, y0 // f * f, f * prev.shape[1], f * prev.shape[0])
        np.testing.assert_array_equal(cov, ref_cov)
        np.testing.assert_allclose(prev.reshape(ref.shape), ref, atol=2e-5)
    # Grow the canvas. 1000: the factor stays 1 (only the painted tiles are re-read); 60: it changes.
    c.render_preview(1000)
    for k in range(4, 9):
        c.paint(img, rotation(-5.0 * k, 40, 30, 30.0 * k - 10.0, -9.0 * k))
    for max_side in (1000, 60, 120):
        x0, y0, x1, y1 = c.bounds()
        f = next(d for d in (1, 2, 4, 8, 16, 32, 64) if max(x1 - x0, y1 - y0) / d <= max_side)
        prev, cov = c.render_preview(max_side)
        ref, ref_cov = _block_means(c, f)
        np.testing.assert_array_equal(cov, ref_cov)
        np.testing.assert_allclose(prev.reshape(ref.shape), ref, atol=2e-5)
    empty = TiledCanvas(channels, tile_size=64, blend=blend)
    e, ec = empty.render_preview(100)
    assert e.size == 0 and ec.size == 0
    with pytest.raises(CanvasError, match='max_side'):
        c.render_preview(0)


@pytest.mark.parametrize('blend', ['bestview', 'multiband'])
def test_labels_name_the_frame_each_pixel_comes_from(blend: str) -> None:
    """Two frames side by side overlapping by half: each pixel's label is the frame whose centre is
    nearer (eq. 4.7's closeness weight), -1 where none painted; a feather canvas has none."""
    c = TiledCanvas(3, tile_size=32, blend=blend)
    for k, shift in enumerate((0.0, 40.0)):
        r = c.paint(texture(60, 80, seed=k), np.array([[1.0, 0, shift], [0, 1.0, 0], [0, 0, 1.0]]))
        assert r.frame_index == k
    labels = c.labels((0, 0, 120, 60))
    assert labels.dtype == np.int32 and labels.shape == (60, 120)
    assert (labels[5:55, 2:30] == 0).all() and (labels[5:55, 90:118] == 1).all()
    assert set(np.unique(labels[:, 50:70])) == {0, 1}  # the seam between the centres 40 px apart
    assert (c.labels((200, 0, 210, 10)) == -1).all()
    with pytest.raises(CanvasError, match='no labels'):
        TiledCanvas(3, tile_size=32, blend='feather').labels((0, 0, 4, 4))


@pytest.mark.parametrize('channels', [1, 3, 5])
def test_preview_block_sums_are_the_sums_of_the_blocks(channels: int) -> None:
    """block_sums (OpenCV's area average times f^2 up to 4 channels) gives the sums over f x f blocks of
    the colour and the weight, not only their ratio, and copies: the tile painted later leaves them."""
    from types import SimpleNamespace

    from srmosaic_ros.core.mosaic.preview import block_sums

    rng = np.random.default_rng(channels)
    t = 64
    tile = SimpleNamespace(best_view_tile=False, acc=rng.random((t, t, channels), dtype=np.float32),
                           wsum=rng.random((t, t), dtype=np.float32))
    for f in (1, 2, 4, 8):
        n = t // f
        acc, w = block_sums(tile, f, t, channels)
        assert acc.shape == (n, n, channels) and w.shape == (n, n) and acc.dtype == w.dtype == np.float32
        np.testing.assert_allclose(acc, tile.acc.reshape(n, f, n, f, channels).sum(axis=(1, 3)), rtol=1e-5)
        np.testing.assert_allclose(w, tile.wsum.reshape(n, f, n, f).sum(axis=(1, 3)), rtol=1e-5)
        assert not np.shares_memory(acc, tile.acc) and not np.shares_memory(w, tile.wsum)


@pytest.mark.parametrize('blend', BLENDS)
def test_a_paint_in_part_is_the_whole_paint_on_the_boxes_asked_for(blend: str) -> None:
    """A frame painted on boxes of a few tiles (thinning.py's slivers at opposite corners of its
    footprint, each warped on its own) leaves those boxes as painting it whole does, within one
    integer step of the warp, and nothing anywhere else; the paint's bbox is the painted pixels'."""
    img = (texture(90, 120, seed=3) * 255).round().astype(np.uint8)
    m = rotation(20.0, 60, 45, 40, 30)
    # its footprint's top corner is near (59, 12), its bottom one near (141, 137)
    rects = {(1, 0): (40, 8, 64, 32), (4, 4): (128, 128, 150, 140), (9, 9): (300, 300, 310, 310)}
    whole, part = TiledCanvas(3, 32, blend=blend), TiledCanvas(3, 32, blend=blend)
    whole.paint(img, m)
    res = part.paint(img, m, tiles=rects)
    assert res.touched_tiles == ((1, 0), (4, 4))  # (9, 9): outside the footprint
    region = whole.bounds()
    w_img, w_cov = whole.render(region)
    p_img, p_cov = part.render(region)
    asked = np.zeros(w_cov.shape, bool)
    for x0, y0, x1, y1 in list(rects.values())[:2]:
        asked[max(y0 - region[1], 0):y1 - region[1], max(x0 - region[0], 0):x1 - region[0]] = True
    np.testing.assert_array_equal(p_cov, w_cov & asked)
    if blend == 'feather':  # the others blend across the boxes' edges
        np.testing.assert_allclose(p_img[p_cov], w_img[p_cov], rtol=0, atol=1.2 / 255 + 1e-6)
    np.testing.assert_allclose(part.weights(region)[asked], whole.weights(region)[asked], rtol=0, atol=1e-6)
    ys, xs = np.nonzero(p_cov)
    assert res.bbox == (region[0] + xs.min(), region[1] + ys.min(), region[0] + xs.max() + 1, region[1] + ys.max() + 1)
    if blend != 'feather':
        np.testing.assert_array_equal(part.labels(region)[p_cov], whole.labels(region)[p_cov])


@pytest.mark.parametrize('f', [1, 4])
def test_tile_blocks_are_the_preview_blocks_of_one_tile_and_pop_touched_names_the_changed(f: int) -> None:
    """tile_blocks(key, f) is the block mean of that tile alone (render_preview's blocks); the tiles
    pop_touched names are those painted since it last ran (what the live map sends)."""
    c = TiledCanvas(3, tile_size=64)
    img = texture(60, 80, 3, seed=5)
    c.paint(img, translation(10.0, 20.0))
    first = c.pop_touched()
    assert first == frozenset(c.tile_keys()) and c.pop_touched() == frozenset()
    c.paint(img, translation(100.0, 20.0))
    second = c.pop_touched()
    assert second and second != first and all(key[0] >= 1 for key in second)
    x0, y0, x1, y1 = c.bounds()
    ref, ref_cov = _block_means(c, f)
    for key in c.tile_keys():
        image, covered = c.tile_blocks(key, f)
        n = 64 // f
        assert image.shape == (n, n, 3) and covered.shape == (n, n)
        # the tile's blocks in the reference grid (which starts at bounds // f * f)
        oy, ox = (key[1] * 64 - y0 // f * f) // f, (key[0] * 64 - x0 // f * f) // f
        ys, xs = slice(max(oy, 0), oy + n), slice(max(ox, 0), ox + n)
        sub, sub_cov = ref[ys, xs], ref_cov[ys, xs]
        mine, mine_cov = image[max(-oy, 0):, max(-ox, 0):][:sub.shape[0], :sub.shape[1]], \
            covered[max(-oy, 0):, max(-ox, 0):][:sub.shape[0], :sub.shape[1]]
        np.testing.assert_array_equal(mine_cov, sub_cov)
        np.testing.assert_allclose(mine[mine_cov], sub[sub_cov], atol=2e-5)
    assert c.tile_blocks((99, 99), f) is None
    with pytest.raises(CanvasError, match='divide the tile size'):
        c.tile_blocks(c.tile_keys()[0], 3)
