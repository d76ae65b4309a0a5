"""The flight simulator: geometry, rendering against its own truth, telemetry, bags, CLI."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.georef.frames import R_enu_from_body, matrix_from_quat_xyzw, rotvec_from_matrix
from srmosaic_ros.core.georef.ground_homography import apply_H
from srmosaic_ros.errors import BagError, ConfigError, SimulationError
from srmosaic_ros.sim import SimConfig, load_truth, simulate, write_flight
from srmosaic_ros.sim.cli import add_arguments, config_from_args, run
from srmosaic_ros.sim.flight import build_trajectory
from srmosaic_ros.sim.render import effective_sigma_px, hr_H_lr, local_scales, reference_render, render_frame
from srmosaic_ros.sim.trajectory import GRAVITY_M_S2

FAST = {'width': 160, 'height': 120, 'frames': 6}


def lk_shift(ref: np.ndarray, img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(dx, dy) such that img(x) ~ ref(x + d): one Gauss-Newton step on ref's gradients."""
    ref = ref.astype(np.float64)
    img = img.astype(np.float64)
    if ref.ndim == 3:
        ref, img = ref.mean(axis=2), img.mean(axis=2)
    gx = (np.roll(ref, -1, 1) - np.roll(ref, 1, 1)) / 2
    gy = (np.roll(ref, -1, 0) - np.roll(ref, 1, 0)) / 2
    mask = mask.copy()
    mask[:2], mask[-2:], mask[:, :2], mask[:, -2:] = False, False, False, False  # np.roll wraps around
    a = np.stack([gx[mask], gy[mask]], 1)
    return np.linalg.lstsq(a, (img - ref)[mask], rcond=None)[0]


def warp_prev_from_cur(flight, k: int, images: list[np.ndarray] | None = None,
                       interpolation: int = cv2.INTER_CUBIC) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame k-1, frame k warped into k-1 by the true prev_H_cur, overlap mask)."""
    cam = flight.camera
    images = [f.image for f in flight.frames] if images is None else images
    prev = images[k - 1].astype(np.float32)
    cur = images[k].astype(np.float32)
    cur_H_prev = np.linalg.inv(flight.truth.frames[k].prev_H_cur)
    size = (cam.width, cam.height)
    warped = cv2.warpPerspective(cur, cur_H_prev, size, flags=interpolation | cv2.WARP_INVERSE_MAP)
    valid = cv2.warpPerspective(np.ones((cam.height, cam.width), np.uint8), cur_H_prev, size,
                                flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
    # erode also from the image edges: the interpolation needs support inside the current frame
    valid = cv2.erode(valid, np.ones((9, 9), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    return prev, warped, valid


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a, dtype=np.float64))))


@pytest.fixture(scope='module')
def textured_world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A random multi-scale RGB texture, 1200x900 px (unknown place: needs an origin)."""
    rng = np.random.default_rng(11)
    img = np.zeros((900, 1200, 3), np.float32)
    for sigma, amp in ((30, 60), (8, 40), (2, 30), (0.7, 20)):
        img += amp * cv2.GaussianBlur(rng.normal(size=(900, 1200, 3)).astype(np.float32), (0, 0), sigma) * sigma
    img = 128 + 60 * img / img.std()
    path = tmp_path_factory.mktemp('worlds') / 'texture.png'
    cv2.imwrite(str(path), np.clip(img, 0, 255).astype(np.uint8))
    return path


def texture_config(world: Path, **kw: object) -> SimConfig:
    base = {'world': str(world), 'world_gsd_m': 0.25, 'origin_lat_deg': 45.0, 'origin_lon_deg': 7.0}
    base.update(FAST)
    base.update(kw)
    return SimConfig(**base)  # type: ignore[arg-type]


# --- smoke, shapes, options ------------------------------------------------------------------


def test_smoke_default_world_shapes_and_counts() -> None:
    flight = simulate(SimConfig(**FAST, seed=1))  # type: ignore[arg-type]
    assert len(flight.frames) == 6 == len(flight.truth.frames)
    assert all(f.image.shape == (120, 160, 3) and f.image.dtype == np.uint8 for f in flight.frames)
    cam = flight.camera
    assert (cam.width, cam.height, cam.cx, cam.cy) == (160, 120, 79.5, 59.5)
    assert cam.fx == pytest.approx(80 / math.tan(math.radians(30)))
    # 5 s of flight: fixes at 5 Hz, IMU at 50 Hz, all within the frames' time span
    duration_ns = flight.frames[-1].stamp_ns - flight.frames[0].stamp_ns
    assert duration_ns == 1_250_000_000
    assert len(flight.fixes) == 7 and len(flight.imus) == 63
    assert flight.truth.frames[0].prev_H_cur is None
    assert flight.truth.camera_gsd_m == pytest.approx(100 / cam.fx)


def test_ir_mode_is_mono_and_decimation_scales_intrinsics(textured_world: Path) -> None:
    flight = simulate(texture_config(textured_world, mode='ir', decimate=2, noise_sigma=0.0))
    assert flight.frames[0].image.shape == (60, 80) and flight.frames[0].image.dtype == np.uint8
    assert flight.world.image.ndim == 2
    cam = flight.camera
    assert (cam.width, cam.height, cam.cx, cam.cy) == (80, 60, 39.5, 29.5)
    assert cam.fx == pytest.approx(40 / math.tan(math.radians(30)))
    assert float(flight.frames[0].image.std()) > 5.0


def test_default_line_flight_fits_and_moves_moderately() -> None:
    """The demo's flight: 60 frames stay inside the world, 8..25 px of motion between frames."""
    flight = simulate(SimConfig(width=64, height=48, seed=7))  # footprint depends on the FOV only
    assert len(flight.frames) == 60
    pp = np.array([[319.5, 239.5]])
    scale = 640 / 64
    motion = [np.linalg.norm(apply_H(f.prev_H_cur, pp / scale) - pp / scale) * scale for f in flight.truth.frames[1:]]
    assert 8 < min(motion) and max(motion) < 25


def test_default_lawnmower_fits_with_overlapping_return_legs() -> None:
    flight = simulate(SimConfig(trajectory='lawnmower', width=32, height=24, noise_sigma=0))
    yaw = np.array([f.yaw_deg for f in flight.truth.frames])
    assert len(flight.frames) == 196
    assert np.any(np.abs(yaw) < 10) and np.any(np.abs(yaw) > 170)  # legs east and west
    # frame 20 (first leg) and its nearest frame of the second leg overlap
    c = np.array([[15.5, 11.5]])
    first = apply_H(flight.truth.frames[20].world_px_H_frame, c)
    second_leg = [f for f in flight.truth.frames if abs(f.yaw_deg) > 170]
    dist = min(np.linalg.norm(apply_H(f.world_px_H_frame, c) - first) for f in second_leg)
    assert dist * 0.1 < 100  # legs 60 m apart, footprint 115 m across


# --- determinism -----------------------------------------------------------------------------


def test_same_seed_same_bytes_other_seed_other_noise() -> None:
    a = simulate(SimConfig(**FAST, seed=5))  # type: ignore[arg-type]
    b = simulate(SimConfig(**FAST, seed=5))  # type: ignore[arg-type]
    c = simulate(SimConfig(**FAST, seed=6))  # type: ignore[arg-type]
    assert all(fa.image.tobytes() == fb.image.tobytes() for fa, fb in zip(a.frames, b.frames))
    assert [f.stamp_ns for f in a.frames] == [f.stamp_ns for f in b.frames]
    for x, y in zip(a.fixes, b.fixes):
        assert (x.latitude_deg, x.longitude_deg, x.altitude_m) == (y.latitude_deg, y.longitude_deg, y.altitude_m)
    for x, y in zip(a.imus, b.imus):
        assert x.orientation_xyzw.tobytes() == y.orientation_xyzw.tobytes()
        assert x.linear_acceleration_m_s2.tobytes() == y.linear_acceleration_m_s2.tobytes()
    assert json.dumps(a.truth.to_dict()) == json.dumps(b.truth.to_dict())
    assert a.frames[0].image.tobytes() != c.frames[0].image.tobytes()
    assert a.fixes[0].latitude_deg != c.fixes[0].latitude_deg


def test_noise_streams_are_independent_of_the_trajectory() -> None:
    """Changing the image noise leaves trajectory and telemetry unchanged."""
    a = simulate(SimConfig(**FAST, seed=5, noise_sigma=0.0))  # type: ignore[arg-type]
    b = simulate(SimConfig(**FAST, seed=5, noise_sigma=4.0))  # type: ignore[arg-type]
    np.testing.assert_array_equal(a.truth.frames[3].world_px_H_frame, b.truth.frames[3].world_px_H_frame)
    assert a.fixes[2].latitude_deg == b.fixes[2].latitude_deg
    diff = a.frames[2].image.astype(float) - b.frames[2].image.astype(float)
    assert 3.0 < rms(diff) < 5.0


# --- rendering agrees with the truth ---------------------------------------------------------


@pytest.mark.parametrize('decimate', [1, 2])
def test_render_matches_world_warped_by_world_px_H_frame(decimate: int) -> None:
    """Frames vs the world blurred by the same PSF (in world pixels) and sampled through the truth."""
    cfg = SimConfig(width=320, height=240, frames=3, noise_sigma=0.0, decimate=decimate, seed=3)
    flight = simulate(cfg)
    cam = flight.camera
    for k in (0, 2):
        world_px_H_frame = flight.truth.frames[k].world_px_H_frame
        centre = np.array([[(cam.width - 1) / 2, (cam.height - 1) / 2]])
        s = float(np.sqrt(np.prod(local_scales(world_px_H_frame, centre)[0])))  # world px per frame px
        sigma_world = effective_sigma_px(cfg.psf_sigma_px) * s / decimate
        ref = reference_render(flight.world.image, world_px_H_frame, (cam.width, cam.height), sigma_world)
        img = flight.frames[k].image.astype(np.float32)
        m = np.zeros(img.shape[:2], bool)
        m[6:-6, 6:-6] = True
        assert rms((img - ref)[m]) < 0.4  # 8-bit rounding alone gives 0.29
        assert np.all(np.abs(lk_shift(ref, img, m)) < 0.005)  # px


@pytest.mark.parametrize(('decimate', 'clean_rms'), [(1, 0.6), (2, 1.3)])
def test_prev_H_cur_aligns_consecutive_frames(decimate: int, clean_rms: float) -> None:
    """Frame k warped by the true prev_H_cur onto frame k-1: what is left is rounding and noise.

    Measured (320x240, psf 0.7): 0.40 grey levels RMS without noise (8-bit rounding of both frames
    alone gives 0.38); about 1 with decimation 2, whose frames alias by design (y = D B W x).
    """
    clean = simulate(SimConfig(width=320, height=240, frames=4, noise_sigma=0.0, decimate=decimate, seed=4))
    noisy = simulate(SimConfig(width=320, height=240, frames=4, noise_sigma=2.0, decimate=decimate, seed=4))
    for k in (1, 3):
        prev, warped, valid = warp_prev_from_cur(clean, k)
        residual = rms((warped - prev)[valid])
        assert residual < clean_rms
        prev_n, warped_n, valid_n = warp_prev_from_cur(noisy, k)
        # two independent noise fields (the warped one slightly smoothed), plus the clean residual
        assert rms((warped_n - prev_n)[valid_n]) < math.hypot(2.0 * math.sqrt(2.0), clean_rms)
        # sensitivity: one pixel of error in the homography shows clearly
        assert rms((np.roll(warped, 1, axis=1) - prev)[valid]) > 3 * residual


@pytest.mark.parametrize(('decimate', 'clean_rms'), [(1, 0.15), (2, 1.2)])
def test_truth_is_exact_to_a_few_thousandths_of_a_pixel(decimate: int, clean_rms: float) -> None:
    """Unrounded renders through the truth, warped with Lanczos: the best-fit residual shift is < 0.01 px.

    Measured: 0.06 grey levels RMS and under 0.002 px for decimation 1; 0.8 and under 0.006 px
    for decimation 2 (aliased frames).
    """
    cfg = SimConfig(width=320, height=240, frames=4, noise_sigma=0.0, decimate=decimate, seed=5)
    flight = simulate(cfg)
    sensor_H_frame = hr_H_lr(decimate)
    renders = [render_frame(flight.world.image, t.world_px_H_frame @ np.linalg.inv(sensor_H_frame), (320, 240),
                            decimate=decimate, psf_sigma_px=cfg.psf_sigma_px) for t in flight.truth.frames]
    for k in (1, 2, 3):
        prev, warped, valid = warp_prev_from_cur(flight, k, renders, cv2.INTER_LANCZOS4)
        assert rms((warped - prev)[valid]) < clean_rms
        assert np.all(np.abs(lk_shift(prev, warped, valid)) < 0.01)


def test_world_centre_appears_at_the_principal_point(tmp_path: Path) -> None:
    img = np.full((601, 801), 40, np.uint8)
    cv2.circle(img, (400, 300), 12, 255, -1)
    world = tmp_path / 'dot.png'
    cv2.imwrite(str(world), img)
    cfg = SimConfig(world=str(world), world_gsd_m=0.1, origin_lat_deg=10.0, origin_lon_deg=20.0, frames=1,
                    width=160, height=120, altitude_m=40.0, gust_deg=0.0, gust_pos_m=0.0, noise_sigma=0.0,
                    heading_deg=37.0)
    flight = simulate(cfg)
    truth = flight.truth.frames[0]
    np.testing.assert_allclose(apply_H(truth.world_px_H_frame, np.array([79.5, 59.5])), [400.0, 300.0], atol=1e-9)
    frame = flight.frames[0].image.astype(np.float64)
    weights = np.clip(frame.mean(axis=2) - 40.0, 0, None)
    ys, xs = np.mgrid[:120, :160]
    centroid = [float((weights * xs).sum() / weights.sum()), float((weights * ys).sum() / weights.sum())]
    np.testing.assert_allclose(centroid, [79.5, 59.5], atol=0.02)
    assert truth.latitude_deg == pytest.approx(10.0, abs=1e-12)
    np.testing.assert_allclose(truth.position_enu_m, [0, 0, 40.0], atol=1e-9)


def test_world_detail_finer_than_the_camera_does_not_alias(tmp_path: Path) -> None:
    """A grating of 2.5 world px (4 to 5 per camera pixel here) renders as flat grey, not as moire."""
    x = np.arange(1600)
    grating = (128 + 100 * np.sin(2 * np.pi * x / 2.5))[None, :] * np.ones((1200, 1))
    world = tmp_path / 'grating.png'
    cv2.imwrite(str(world), np.clip(grating, 0, 255).astype(np.uint8))
    cfg = SimConfig(world=str(world), world_gsd_m=0.1, origin_lat_deg=0.0, origin_lon_deg=0.0, frames=1,
                    width=160, height=120, altitude_m=60.0, noise_sigma=0.0, heading_deg=20.0)
    flight = simulate(cfg)
    s = float(local_scales(flight.truth.frames[0].world_px_H_frame, np.array([[79.5, 59.5]]))[0].min())
    assert s > 4.0
    assert float(flight.frames[0].image.astype(float).std()) < 1.0
    # naive point sampling of the same geometry shows the aliasing this avoids
    naive = reference_render(flight.world.image, flight.truth.frames[0].world_px_H_frame, (160, 120), 0.0)
    assert float(naive.std()) > 20.0


# --- trajectory and telemetry ----------------------------------------------------------------


def test_truth_is_self_consistent() -> None:
    flight = simulate(SimConfig(**FAST, seed=2))  # type: ignore[arg-type]
    origin = flight.world.origin
    for prev, cur in zip(flight.truth.frames, flight.truth.frames[1:]):
        chained = np.linalg.inv(prev.world_px_H_frame) @ cur.world_px_H_frame
        np.testing.assert_allclose(chained / chained[2, 2], cur.prev_H_cur, atol=1e-9)
        lat, lon, alt = origin.geodetic_from_enu(cur.position_enu_m)
        assert cur.latitude_deg == float(lat) and cur.longitude_deg == float(lon) and cur.altitude_m == float(alt)
    assert all(abs(f.roll_deg) < 10 and abs(f.pitch_deg) < 10 for f in flight.truth.frames)


def test_telemetry_without_noise_equals_truth() -> None:
    cfg = SimConfig(**FAST, gps_sigma_h_m=0.0, gps_sigma_v_m=0.0, imu_sigma_deg=0.0,  # type: ignore[arg-type]
                    gyro_sigma_rad_s=0.0, accel_sigma_m_s2=0.0, seed=8, fix_rate_hz=4.0, imu_rate_hz=100.0)
    flight = simulate(cfg)
    fixes = {f.stamp_ns: f for f in flight.fixes}
    imus = {s.stamp_ns: s for s in flight.imus}
    for truth in flight.truth.frames:  # at these rates frame stamps are also fix and IMU stamps
        fix = fixes[truth.stamp_ns]
        assert fix.latitude_deg == pytest.approx(truth.latitude_deg, abs=1e-12)
        assert fix.longitude_deg == pytest.approx(truth.longitude_deg, abs=1e-12)
        assert fix.altitude_m == pytest.approx(truth.altitude_m, abs=1e-6)
        R = matrix_from_quat_xyzw(imus[truth.stamp_ns].orientation_xyzw)
        expected = R_enu_from_body(*np.radians([truth.roll_deg, truth.pitch_deg, truth.yaw_deg]))
        np.testing.assert_allclose(R, expected, atol=1e-12)
    # gyro agrees with the attitude's finite differences between IMU samples
    for a, b, c in zip(flight.imus, flight.imus[1:], flight.imus[2:]):
        dt = (c.stamp_ns - a.stamp_ns) * 1e-9
        ra, rc = matrix_from_quat_xyzw(a.orientation_xyzw), matrix_from_quat_xyzw(c.orientation_xyzw)
        np.testing.assert_allclose(rotvec_from_matrix(ra.T @ rc) / dt, b.angular_velocity_rad_s, atol=2e-4)


def test_level_unaccelerated_flight_reads_gravity_on_body_z() -> None:
    cfg = SimConfig(**FAST, gust_deg=0.0, gust_pos_m=0.0, imu_sigma_deg=0.0,  # type: ignore[arg-type]
                    gyro_sigma_rad_s=0.0, accel_sigma_m_s2=0.0)
    flight = simulate(cfg)
    for s in flight.imus:
        np.testing.assert_allclose(s.linear_acceleration_m_s2, [0, 0, GRAVITY_M_S2], atol=1e-5)
        np.testing.assert_allclose(s.angular_velocity_rad_s, 0, atol=1e-9)


def test_noise_levels_and_covariances() -> None:
    cfg = SimConfig(width=32, height=24, frames=10, fix_rate_hz=50.0, seed=9)
    flight = simulate(cfg)
    traj, _ = build_trajectory(cfg)  # the same trajectory again (deterministic)
    origin = flight.world.origin
    t0 = flight.frames[0].stamp_ns
    err = np.array([origin.enu_from_geodetic(f.latitude_deg, f.longitude_deg, f.altitude_m)
                    - traj.state((f.stamp_ns - t0) * 1e-9).position_enu_m for f in flight.fixes])
    assert len(err) == 113
    assert 2.0 < err[:, :2].std() < 3.0 and 4.0 < err[:, 2].std() < 6.0
    fix = flight.fixes[0]
    assert fix.covariance_type == 2 and fix.status == 0
    np.testing.assert_allclose(fix.position_covariance_m2, np.diag([2.5**2, 2.5**2, 25.0]))
    np.testing.assert_allclose(flight.imus[0].orientation_covariance, np.eye(3) * math.radians(0.5) ** 2)


# --- errors ----------------------------------------------------------------------------------


@pytest.mark.parametrize(('changes', 'option'), [
    ({'altitude_m': 400.0}, '--altitude'),
    ({'frames': 200}, '--frames'),
    ({'trajectory': 'lawnmower', 'legs': 6}, '--legs'),
    ({'start_east_m': 190.0, 'start_north_m': 0.0}, '--start'),
])
def test_footprint_leaving_the_world_is_refused(changes: dict, option: str) -> None:
    with pytest.raises(SimulationError, match=option):
        simulate(SimConfig(width=32, height=24, **changes))


def test_lawnmower_too_many_frames_and_horizon_are_refused() -> None:
    with pytest.raises(SimulationError, match='--frames'):
        simulate(SimConfig(trajectory='lawnmower', frames=500, width=32, height=24))
    with pytest.raises(SimulationError, match='--gimbal-elevation'):
        simulate(SimConfig(gimbal_elevation_deg=-20.0, width=32, height=24, frames=1))


def test_invalid_options_are_refused(textured_world: Path) -> None:
    with pytest.raises(ConfigError, match='unknown'):
        SimConfig.from_dict({'altitude': 10})
    with pytest.raises(ConfigError, match='mode'):
        SimConfig(mode='sar')
    with pytest.raises(ConfigError, match='decimate'):
        SimConfig(decimate=0)
    with pytest.raises(ConfigError, match='--origin'):  # unknown place without an origin
        simulate(SimConfig(world=str(textured_world), **FAST))  # type: ignore[arg-type]


def test_config_round_trips_through_a_dict() -> None:
    cfg = SimConfig(trajectory='lawnmower', lever_arm_m=(0.1, 0.0, -0.2), seed=3)
    assert SimConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg


# --- bags, ground truth file, CLI -------------------------------------------------------------


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
@pytest.mark.parametrize('transport', ['raw', 'compressed'])
def test_write_flight_and_read_back(tmp_path: Path, textured_world: Path, storage: str, transport: str) -> None:
    from srmosaic_ros.core.types import Frame, GeoFix, ImuSample
    from srmosaic_ros.io.bags import inspect_bag, read_flight

    flight = simulate(texture_config(textured_world, mode='eo' if transport == 'raw' else 'ir', seed=1))
    out = write_flight(flight, tmp_path / 'bag', storage=storage, transport=transport)
    info = inspect_bag(out)
    image_topic = '/camera/image_raw' if transport == 'raw' else '/camera/image_raw/compressed'
    counts = {name: t.count for name, t in info.topics.items()}
    assert counts == {image_topic: 6, '/camera/camera_info': 6, '/fix': len(flight.fixes),
                      '/imu/data': len(flight.imus)}
    items = list(read_flight(out))
    frames = [i for i in items if isinstance(i, Frame)]
    assert len(frames) == 6
    assert sum(isinstance(i, GeoFix) for i in items) == len(flight.fixes)
    assert sum(isinstance(i, ImuSample) for i in items) == len(flight.imus)
    for got, want in zip(frames, flight.frames):
        assert got.stamp_ns == want.stamp_ns and got.image.shape == want.image.shape
        if transport == 'raw':
            np.testing.assert_array_equal(got.image, want.image)
        else:
            assert np.abs(got.image.astype(float) - want.image).mean() < 3.0
        assert got.camera is not None and got.camera.fx == pytest.approx(flight.camera.fx)
    truth = load_truth(out / 'ground_truth.json')
    assert truth.to_dict() == json.loads(json.dumps(flight.truth.to_dict()))
    assert [f.stamp_ns for f in truth.frames] == [f.stamp_ns for f in frames]
    np.testing.assert_array_equal(truth.frames[4].world_px_H_frame, flight.truth.frames[4].world_px_H_frame)
    assert truth.camera == flight.camera
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bag']  # no staging folder left


def test_ground_truth_file_contents(tmp_path: Path) -> None:
    flight = simulate(SimConfig(**FAST, seed=1))  # type: ignore[arg-type]
    out = write_flight(flight, tmp_path / 'b')
    data = json.loads((out / 'ground_truth.json').read_text())
    assert data['format_version'] == 1
    assert data['world']['path'] == 'data/worlds/caliterra_IMG_9360.jpg'
    assert data['world']['origin'] == {'latitude_deg': 30.17115, 'longitude_deg': -98.08987, 'altitude_m': 0.0}
    assert data['config']['seed'] == 1 and data['config']['psf_sigma_px'] == 0.7
    x0, y0, x1, y1 = data['covered_bbox_world_px']
    assert 0 <= x0 < x1 <= 3999 and 0 <= y0 < y1 <= 2999
    frame = data['frames'][1]
    assert set(frame) >= {'stamp_ns', 'position_enu_m', 'latitude_deg', 'longitude_deg', 'altitude_m', 'roll_deg',
                          'pitch_deg', 'yaw_deg', 'world_px_H_frame', 'prev_H_cur'}
    assert data['frames'][0]['prev_H_cur'] is None
    assert load_truth(out).frames[1].prev_H_cur.shape == (3, 3)  # a folder works too


def test_write_flight_refuses_to_overwrite_unless_asked(tmp_path: Path) -> None:
    flight = simulate(SimConfig(width=32, height=24, frames=2))
    write_flight(flight, tmp_path / 'b', storage='mcap')
    with pytest.raises(BagError, match='--overwrite'):
        write_flight(flight, tmp_path / 'b')
    write_flight(flight, tmp_path / 'b', overwrite=True)
    assert (tmp_path / 'b' / 'b.db3').is_file() and not (tmp_path / 'b' / 'b.mcap').exists()


def test_load_truth_errors(tmp_path: Path) -> None:
    from srmosaic_ros.errors import InputError

    with pytest.raises(InputError, match='not found'):
        load_truth(tmp_path / 'missing.json')
    bad = tmp_path / 'bad.json'
    bad.write_text('{"format_version": 99}')
    with pytest.raises(InputError, match='format_version'):
        load_truth(bad)


def test_cli_defaults_come_from_simconfig_and_run_writes_a_bag(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(['--out', str(tmp_path / 'x')])
    assert config_from_args(args) == SimConfig()
    args = parser.parse_args(['--mode', 'ir', '--gimbal-elevation', '-80', '--origin', '1', '2', '--turn-bank',
                              '--out', 'x'])
    cfg = config_from_args(args)
    assert (cfg.mode, cfg.gimbal_elevation_deg, cfg.origin_lat_deg, cfg.origin_lon_deg, cfg.turn_bank) == (
        'ir', -80.0, 1.0, 2.0, True)
    args = parser.parse_args(['--frames', '3', '--width', '64', '--height', '48', '--seed', '4', '--storage', 'mcap',
                              '--transport', 'compressed', '--start', '-10', '5', '--no-progress',
                              '--out', str(tmp_path / 'x')])
    cfg = config_from_args(args)
    assert (cfg.frames, cfg.width, cfg.seed, cfg.start_east_m, cfg.start_north_m) == (3, 64, 4, -10.0, 5.0)
    assert run(args) == 0
    assert '3 frames 64x48' in capsys.readouterr().out
    assert (tmp_path / 'x' / 'x.mcap').is_file() and (tmp_path / 'x' / 'ground_truth.json').is_file()
    with pytest.raises(BagError, match='--overwrite'):
        run(args)
