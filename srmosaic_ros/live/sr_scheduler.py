"""SRTileScheduler: the SR node's frames and which tiles each round makes (no ROS).

    scheduler = SRTileScheduler(tile_config, pending=100, kept=48, order=stream_order)
    scheduler.add_image(stamp_ns, msg)                      # image callback (kept, decoded later)
    scheduler.add_registration(stamp_ns, segment, seg_H)    # registration callback
    for job in scheduler.plan(decode, tiles_per_round):     # worker: the tiles of this round
        ...                                                 # job.plan, job.frames, job.refresh

The frames live in a live.sr.LiveFrameStore (``pending`` images waiting for their registration,
``kept`` registered frames of the newest segment). A round plans with live.sr.plan_live_tiles: tiles
never published first, then tiles that ``refresh_growth`` times as many frames now cover (a
revisit). The tiles published are remembered for the newest segment only. A round that found
nothing is not planned again until a frame is registered.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.sr.scheduler import SRTileConfig, TilePlan
from .sr import LiveFrame, LiveFrameStore, plan_live_tiles

__all__ = ['SRJob', 'SRTileScheduler']


@dataclass
class SRJob:
    """One tile of a round: its plan, the frames it uses (oldest first), whether it was published before."""

    plan: TilePlan
    frames: list[LiveFrame]
    refresh: bool

    @property
    def segment(self) -> int:
        return self.frames[-1].segment


class SRTileScheduler:
    """The frame store, the frame sizes and the tiles published (module docstring). ``order``: the
    node's StreamOrder (``accept(stream, stamp_ns) -> bool``). Thread-safe: the callbacks add while
    the worker plans."""

    def __init__(self, config: SRTileConfig, *, pending: int, kept: int, order: Any, refresh_growth: float) -> None:
        self.refresh_growth = float(refresh_growth)
        self._config = config
        self._store = LiveFrameStore(pending=pending, kept=kept)
        self._lock = threading.Lock()
        self._order = order
        self._sizes: dict[int, tuple[int, int]] = {}  # stamp_ns -> (width, height)
        # (segment, x0, y0) of each published tile -> frames its last publication was made from
        self._done: dict[tuple[int, int, int], int] = {}
        self._planned_at = -1  # store.added at the last round that found nothing to do

    def add_image(self, stamp_ns: int, payload: Any) -> None:
        """An image (kept as it came: decoded only when a tile uses it), if its stamp is in order."""
        with self._lock:
            if self._order.accept('image', stamp_ns):
                self._store.add_image(stamp_ns, payload)

    def add_registration(self, stamp_ns: int, segment: int, seg_H_frame: np.ndarray | None) -> bool:
        """The mosaic placed (segment >= 0) or skipped the frame; True when its registration came after
        its image had been dropped for room (live.sr_images_pending too small)."""
        with self._lock:
            before = self._store.missed_dropped
            self._store.add_registration(stamp_ns, segment, seg_H_frame)
            return self._store.missed_dropped > before

    def counts(self) -> tuple[int, int, int]:
        """(registered frames kept, images waiting for their registration, registrations without image)."""
        with self._lock:
            return len(self._store.registered()), self._store.pending, self._store.missed

    def plan(self, decode: Callable[[LiveFrame], np.ndarray | None], most: int, *,
             header_size: Callable[[Any], tuple[int, int] | None]) -> list[SRJob]:
        """Up to ``most`` tiles to make now. Frame sizes: ``header_size(payload)`` (width, height)
        where the message says it (an Image), else ``decode(frame)``'s pixels (None: unusable) of the
        newest frame, once per round, for the others too (the frames of one stream share a size)."""
        with self._lock:
            if self._store.added == self._planned_at:
                return []  # nothing new since a round found no tile
            frames = self._store.registered()
            added = self._store.added
        stream_size = None
        for f in reversed(frames):
            if f.stamp_ns in self._sizes:
                continue
            if (size := header_size(f.payload)) is not None:
                self._sizes[f.stamp_ns] = size
                continue
            if stream_size is None:
                image = decode(f)
                if image is None:
                    continue
                stream_size = (image.shape[1], image.shape[0])
            self._sizes[f.stamp_ns] = stream_size
        frames = [f for f in frames if f.stamp_ns in self._sizes]
        live = {f.stamp_ns for f in frames}
        self._sizes = {k: v for k, v in self._sizes.items() if k in live}
        if frames and any(key[0] != frames[-1].segment for key in self._done):
            # the store keeps the newest segment only: older segments' tiles can never come again
            self._done = {key: n for key, n in self._done.items() if key[0] == frames[-1].segment}
        plans = plan_live_tiles(frames, self._sizes, self._config, self._done, refresh_growth=self.refresh_growth)
        if not plans:
            self._planned_at = added
            return []
        jobs = []
        for plan, used in plans[:most]:
            key = (used[-1].segment, plan.x0, plan.y0)
            jobs.append(SRJob(plan, used, key in self._done))
            self._done[key] = len(used)  # taken, whether it succeeds or is left to the mosaic
        return jobs
