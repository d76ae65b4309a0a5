"""Synthetic UAS flights over an orthophoto, with exact ground truth; written as rosbag2 bags.

``simulate(SimConfig(...))`` renders frames and telemetry; ``write_flight(flight, out_dir)`` writes
the bag and ``out_dir/ground_truth.json``; ``load_truth(path)`` reads the truth back.
"""
from __future__ import annotations

from .config import SimConfig
from .flight import SimulatedFlight, frame_intrinsics, sensor_intrinsics, simulate
from .record import write_flight
from .truth import FrameTruth, Truth, load_truth, save_truth

__all__ = [
    'FrameTruth',
    'SimConfig',
    'SimulatedFlight',
    'Truth',
    'frame_intrinsics',
    'load_truth',
    'save_truth',
    'sensor_intrinsics',
    'simulate',
    'write_flight',
]
