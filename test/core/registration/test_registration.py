"""Registrar against known homographies on real aerial texture."""
from __future__ import annotations

import numpy as np
import pytest

from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.registration import Registrar, RegistrationConfig, check_homography

from imagery import similarity, translation, view

W, H = 320, 240


def _pair(cur_H_world_delta: np.ndarray, noise: float = 2.0):
    """prev frame at world offset (200, 150); cur = prev moved by delta (frame->frame)."""
    world_H_prev = translation(200.0, 150.0)
    world_H_cur = world_H_prev @ cur_H_world_delta
    prev = view(world_H_prev, W, H, noise=noise, seed=1)
    cur = view(world_H_cur, W, H, noise=noise, seed=2)
    prev_H_cur = np.linalg.inv(world_H_prev) @ world_H_cur
    return prev, cur, prev_H_cur


@pytest.mark.parametrize('delta', [
    translation(12.3, -7.6),
    similarity(6.0, 1.0, 20.0, 10.0, W / 2, H / 2),
    similarity(-4.0, 1.15, -15.0, 25.0, W / 2, H / 2),
])
def test_registers_known_motion_subpixel(delta):
    prev, cur, prev_H_cur = _pair(delta)
    reg_ = Registrar()
    reg = reg_.register(reg_.describe(prev), reg_.describe(cur))
    assert reg.ok, reg.reason
    assert reg.inliers >= 30
    assert corner_error_px(reg.prev_H_cur, prev_H_cur, W, H) < 0.3


def test_textureless_frame_fails_explicitly():
    prev, _, _ = _pair(translation(5, 5))
    flat = np.full_like(prev, 128)
    reg_ = Registrar()
    reg = reg_.register(reg_.describe(prev), reg_.describe(flat))
    assert not reg.ok
    assert 'too few' in reg.reason


def test_unrelated_frames_fail():
    prev = view(translation(10, 10), W, H, noise=2)
    other = view(translation(600, 450), W, H, noise=2)
    reg_ = Registrar()
    reg = reg_.register(reg_.describe(prev), reg_.describe(other))
    assert not reg.ok


def test_check_homography_rejects_implausible():
    assert check_homography(np.eye(3), W, H) == ''
    assert 'scale' in check_homography(np.diag([3.0, 3.0, 1.0]), W, H)
    assert 'mirror' in check_homography(np.diag([-1.0, 1.0, 1.0]), W, H)
    persp = np.eye(3)
    persp[2, 0] = 0.002
    assert 'perspective' in check_homography(persp, W, H)
    assert 'finite' in check_homography(np.full((3, 3), np.nan), W, H)


def test_config_refuses_bad_values():
    with pytest.raises(ValueError, match='ratio'):
        RegistrationConfig(ratio=1.5)
