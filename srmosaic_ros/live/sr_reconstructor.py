"""SRReconstructor: where the SR node reconstructs its tiles, in a worker process or in the calling thread (no ROS).

``worker='process'`` (live.sr_worker, default) hands each tile to a worker process (spawned at
start, niceness 10, ``torch_threads`` threads), so that SR in the mosaic node's process takes
neither the interpreter lock nor the CPU from registration; ``'thread'`` reconstructs in the
calling thread. A worker process that dies (out of memory, killed) is reported once through
``warn``, replaced, and its tile raises SRError.
"""
from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np

from ..core.sr.reconstruct import SRConfig, SRError
from ..errors import SrMosaicError
from .sr import init_sr_worker_process, reconstruct_live_tile, reconstruct_live_tile_image, sr_worker_ready

__all__ = ['SRReconstructor']


class SRReconstructor:
    """Reconstructs SR tiles (module docstring). ``factor``: the SR factor; ``config``: the sr.* settings;
    ``warn``: the node's WarnOnce (``warn(kind, text)``)."""

    def __init__(self, worker: str, factor: int, config: SRConfig, torch_threads: int, warn: Any) -> None:
        if worker not in ('process', 'thread'):
            msg = f"live.sr_worker must be 'process' or 'thread', got {worker!r}."
            raise SrMosaicError(msg)
        self.worker = worker
        self.factor = int(factor)
        self._config = config
        self._torch_threads = int(torch_threads)
        self._warn = warn
        self._stopping = False
        self._pool = self._start_pool() if worker == 'process' else None

    def _start_pool(self) -> ProcessPoolExecutor:
        # spawn, not fork: this process runs DDS threads, which a fork would copy half-alive.
        pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                                   initializer=init_sr_worker_process, initargs=(self._torch_threads, 10, os.getpid()))
        pool.submit(sr_worker_ready)  # start it now, not at the first tile
        return pool

    def reconstruct(self, plan: Any, images: list[np.ndarray], seg_H_frames: list[np.ndarray],
                    segment: int) -> tuple[np.ndarray, Any, str]:
        """(tile image, SRTilePlacement, stop reason) of ``plan`` from the frames' images and homographies."""
        if self._pool is None:
            image, placement, res = reconstruct_live_tile(plan, images, seg_H_frames, self.factor, self._config, segment)
            return image, placement, str(res.stop_reason)
        try:
            return self._pool.submit(reconstruct_live_tile_image, plan, images, seg_H_frames, self.factor,
                                     self._config, segment).result()
        except BrokenProcessPool:
            if self._stopping:  # stop() ended the worker process
                raise SRError('the node is stopping: the tile in progress was abandoned') from None
            self._warn('sr worker died', 'the SR worker process died (out of memory or killed); it is restarted '
                       'and the tile skipped')
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None if self._stopping else self._start_pool()
            raise SRError('the SR worker process died') from None

    def abandon(self) -> None:
        """End the worker process now: a tile in progress is abandoned (ProcessPoolExecutor has no way
        to stop a running call before Python 3.14's terminate_workers(); its processes are in _processes)."""
        self._stopping = True
        if self._pool is not None:
            for proc in list((getattr(self._pool, '_processes', None) or {}).values()):
                proc.terminate()

    def close(self, wait: bool) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=wait, cancel_futures=True)
