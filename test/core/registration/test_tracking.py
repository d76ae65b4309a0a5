"""Registration by photometric tracking (TorchRegistrar.track) and the policy that chooses it
(core/registration/tracking.py), against the truth of rendered frames, and in the pipeline."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.registration import RegistrationConfig, make_registrar
from srmosaic_ros.core.registration.pyramid import PyramidRegistrar
from srmosaic_ros.core.registration.registrar import Registration
from srmosaic_ros.core.registration.torch_registrar import TorchRegistrar
from srmosaic_ros.core.registration.tracking import TRACK_RMS_FACTOR, MotionTracker
from srmosaic_ros.core.types import Frame
from srmosaic_ros.pipeline import Pipeline

from imagery import similarity, translation, view

W, H = 320, 240
MS = 1_000_000


@pytest.fixture(scope='module')
def registrar() -> TorchRegistrar:
    return TorchRegistrar(device='cpu')


def _pair(delta: np.ndarray):
    world_H_prev = translation(200.0, 150.0)
    prev = view(world_H_prev, W, H, noise=2.0, seed=1)
    cur = view(world_H_prev @ delta, W, H, noise=2.0, seed=2)
    return prev, cur, delta


def test_describe_without_keypoints_registers_as_with_them(registrar):
    prev, cur, truth = _pair(similarity(2.0, 1.02, 9.0, -5.0, W / 2, H / 2))
    lazy_p, lazy_c = registrar.describe(prev, keypoints=False), registrar.describe(cur, keypoints=False)
    assert lazy_p.keypoints is None and lazy_p.templates  # only what tracking needs
    eager = registrar.register(registrar.describe(prev), registrar.describe(cur))
    lazy = registrar.register(lazy_p, lazy_c)
    assert lazy_p.keypoints is not None and len(lazy_c) == len(lazy_c.keypoints_px) > 50
    assert lazy.ok and eager.ok and lazy.inliers == eager.inliers
    np.testing.assert_allclose(lazy.prev_H_cur, eager.prev_H_cur, rtol=0, atol=1e-9)


def test_track_from_a_close_prediction_reaches_the_feature_estimate(registrar):
    prev, cur, truth = _pair(similarity(1.5, 1.01, 7.3, -4.6, W / 2, H / 2))
    fp, fc = registrar.describe(prev, keypoints=False), registrar.describe(cur, keypoints=False)
    predicted = truth @ translation(1.2, -0.8)  # the previous pair's motion, a pixel off
    reg = registrar.track(fp, fc, predicted, max_rms=1.0)
    assert reg.ok, reg.reason
    assert reg.extras['tracked'] == 1.0 and reg.inliers == 0 and np.isnan(reg.rms_px)
    assert fp.keypoints is None and fc.keypoints is None  # no keypoints were needed
    assert corner_error_px(reg.prev_H_cur, truth, W, H) < 0.1
    feat = registrar.register(fp, fc)
    assert corner_error_px(reg.prev_H_cur, feat.prev_H_cur, W, H) < 0.02
    assert reg.covariance is not None and reg.covariance.shape == (8, 8)
    assert np.all(np.linalg.eigvalsh(reg.covariance) > 0)


def test_track_refuses_a_far_prediction_and_a_high_residual(registrar):
    prev, cur, truth = _pair(translation(12.0, -7.0))
    fp, fc = registrar.describe(prev, keypoints=False), registrar.describe(cur, keypoints=False)
    far = registrar.track(fp, fc, truth @ translation(25.0, 18.0), max_rms=1.0)
    assert not far.ok
    assert 'prediction' in far.reason or 'converge' in far.reason
    good = registrar.track(fp, fc, truth @ translation(0.5, 0.5), max_rms=1.0)
    assert good.ok
    tight = registrar.track(fp, fc, truth @ translation(0.5, 0.5), max_rms=0.5 * good.extras['photometric_rms'])
    assert not tight.ok and 'residual' in tight.reason


def test_track_on_a_pyramid_level_in_full_size_pixels():
    reg = PyramidRegistrar(make_registrar(RegistrationConfig(), 'cpu'), max_width=320)
    w, h = 640, 480
    world_H_prev = translation(100.0, 80.0)
    truth = similarity(1.0, 1.0, 14.0, -6.0, w / 2, h / 2)
    prev = view(world_H_prev, w, h, noise=2.0, seed=1)
    cur = view(world_H_prev @ truth, w, h, noise=2.0, seed=2)
    fp, fc = reg.describe(prev, keypoints=False), reg.describe(cur, keypoints=False)
    assert fp.level == 1
    out = reg.track(fp, fc, truth @ translation(1.5, 1.0), max_rms=1.0)
    assert out.ok, out.reason
    assert corner_error_px(out.prev_H_cur, truth, w, h) < 0.2


def _reg(tracked: bool, rms: float = 0.01, refined: bool = True) -> Registration:
    extras = {'tracked': 1.0} if tracked else {'refined': float(refined), 'photometric_rms': rms}
    return Registration(True, translation(3.0, 0.0), 100, 80, 0.3, extras=extras)


def test_tracker_policy():
    t = MotionTracker(frames=4)
    assert t.prediction(0, 0, 1, 40 * MS) is None  # nothing placed yet
    t.placed(_reg(False), 0, 0, 1, 40 * MS)
    np.testing.assert_array_equal(t.prediction(1, 40 * MS, 2, 80 * MS), translation(3.0, 0.0))
    assert t.max_rms() == pytest.approx(TRACK_RMS_FACTOR * 0.01)
    assert t.prediction(1, 40 * MS, 3, 120 * MS) is None       # not the next frame
    # twice the interval (a dropped frame): the motion continued over it
    np.testing.assert_allclose(t.prediction(1, 40 * MS, 2, 120 * MS), translation(6.0, 0.0), atol=1e-9)
    np.testing.assert_allclose(t.prediction(1, 40 * MS, 2, 60 * MS), translation(1.5, 0.0), atol=1e-9)  # half
    assert t.prediction(1, 40 * MS, 2, 40 * MS + 4 * 40 * MS + 1) is None  # more than TRACK_MAX_DT_RATIO times
    assert t.prediction(1, 40 * MS, 2, 80 * MS + 1) is t.motion[3]  # a rounding of the stamps: the motion as it is
    for k in (2, 3, 4):  # frames - 1 pairs tracked, then one by features
        assert t.prediction(k - 1, (k - 1) * 40 * MS, k, k * 40 * MS) is not None
        t.placed(_reg(True), k - 1, (k - 1) * 40 * MS, k, k * 40 * MS)
    assert t.prediction(4, 160 * MS, 5, 200 * MS) is None
    t.placed(_reg(False, refined=False), 4, 160 * MS, 5, 200 * MS)  # refinement not applied: no reference
    assert t.prediction(5, 200 * MS, 6, 240 * MS) is None
    t.placed(_reg(False), 5, 200 * MS, 6, 240 * MS)
    assert t.prediction(6, 240 * MS, 7, 280 * MS) is not None
    t.lost()
    assert t.prediction(6, 240 * MS, 7, 280 * MS) is None
    assert MotionTracker(frames=0).prediction(0, 0, 1, 40 * MS) is None


def _flight(offsets, frames_per_s=25.0):
    return [Frame(int(i * 1e9 / frames_per_s), view(translation(*o), W, H, noise=2.0, seed=i))
            for i, o in enumerate(offsets)]


def _run(frames, track_frames):
    cfg = pipeline_config({'registration.track_frames': track_frames})
    pipe = Pipeline(cfg)
    for f in frames:
        pipe.feed(f)
    return pipe.finish()


def test_pipeline_tracks_a_smooth_flight_as_accurately_as_features():
    # a smooth flight, then a sudden jump (the prediction 25 px off): that pair goes to features
    offsets = [(100 + 6 * i + 0.05 * i * i, 120 + 2 * i) for i in range(16)]
    offsets[12:] = [(x + 25.0, y + 20.0) for x, y in offsets[12:]]
    frames = _flight(offsets)
    tracked, features = _run(frames, 10), _run(frames, 0)
    regs = [r.registration for r in tracked.records[1:]]
    kinds = ['t' if r.extras.get('tracked') else 'f' for r in regs]
    assert kinds[0] == 'f' and kinds.count('t') >= 8
    assert kinds[11] == 'f' and regs[11].extras.get('track_refused') == 1.0  # frame 12: the jump
    assert not any(r.registration.extras.get('tracked') for r in features.records[1:])
    for res in (tracked, features):
        assert all(r.painted for r in res.records) and len(res.segments) == 1
    for a, b, o in zip(tracked.records, features.records, offsets):
        truth = translation(o[0] - offsets[0][0], o[1] - offsets[0][1])
        assert corner_error_px(a.seg_H_frame, truth, W, H) < 0.3
        assert corner_error_px(a.seg_H_frame, b.seg_H_frame, W, H) < 0.1


def test_report_medians_over_feature_pairs_and_counts():
    from srmosaic_ros.app.process import registration_report
    feat = Registration(True, np.eye(3), 120, 100, 0.4, time_s=0.02, extras={'track_refused': 1.0})
    feat2 = Registration(True, np.eye(3), 90, 80, 0.6, time_s=0.02)
    tracked = Registration(True, np.eye(3), 0, 0, float('nan'), time_s=0.01, extras={'tracked': 1.0})
    r = registration_report([feat, tracked, tracked, feat2])
    assert r['median_inliers'] == 90.0 and r['median_rms_px'] == pytest.approx(0.5)
    assert r['tracked'] == 2 and r['track_refused'] == 1 and r['median_ms'] == pytest.approx(15.0)
    assert registration_report([tracked])['median_rms_px'] is None


def test_homography_power_continues_a_motion():
    from scipy.linalg import expm

    from srmosaic_ros.core.homography import homography_power
    A = np.array([[2e-3, 1e-2, 12.0], [-9e-3, -1e-3, -4.0], [2e-6, -1e-6, 0.0]])  # a frame interval's motion
    for r in (0.5, 1.0, 2.0, 3.7):
        want = expm(r * A)
        np.testing.assert_allclose(homography_power(7.0 * expm(A), r), want / want[2, 2], rtol=0, atol=1e-9)
    assert homography_power(np.diag([-1.0, 1.0, 1.0]), 2.0) is None  # a reflection has no real logarithm
    assert homography_power(np.zeros((3, 3)), 2.0) is None


def test_pipeline_tracks_across_irregular_drops():
    """A live node drops frames from its queue when it falls behind: the intervals between the frames
    it processes vary (40, 80, 120 ms...). The motion is continued over each interval, so such pairs
    are tracked (before: every pair after an interval change went to features) and placed as well as
    features place them."""
    keep = [0, 1, 2, 4, 5, 8, 9, 11, 13, 14, 17, 18, 20, 21, 23, 26, 27, 29]  # stream frames the node took
    offsets = [(100 + 4 * i + 0.03 * i * i, 120 + 1.5 * i) for i in range(30)]
    frames = [f for i, f in enumerate(_flight(offsets)) if i in keep]
    kept = [offsets[i] for i in keep]
    tracked, features = _run(frames, 10), _run(frames, 0)
    regs = [r.registration for r in tracked.records[1:]]
    assert sum(bool(r.extras.get('tracked')) for r in regs) >= 10
    for a, b, o in zip(tracked.records, features.records, kept):
        truth = translation(o[0] - kept[0][0], o[1] - kept[0][1])
        assert a.painted and corner_error_px(a.seg_H_frame, truth, W, H) < 0.3
        assert corner_error_px(a.seg_H_frame, b.seg_H_frame, W, H) < 0.1
