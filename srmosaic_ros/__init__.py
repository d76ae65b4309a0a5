"""srmosaic_ros: super-resolution mosaicking of UAS video, live in ROS 2 or offline."""
from __future__ import annotations

__all__ = ['__version__']
__version__ = '0.1.0'
