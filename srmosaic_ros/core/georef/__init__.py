"""Georeferencing: frame transforms, geodetic <-> local ENU, flat-ground homographies, the pose UKF.

The UKF and the Georeferencer import filterpy (slow to import): they load on first use, so that
``import srmosaic_ros.core.georef.frames`` stays light.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..lazy import lazy_attributes

if TYPE_CHECKING:
    from .georeferencer import (
        FramePose,
        GeoRaster,
        GeorefConfig,
        Georeferencer,
        camera_pose_from_enu_H_image,
        utm_epsg,
    )
    from .ground_homography import homography_from_corners
    from .ukf import CameraMount, PoseUkf, UkfParams, UpdateResult

_LAZY = {
    'FramePose': 'georeferencer',
    'GeoRaster': 'georeferencer',
    'GeorefConfig': 'georeferencer',
    'Georeferencer': 'georeferencer',
    'camera_pose_from_enu_H_image': 'georeferencer',
    'homography_from_corners': 'ground_homography',
    'utm_epsg': 'georeferencer',
    'CameraMount': 'ukf',
    'PoseUkf': 'ukf',
    'UkfParams': 'ukf',
    'UpdateResult': 'ukf',
}

__all__ = [
    'CameraMount',
    'FramePose',
    'GeoRaster',
    'GeorefConfig',
    'Georeferencer',
    'PoseUkf',
    'UkfParams',
    'UpdateResult',
    'camera_pose_from_enu_H_image',
    'homography_from_corners',
    'utm_epsg',
]

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, globals())  # PEP 562
