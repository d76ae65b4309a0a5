"""Lens distortion removed at the input edge, so that every later stage sees a pinhole camera.

Two views of a plane are related by a homography only through a pinhole camera: with the barrel
distortion of a small UAS lens (k1 ~ -0.1 to -0.3) the registration's residuals and the mosaic's
seams grow toward the frame edges, and georeferenced footprints bend. A frame whose intrinsics
carry distortion (CameraInfo.d, or a calibration YAML) is therefore remapped once, on arrival, to
the pinhole camera that keeps every output pixel inside the original image (OpenCV's
getOptimalNewCameraMatrix with alpha = 0: no black border to paint into the mosaic; for a barrel
lens the new focal length is a few percent longer), and carries that camera from then on.

Models (sensor_msgs/CameraInfo distortion_model): ``plumb_bob`` and ``rational_polynomial``
(cv2.undistort's radial-tangential model, 4, 5, 8, 12 or 14 coefficients) and ``equidistant``
(fisheye, 4 coefficients). Other models with non-zero coefficients are refused with the way out
(rectify upstream, image_proc, and publish a camera with zero distortion, or set
``undistort: false`` for images that are rectified already).

The remap tables are built once per camera (building one costs several times applying it).
"""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ..errors import InputError
from .types import CameraIntrinsics, Frame

__all__ = ['SUPPORTED_MODELS', 'Undistorter', 'pinhole_of']

SUPPORTED_MODELS = ('plumb_bob', 'rational_polynomial', 'equidistant')
_RADTAN_SIZES = (4, 5, 8, 12, 14)


def _check(camera: CameraIntrinsics) -> None:
    model = camera.distortion_model or 'plumb_bob'
    n = len(camera.distortion)
    if model not in SUPPORTED_MODELS:
        msg = (f'camera distortion model {model!r} with coefficients {list(camera.distortion)} is not supported '
               f'(supported: {", ".join(SUPPORTED_MODELS)}); rectify the images upstream (image_proc) and give '
               'a camera with zero distortion, or set undistort: false if the images are rectified already.')
        raise InputError(msg)
    if (model == 'equidistant' and n != 4) or (model != 'equidistant' and n not in _RADTAN_SIZES):
        msg = (f'camera distortion model {model!r} with {n} coefficients: expected '
               f'{"4" if model == "equidistant" else " or ".join(map(str, _RADTAN_SIZES))}.')
        raise InputError(msg)


def pinhole_of(camera: CameraIntrinsics) -> tuple[CameraIntrinsics, np.ndarray, np.ndarray]:
    """(the pinhole camera of the undistorted image, remap tables map_x, map_y (H, W) float32)."""
    _check(camera)
    size = (camera.width, camera.height)
    K = camera.K
    D = np.asarray(camera.distortion, dtype=np.float64)
    if camera.distortion_model == 'equidistant':
        K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, size, np.eye(3), balance=0.0)
        map_x, map_y = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), K_new, size, cv2.CV_32FC1)
    else:
        K_new, _ = cv2.getOptimalNewCameraMatrix(K, D, size, 0.0, size)  # alpha 0: all pixels valid
        map_x, map_y = cv2.initUndistortRectifyMap(K, D, None, K_new, size, cv2.CV_32FC1)
    pinhole = CameraIntrinsics(camera.width, camera.height, float(K_new[0, 0]), float(K_new[1, 1]),
                               float(K_new[0, 2]), float(K_new[1, 2]))
    return pinhole, map_x, map_y


class Undistorter:
    """Frames with distortion -> frames of the equivalent pinhole camera (see the module docstring).

    Frames without a camera, or whose camera has no distortion, pass unchanged. ``undistorted``
    counts the frames remapped.
    """

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self.undistorted = 0
        self._tables: dict[CameraIntrinsics, tuple[CameraIntrinsics, np.ndarray, np.ndarray]] = {}

    def camera(self, camera: CameraIntrinsics | None) -> CameraIntrinsics | None:
        """The camera frames of ``camera`` will have after :meth:`image` (the same if nothing to do)."""
        if camera is None or not self.enabled or not camera.has_distortion:
            return camera
        return self._table(camera)[0]

    def image(self, image: np.ndarray, camera: CameraIntrinsics | None) -> np.ndarray:
        """``image`` (H, W[, C]) of ``camera`` remapped to its pinhole camera (bilinear)."""
        if camera is None or not self.enabled or not camera.has_distortion:
            return image
        h, w = image.shape[:2]
        if (w, h) != (camera.width, camera.height):
            msg = (f'a {w}x{h} image with the intrinsics of a {camera.width}x{camera.height} camera: the '
                   'distortion cannot be removed; send the CameraInfo of this image size.')
            raise InputError(msg)
        _, map_x, map_y = self._table(camera)
        self.undistorted += 1
        return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def frame(self, frame: Frame, camera: CameraIntrinsics | None = None) -> Frame:
        """``frame`` with its pixels undistorted and its camera the pinhole one; ``camera``: the
        intrinsics to use when the frame carries none (live: the latest CameraInfo)."""
        cam = frame.camera if frame.camera is not None else camera
        if cam is None or not self.enabled or not cam.has_distortion:
            return frame
        return dataclasses.replace(frame, image=self.image(frame.image, cam), camera=self.camera(cam))

    def _table(self, camera: CameraIntrinsics) -> tuple[CameraIntrinsics, np.ndarray, np.ndarray]:
        if camera not in self._tables:
            if len(self._tables) >= 4:  # a camera that changes (zoom): keep the latest few
                self._tables.pop(next(iter(self._tables)))
            self._tables[camera] = pinhole_of(camera)
        return self._tables[camera]
