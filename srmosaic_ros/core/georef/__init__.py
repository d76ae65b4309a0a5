"""Georeferencing: frame transforms, geodetic <-> local ENU, flat-ground homographies, the pose UKF.

The UKF and the Georeferencer import filterpy (slow to import): they load on first use, so that
``import srmosaic_ros.core.georef.frames`` stays light.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

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


def __getattr__(name: str) -> Any:  # PEP 562 lazy attributes
    if name in _LAZY:
        return getattr(importlib.import_module(f'.{_LAZY[name]}', __name__), name)
    msg = f'module {__name__!r} has no attribute {name!r}'
    raise AttributeError(msg)


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
