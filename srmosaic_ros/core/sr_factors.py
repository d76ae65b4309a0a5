"""The SR factors offered: sr_tiles.factor and `srmosaic process --sr-factor` take one of these.

One declaration, light to import (the command line checks --sr-factor before loading torch): the
SR tile settings (core/sr/scheduler.py), the ROS parameter's range (nodes/parameters.py) and the
command line's check and help read it.
"""
from __future__ import annotations

__all__ = ['SR_FACTORS']

SR_FACTORS = (2, 3, 4)
