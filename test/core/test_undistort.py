"""Lens distortion removed at the input edge (core/undistort.py): exact remap geometry, and a
simulated flight seen through a barrel lens registers as accurately as through a pinhole."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.types import CameraIntrinsics, Frame
from srmosaic_ros.core.undistort import Undistorter, pinhole_of
from srmosaic_ros.errors import InputError
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, simulate

BARREL = (-0.25, 0.08, 0.0005, -0.0003, 0.0)


def _camera(width: int = 320, height: int = 240, model: str = 'plumb_bob', d: tuple = BARREL) -> CameraIntrinsics:
    return CameraIntrinsics(width, height, 280.0, 281.0, 161.3, 118.9, model, d)


@pytest.mark.parametrize(('model', 'd'), [('plumb_bob', BARREL), ('rational_polynomial', BARREL + (0.01, 0.0, 0.0)),
                                          ('equidistant', (0.05, -0.01, 0.002, 0.0))])
def test_remap_sends_each_pinhole_pixel_to_where_the_lens_imaged_it(model: str, d: tuple) -> None:
    cam = _camera(model=model, d=d)
    pinhole, map_x, map_y = pinhole_of(cam)
    assert not pinhole.has_distortion and (pinhole.width, pinhole.height) == (320, 240)
    u = np.array([[10.0, 12.0], [160.0, 120.0], [300.0, 20.0], [5.0, 230.0], [250.0, 200.0]])
    rays = np.c_[(u - [pinhole.cx, pinhole.cy]) / [pinhole.fx, pinhole.fy], np.ones(len(u))]
    if model == 'equidistant':
        want, _ = cv2.fisheye.projectPoints(rays[None], np.zeros(3), np.zeros(3), cam.K, np.array(d))
    else:
        want, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.K, np.array(d))
    got = np.stack([map_x[u[:, 1].astype(int), u[:, 0].astype(int)], map_y[u[:, 1].astype(int), u[:, 0].astype(int)]], 1)
    np.testing.assert_allclose(got, want.reshape(-1, 2), atol=1e-3)
    # alpha 0: every output pixel comes from inside the image (no border painted into the mosaic)
    assert map_x.min() >= -0.5 and map_x.max() <= 319.5 and map_y.min() >= -0.5 and map_y.max() <= 239.5


def test_frames_without_distortion_pass_untouched_and_bad_models_are_refused() -> None:
    und = Undistorter()
    image = np.zeros((240, 320), np.uint8)
    plain = Frame(1, image, _camera(d=(0.0,) * 5))
    assert und.frame(plain) is plain and und.frame(Frame(2, image, None)) is not None
    assert Undistorter(enabled=False).frame(Frame(3, image, _camera())).image is image
    with pytest.raises(InputError, match="'kannala' .* not supported.*undistort: false"):
        und.frame(Frame(4, image, _camera(model='kannala', d=(0.1, 0.0, 0.0, 0.0))))
    with pytest.raises(InputError, match='a 160x120 image with the intrinsics of a 320x240 camera'):
        und.frame(Frame(5, np.zeros((120, 160), np.uint8), _camera()))
    out = und.frame(Frame(6, np.zeros((240, 320), np.uint16), _camera()))
    assert out.image.dtype == np.uint16 and not out.camera.has_distortion and und.undistorted == 1


def test_a_barrel_lens_flight_registers_like_a_pinhole_one() -> None:
    """Simulated frames re-imaged through a barrel lens (k1 = -0.25: 12 % at the corners of 320x240;
    rendered from 400x300 pinhole frames so that the lens never looks outside them). Undistorted,
    the consecutive homographies match the truth (in the undistorted pixels) as the pinhole frames
    do; left distorted they are off by pixels."""
    flight = simulate(SimConfig(width=400, height=300, world_gsd_m=0.3, frames=8, speed_m_s=8.0, seed=2))
    big = flight.camera
    lens = CameraIntrinsics(320, 240, big.fx, big.fy, 159.5, 119.5, 'plumb_bob', BARREL)
    # distorted image: pixel p_d shows what the pinhole saw at its undistorted position
    grid = np.stack(np.meshgrid(np.arange(320.0), np.arange(240.0)), -1).reshape(-1, 1, 2)
    src = cv2.undistortPoints(grid, lens.K, np.array(BARREL), P=big.K).reshape(240, 320, 2).astype(np.float32)
    assert src[..., 0].min() > 0 and src[..., 0].max() < 399 and src[..., 1].min() > 0 and src[..., 1].max() < 299
    frames = [Frame(f.stamp_ns, cv2.remap(f.image, src[..., 0], src[..., 1], cv2.INTER_CUBIC), lens)
              for f in flight.frames]
    pinhole, _, _ = pinhole_of(lens)
    A = pinhole.K @ np.linalg.inv(big.K)  # pinhole pixels -> undistorted pixels
    # distorted frames, read as if pinhole: the best a homography can do is the lens's own pinhole
    B = lens.K @ np.linalg.inv(big.K)

    def errors(undistort: bool) -> list[float]:
        pipe = Pipeline(dataclasses.replace(pipeline_config(), undistort=undistort, georef_enabled=False))
        recs = [r for f in frames for r in pipe.feed_frame(f)]
        recs += pipe.finish().records[len(recs):]
        out = []
        for rec, t in zip(recs[1:], flight.truth.frames[1:]):
            m = A if undistort else B
            reg = rec.registration
            out.append(corner_error_px(reg.prev_H_cur, m @ t.prev_H_cur @ np.linalg.inv(m), 320, 240)
                       if reg is not None and reg.ok else np.inf)
        return out

    fixed, raw = errors(True), errors(False)
    assert max(fixed) < 0.1, fixed
    assert np.median(raw) > 10 * max(fixed), raw
