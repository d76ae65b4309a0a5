"""Drift control (core/georef/drift.py, Georeferencer.correct): the pose errors as a Gauss-Markov
process whose time constant is in seconds, not frames."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.georef import FramePose, GeorefConfig, Georeferencer, homography_from_corners
from srmosaic_ros.core.georef.drift import InformationRate, pose_error_transition
from srmosaic_ros.core.georef.ground_homography import apply_H
from srmosaic_ros.core.metrics import mosaic_corner_errors
from srmosaic_ros.core.types import CameraIntrinsics, GeoFix
from srmosaic_ros.errors import ConfigError

CAM = CameraIntrinsics(320, 240, 277.0, 277.0, 159.5, 119.5)  # 0.36 m/px at 100 m
CORNERS = np.array([[0.0, 0.0], [319.0, 0.0], [319.0, 239.0], [0.0, 239.0]])
SPEED = 8.0  # m/s east
P_POS = 1.0  # m^2, declared position variance of every pose
P_ATT = 1e-6  # rad^2


def info_rate(tau_pos_s: float, tau_att_s: float = 0.5) -> np.ndarray:
    """Information per second that makes the filter-derived time constants tau = 1 / (P Lambda)."""
    return np.diag([1.0 / (tau_pos_s * P_POS)] * 3 + [1.0 / (tau_att_s * P_ATT)] * 3)


def make_georef(**config) -> Georeferencer:
    georef = Georeferencer(GeorefConfig(ground_altitude_m=0.0, **config), CAM)
    georef.feed_fix(GeoFix(0, 45.0, 7.0, 100.0))
    georef.make_raster(pose_at(georef, 0.0))
    return georef


def pose_at(georef: Georeferencer, t: float, error_en: tuple[float, float] = (0.0, 0.0),
            info: np.ndarray | None = None) -> FramePose:
    """The pose at time t of a nadir flight east at 100 m, off by error_en (m), declaring P_POS, P_ATT."""
    p = np.array([SPEED * t + error_en[0], error_en[1], 100.0])
    rpy = np.zeros(3)
    cov = np.diag([P_POS] * 3 + [P_ATT] * 3)
    return FramePose(int(round(t * 1e9)), True, p, rpy, cov, camera=georef.mount.camera_pose(np.r_[p, rpy]),
                     ground_z_m=0.0, info_rate=info)


def true_placements(georef: Georeferencer, times: np.ndarray) -> list[np.ndarray]:
    return [georef.raster_H_frame(pose_at(georef, t)) for t in times]


def corner_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(apply_H(a, CORNERS) - apply_H(b, CORNERS), axis=1).mean())


def test_transition_keeps_the_pose_covariance_and_decays_with_the_time_constant() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(7, 7))
    P0 = a @ a.T + 0.1 * np.eye(7)
    P1 = 0.8 * P0 + 0.05 * np.eye(7)
    for kwargs in ({'time_constant_s': 2.0}, {'info_rate': np.diag([0.8, 0.8, 0.2, 5e4, 5e4, 5e4, 0.0])}):
        A, Q = pose_error_transition(P0, P1, 0.25, **kwargs)
        np.testing.assert_allclose(A @ P0 @ A.T + Q, P1, atol=1e-9)  # Cov(y_k) = P_k at every frame
        assert np.linalg.eigvalsh(Q).min() > -1e-12
    # scalar: the correlation of consecutive errors is exp(-dt / tau), tau = 1 / (P Lambda)
    for dt in (0.25, 0.0625):
        A, Q = pose_error_transition(np.eye(1) * 2.0, np.eye(1) * 2.0, dt, info_rate=np.eye(1) * 0.1)
        assert A[0, 0] == pytest.approx(math.exp(-dt * 2.0 * 0.1))
        assert Q[0, 0] == pytest.approx(2.0 * (1.0 - math.exp(-2.0 * dt * 2.0 * 0.1)))
    A, Q = pose_error_transition(np.eye(2), np.eye(2), 0.25, time_constant_s=0.0)
    np.testing.assert_allclose(A, 0.0)
    np.testing.assert_allclose(Q, np.eye(2))  # white: independent poses
    A, Q = pose_error_transition(np.eye(2), np.eye(2), 0.25)  # no information: persistent
    np.testing.assert_allclose(A, np.eye(2))
    np.testing.assert_allclose(Q, 0.0, atol=1e-12)


def test_information_rate_is_per_second_over_the_window() -> None:
    rate = InformationRate(3, 10.0)
    for k in range(100):  # 5 Hz, R = 6.25 m^2
        rate.add(k * 200_000_000, np.eye(3) / 6.25)
    np.testing.assert_allclose(rate.rate(99 * 200_000_000), np.eye(3) * 0.8)
    early = InformationRate(3, 10.0)
    for k in range(3):
        early.add(k * 200_000_000, np.eye(3) / 6.25)
    np.testing.assert_allclose(early.rate(2 * 200_000_000), np.eye(3) * 0.8)  # 3 fixes over 0.6 s
    np.testing.assert_allclose(rate.rate(40 * 10**9), 0.0)  # a dropout: nothing renews the error


def kinked_chain_error(georef: Georeferencer, fps: float, duration_s: float = 60.0) -> float:
    """Corner error (px) at the end of a chain that starts drifting 0.5 px/s halfway (a kink: not a
    similarity of the whole mosaic, so drift control must take it out), corrected by exact poses."""
    times = np.arange(0.0, duration_s, 1.0 / fps)
    truth = true_placements(georef, times)
    dt = 1.0 / fps
    placed = [georef.correct(truth[0], pose_at(georef, 0.0, info=info_rate(5.0)))]
    for k in range(1, len(times)):
        bias = 0.5 * dt if times[k] > duration_s / 2 else 0.0
        step = np.linalg.solve(truth[k - 1], truth[k]) @ np.array([[1.0, 0.0, bias], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        placed.append(georef.correct(placed[-1] @ step, pose_at(georef, times[k], info=info_rate(5.0)),
                                     chain_sigma_px=math.sqrt(dt)))  # 1 px per sqrt(s)
    return corner_error(placed[-1], truth[-1])


@pytest.mark.parametrize('tau', [float('nan'), 5.0])
def test_pose_weight_per_second_does_not_depend_on_the_frame_rate(tau: float) -> None:
    """How far the poses let a drifting chain go depends on the information they bring per second:
    the same at 4 and at 16 frames/s. Poses counted as independent frames (time constant 0) pull
    about twice as hard at 16 frames/s (4 times the information)."""
    err = {fps: kinked_chain_error(make_georef(drift_pose_time_constant_s=tau), fps) for fps in (4.0, 16.0)}
    assert 1.0 < err[4.0] < 12.0, err
    assert err[16.0] == pytest.approx(err[4.0], rel=0.1), err
    white = {fps: kinked_chain_error(make_georef(drift_pose_time_constant_s=0.0), fps) for fps in (4.0, 16.0)}
    assert white[4.0] > 1.6 * white[16.0], white


def test_gauss_markov_pose_error_is_not_averaged_into_the_chain_as_jitter() -> None:
    """Poses that wander by 1 m (2.8 px) with a 10 s correlation time at 16 frames/s, a chain that
    drifts by 0.3 px per sqrt(s): modelled as a Gauss-Markov process the wander stays out of the
    mosaic; poses taken as independent (time constant 0) average it in as distortion."""
    fps, tau, duration = 16.0, 10.0, 120.0
    times = np.arange(0.0, duration, 1.0 / fps)
    sigma = 0.3 / math.sqrt(fps)  # px per frame
    rms = {'from the filter': [], 'white': []}
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        phi = math.exp(-1.0 / (fps * tau))
        errors = np.zeros((len(times), 2))
        errors[0] = rng.normal(0.0, math.sqrt(P_POS), 2)
        for k in range(1, len(times)):
            errors[k] = phi * errors[k - 1] + rng.normal(0.0, math.sqrt(P_POS * (1.0 - phi**2)), 2)
        noise = rng.normal(0.0, sigma, (len(times), 4, 2))
        for name, config in (('from the filter', {}), ('white', {'drift_pose_time_constant_s': 0.0})):
            georef = make_georef(**config)
            truth = true_placements(georef, times)
            placed = [georef.correct(truth[0], pose_at(georef, times[0], errors[0], info_rate(tau)))]
            for k in range(1, len(times)):
                step = np.linalg.solve(truth[k - 1], truth[k])
                noisy = homography_from_corners(CORNERS, apply_H(step, CORNERS) + noise[k])
                placed.append(georef.correct(placed[-1] @ noisy, pose_at(georef, times[k], errors[k], info_rate(tau)),
                                             chain_sigma_px=sigma))
            err, _ = mosaic_corner_errors(placed, truth, CAM.width, CAM.height)
            rms[name].append(float(np.sqrt(np.mean(err**2))))
    assert sum(rms['from the filter']) < 0.85 * sum(rms['white']), rms
    assert max(rms['from the filter']) < 2.5, rms


def test_the_anchor_error_stays_in_the_canvas_and_later_chains_follow_it() -> None:
    """The first pose is 2.5 m off (declared: 3 m sigma), the later ones exact (1 m): the chain
    anchored on the first is offset as a whole, an error of the canvas that the re-anchoring takes
    out. Drift control does not bend the mosaic toward the later poses; it estimates the offset
    and places a second chain in the same canvas frame."""
    georef = make_georef()
    fps = 4.0
    times = np.arange(0.0, 60.0, 1.0 / fps)
    truth = true_placements(georef, times)
    first = pose_at(georef, 0.0, (2.0, -1.5), info_rate(5.0))
    first = dataclasses.replace(first, covariance=np.diag([9.0] * 3 + [P_ATT] * 3))
    chained = [georef.raster_H_frame(first)]
    placed = [georef.correct(chained[0], first)]
    for k in range(1, len(times)):
        step = np.linalg.solve(truth[k - 1], truth[k])
        chained.append(chained[-1] @ step)
        placed.append(georef.correct(placed[-1] @ step, pose_at(georef, times[k], info=info_rate(5.0)),
                                     chain_sigma_px=0.05))
    offset = 2.5 / 0.36  # px
    assert corner_error(placed[-1], truth[-1]) == pytest.approx(offset, abs=1.0)
    assert max(corner_error(p, c) for p, c in zip(placed, chained)) < 1.0  # not bent toward the poses
    shift = georef.canvas_similarity @ np.array([160.0, 120.0, 1.0]) - np.array([160.0, 120.0, 1.0])
    assert math.hypot(*shift[:2]) == pytest.approx(offset, abs=1.0)
    georef.reset_drift()  # a new segment on the same canvas, at the last frame, placed by its exact pose
    again = georef.correct(truth[-1], pose_at(georef, times[-1], info=info_rate(5.0)))
    assert corner_error(again, placed[-1]) < 1.0
    georef.reset_drift(new_canvas=True)
    np.testing.assert_allclose(georef.correct(truth[-1], pose_at(georef, times[-1], info=info_rate(5.0))),
                               truth[-1] / truth[-1][2, 2])


def test_an_invalid_pose_leaves_the_chain_and_a_new_chain_starts_where_it_is() -> None:
    georef = make_georef()
    truth = true_placements(georef, np.array([0.0, 0.25, 0.5]))
    off = truth[0] @ np.array([[1.0, 0.0, 3.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(georef.correct(off, pose_at(georef, 0.0, info=info_rate(5.0))), off / off[2, 2])
    chained = off @ np.linalg.solve(truth[0], truth[1])
    np.testing.assert_allclose(georef.correct(chained, FramePose.invalid(250_000_000, 'x')), chained / chained[2, 2])
    out = georef.correct(chained @ np.linalg.solve(truth[1], truth[2]), pose_at(georef, 0.5, info=info_rate(5.0)))
    assert np.all(np.isfinite(out))


def test_the_replaced_frame_count_key_is_refused_with_the_new_name() -> None:
    with pytest.raises(ConfigError, match='georef.drift_pose_time_constant_s'):
        pipeline_config({'georef.drift_pose_correlation_frames': 4.0})
    cfg = pipeline_config({'georef.drift_pose_time_constant_s': 3.0})
    assert cfg.georef.drift_pose_time_constant_s == 3.0
    assert math.isnan(pipeline_config().georef.drift_pose_time_constant_s)
    with pytest.raises(ConfigError, match='drift_pose_time_constant_s'):
        pipeline_config({'georef.drift_pose_time_constant_s': -1.0})


def test_homographies_from_corners_map_each_set_of_corners() -> None:
    """The batched solve (the drift's chain Jacobian needs 16 per frame) maps the corners to each
    target set exactly, as the single one does."""
    from srmosaic_ros.core.georef.ground_homography import homographies_from_corners

    rng = np.random.default_rng(3)
    dst = CORNERS[None] + rng.normal(0.0, 20.0, (5, 4, 2))
    Hs = homographies_from_corners(CORNERS, dst)
    assert Hs.shape == (5, 3, 3)
    for H, d in zip(Hs, dst, strict=True):
        assert np.allclose(apply_H(H, CORNERS), d, atol=1e-8)
        assert np.allclose(H, homography_from_corners(CORNERS, d), atol=1e-12)


def test_a_refined_raster_carries_the_drift_state_over_exactly() -> None:
    """refine_raster (mosaic.resolution 'finest'): after the raster is sampled z times finer mid-chain,
    drift control goes on as it would have on the coarse raster, scaled by z, when its pixel noises
    scale too: placements B = diag(z, z, 1) A, the canvas similarity conjugated by it."""
    a = make_georef(drift_chain_sigma_px=0.05, homography_min_sigma_px=0.5)
    gsd = a.raster.gsd_m_per_px
    zoom = 1.8
    b_gsd = float(f'{gsd / zoom:.2g}')
    z = gsd / b_gsd
    b = make_georef(drift_chain_sigma_px=0.05 * z, homography_min_sigma_px=0.5 * z)
    times = np.arange(0.0, 10.0, 0.25)
    truth = true_placements(a, times)
    first = dataclasses.replace(pose_at(a, 0.0, (2.0, -1.5), info_rate(5.0)), covariance=np.diag([9.0] * 3 + [P_ATT] * 3))
    pa, pb = [a.correct(a.raster_H_frame(first), first)], [b.correct(b.raster_H_frame(first), first)]
    S = np.diag([z, z, 1.0])
    for k in range(1, len(times)):
        if k == 6:  # the first frames settled: B's raster becomes z times finer
            assert b.refine_raster(zoom) == pytest.approx(z)
            assert b.raster.gsd_m_per_px == b_gsd and b.raster.origin_easting_m == a.raster.origin_easting_m
            pb = [S @ p for p in pb]
        step = np.linalg.solve(truth[k - 1], truth[k])
        pose = pose_at(a, times[k], (0.3 * math.sin(k), 0.0), info=info_rate(5.0))
        pa.append(a.correct(pa[-1] @ step, pose, chain_sigma_px=0.05))
        pb.append(b.correct(pb[-1] @ step, pose, chain_sigma_px=0.05 * (z if k >= 6 else 1.0)))
    # the same to numerical differentiation (chain_jacobian's steps are in pixels), against corrections of pixels
    assert max(corner_error(pb[k], S @ pa[k]) for k in range(6, len(times))) < 0.01
    assert max(corner_error(pa[k], truth[k]) for k in range(6, len(times))) > 1.0
    np.testing.assert_allclose(b.canvas_similarity, S @ a.canvas_similarity @ np.linalg.inv(S), rtol=1e-4, atol=0.01)
    assert b.refine_raster(1.0) == 1.0  # no finer: nothing changes
    with pytest.raises(ValueError, match='zoom >= 1'):
        b.refine_raster(0.5)
