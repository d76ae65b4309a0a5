"""Flat-ground homographies of a pinhole camera (dissertation 4.23-4.29).

Pure numpy, float64. Convention: image pixels (x right, y down, pixel centres at integer
coordinates, as K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] assumes); ground points (east, north)
in metres on the horizontal plane z = ``ground_z_m`` of the ENU frame; camera poses as in
:mod:`srmosaic_ros.core.georef.frames` (``X_enu = R_enu_from_cam @ X_cam + C_enu``). Every returned
homography is normalised so that h33 = 1 (4.29).
"""
from __future__ import annotations

import numpy as np

from ..homography import apply_homography as apply_H  # the georef modules' name
from .frames import CameraPose

__all__ = [
    'camera_pose_from_enu_H_image',
    'image_H_ground',
    'ground_H_image',
    'frame2_H_frame1',
    'apply_H',
    'normalize_H',
    'homographies_from_corners',
    'homography_from_corners',
]


def normalize_H(H: np.ndarray) -> np.ndarray:
    """H / h33 (4.29)."""
    H = np.asarray(H, dtype=np.float64)
    return H / H[2, 2]


def image_H_ground(K: np.ndarray, R_enu_from_cam: np.ndarray, C_enu: np.ndarray, *,
                   ground_z_m: float = 0.0) -> np.ndarray:
    """(3, 3) homography from ground (east, north, 1) to image pixels (x, y, 1).

    A ground point X = (e, n, z0) projects to x ~ K R_cam_from_enu (X - C). With
    X - C = M (e, n, 1), M = [[1, 0, -Cx], [0, 1, -Cy], [0, 0, z0 - Cz]]:
    image_H_ground = K R_enu_from_cam^T M.
    """
    C = np.asarray(C_enu, dtype=np.float64)
    M = np.array([[1.0, 0.0, -C[0]], [0.0, 1.0, -C[1]], [0.0, 0.0, ground_z_m - C[2]]])
    return normalize_H(np.asarray(K, dtype=np.float64) @ np.asarray(R_enu_from_cam, dtype=np.float64).T @ M)


def ground_H_image(K: np.ndarray, R_enu_from_cam: np.ndarray, C_enu: np.ndarray, *,
                   ground_z_m: float = 0.0) -> np.ndarray:
    """(3, 3) homography from image pixels (x, y, 1) to ground (east, north, 1) in metres.

    The inverse of :func:`image_H_ground`. Only pixels whose ray points below the horizon
    (third homogeneous coordinate of the result > 0 before normalisation) reach the ground.
    """
    return normalize_H(np.linalg.inv(image_H_ground(K, R_enu_from_cam, C_enu, ground_z_m=ground_z_m)))


def frame2_H_frame1(K: np.ndarray, R1_enu_from_cam: np.ndarray, C1_enu: np.ndarray,
                    R2_enu_from_cam: np.ndarray, C2_enu: np.ndarray, *, K2: np.ndarray | None = None,
                    ground_z_m: float = 0.0) -> np.ndarray:
    """(3, 3) homography from frame-1 pixels to frame-2 pixels induced by the ground plane.

    4.28 in this module's conventions: with R_i = R_cam_i_from_enu, N_w = (0, 0, 1) and
    d = C1_z - ground_z_m the height of camera 1 above the plane,
    H = K2 R_2 (I - (C1 - C2) N_w^T / d) R_1^T K^-1, then normalised (4.29). K2 defaults to K
    (one camera, 4.24).
    """
    K1 = np.asarray(K, dtype=np.float64)
    K2 = K1 if K2 is None else np.asarray(K2, dtype=np.float64)
    R1 = np.asarray(R1_enu_from_cam, dtype=np.float64).T
    R2 = np.asarray(R2_enu_from_cam, dtype=np.float64).T
    C1 = np.asarray(C1_enu, dtype=np.float64)
    C2 = np.asarray(C2_enu, dtype=np.float64)
    d = C1[2] - ground_z_m
    if abs(d) < 1e-12:
        msg = 'camera 1 lies on the ground plane; the plane-induced homography is undefined.'
        raise ValueError(msg)
    n_w = np.array([0.0, 0.0, 1.0])
    H = K2 @ R2 @ (np.eye(3) - np.outer(C1 - C2, n_w) / d) @ R1.T @ np.linalg.inv(K1)
    return normalize_H(H)


def homography_from_corners(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(3, 3) dst_H_src (h22 = 1) exactly mapping 4 points src (4, 2) to dst (4, 2), float64."""
    return homographies_from_corners(src, np.asarray(dst, float)[None])[0]


def homographies_from_corners(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(B, 3, 3) dst_H_src (h22 = 1) mapping the 4 points src (4, 2) to each of dst (B, 4, 2): one
    batched solve of the B 8x8 systems (a Jacobian by differences needs 16 of them per frame)."""
    x, y = (np.asarray(src, float)[:, k] for k in (0, 1))
    dst = np.asarray(dst, float)
    u, v = dst[..., 0], dst[..., 1]                       # (B, 4)
    n = dst.shape[0]
    one, zero = np.ones(4), np.zeros(4)
    A = np.zeros((n, 8, 8))
    A[:, 0::2, :6] = np.stack([x, y, one, zero, zero, zero], axis=1)
    A[:, 1::2, :6] = np.stack([zero, zero, zero, x, y, one], axis=1)
    A[:, 0::2, 6], A[:, 0::2, 7] = -u * x, -u * y
    A[:, 1::2, 6], A[:, 1::2, 7] = -v * x, -v * y
    b = dst.reshape(n, 8)                                 # u0, v0, u1, v1, ...
    h = np.linalg.solve(A, b[..., None])[..., 0]
    return np.concatenate([h, np.ones((n, 1))], axis=1).reshape(n, 3, 3)


def camera_pose_from_enu_H_image(K: np.ndarray, enu_H_image: np.ndarray, *,
                                 ground_z_m: float = 0.0) -> CameraPose:
    """Camera pose of a flat-ground homography: the inverse of :func:`ground_H_image`.

    image_H_ground = K R^T [e1, e2, P0 - C] up to scale (P0 = (0, 0, ground_z_m)); the two first
    columns give R (orthonormalised by SVD), the third the centre, with the sign that puts the
    camera above the ground.
    """
    K_inv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    A = K_inv @ np.linalg.inv(np.asarray(enu_H_image, dtype=np.float64))  # K^-1 image_H_ground
    lam = 0.5 * (np.linalg.norm(A[:, 0]) + np.linalg.norm(A[:, 1]))
    best = None
    for sign in (1.0, -1.0):
        B = sign * A / lam
        M = np.c_[B[:, 0], B[:, 1], np.cross(B[:, 0], B[:, 1])]  # columns: R^T e1, R^T e2, R^T e3
        u, _, vt = np.linalg.svd(M)
        Rt = u @ vt  # R_cam_from_enu
        if np.linalg.det(Rt) < 0:
            continue
        R = Rt.T  # R_enu_from_cam
        center = np.array([0.0, 0.0, ground_z_m]) - R @ B[:, 2]
        if center[2] > ground_z_m and best is None:
            best = CameraPose(R, center)
    if best is None:
        msg = 'the homography does not describe a camera above the ground plane.'
        raise ValueError(msg)
    return best
