"""A keyframe's correction spread back over the frames before it (core/mosaic/revisit.py)."""
from __future__ import annotations

import numpy as np

from srmosaic_ros.core.homography import apply_homography, translation
from srmosaic_ros.core.mosaic.revisit import footprint_pose, spread_correction

W, H = 320, 240
CORNERS = np.array([[0.0, 0.0], [W - 1.0, 0.0], [W - 1.0, H - 1.0], [0.0, H - 1.0]])


def test_each_frame_takes_its_share_of_the_correction_along_the_chain():
    # Four frames 20 px apart, then the keyframe; the mosaic moves the keyframe by (8, -4) px and
    # turns it a little about its centre.
    chain = [translation(20.0 * j, 0.0) for j in range(5)]
    angle = np.radians(0.5)
    c, s = np.cos(angle), np.sin(angle)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    centre = translation(80.0 + W / 2, H / 2)
    corrected = translation(8.0, -4.0) @ centre @ turn @ np.linalg.inv(centre) @ chain[4]
    moved, shifts = spread_correction(chain[:4], [(W, H)] * 4, chain[4], corrected)
    D = corrected @ np.linalg.inv(chain[4])
    full = np.linalg.norm(apply_homography(D, apply_homography(chain[4], CORNERS))
                          - apply_homography(chain[4], CORNERS), axis=1).max()
    for j, (m, shift) in enumerate(zip(moved, shifts, strict=True)):
        before = apply_homography(chain[j], CORNERS)
        after = apply_homography(m, CORNERS)
        t = (j + 1) / 5
        # each corner goes t of the way to where the keyframe's correction takes it (Brownian bridge mean)
        np.testing.assert_allclose(after, before + t * (apply_homography(D, before) - before), atol=1e-6)
        assert m[2, 2] == 1.0
        assert shift == np.linalg.norm(after - before, axis=1).max()
    assert np.all(np.diff(shifts) > 0) and shifts[-1] < full
    # the step left between the last moved frame and the keyframe is a fifth of the correction
    step = np.linalg.norm(apply_homography(moved[-1], CORNERS) - apply_homography(chain[3], CORNERS)
                          - (apply_homography(corrected, CORNERS) - apply_homography(chain[4], CORNERS)), axis=1).max()
    assert step < 0.25 * full


def test_frames_of_other_sizes_and_none():
    moved, shifts = spread_correction([np.eye(3), translation(5.0, 0.0)], [(W, H), (160, 120)], translation(10.0, 0.0),
                                      translation(13.0, 0.0))
    np.testing.assert_allclose(moved[0], translation(1.0, 0.0), atol=1e-9)   # a third of 3 px
    np.testing.assert_allclose(moved[1], translation(7.0, 0.0), atol=1e-9)   # two thirds
    np.testing.assert_allclose(shifts, [1.0, 2.0])
    assert spread_correction([], [], np.eye(3), np.eye(3))[0] == []


def test_footprint_pose_is_the_centre_and_the_direction_the_frame_faces():
    np.testing.assert_allclose(footprint_pose(np.eye(3), W, H), [W / 2, H / 2, 0.0], atol=1e-12)
    angle = np.radians(120.0)
    c, s = np.cos(angle), np.sin(angle)
    turned = translation(500.0, 300.0) @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ translation(-W / 2, -H / 2)
    np.testing.assert_allclose(footprint_pose(turned, W, H), [500.0, 300.0, angle], atol=1e-9)
    # projective: the centre is the mapped centre, not the mean of the mapped corners
    tilted = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1e-3, 1.0]])
    expected = apply_homography(tilted, np.array([W / 2, H / 2]))
    np.testing.assert_allclose(footprint_pose(tilted, W, H)[:2], expected, atol=1e-9)
