"""Live super-resolution: a bounded store of registered frames, tile planning on it, tile placement.

ROS-free helpers of the SR node (nodes/sr_node.py), usable by any other driver:

    store = LiveFrameStore(pending=100, kept=64)
    store.add_image(stamp_ns, payload)                      # as frames arrive (payload: anything)
    store.add_registration(stamp_ns, segment, seg_H_frame)  # when the mosaic placed the frame
    plans = plan_live_tiles(store.registered(segment), sizes, tile_config, done)
    image, placement = reconstruct_live_tile(plan, frames, sr_config, segment)

Placement (the tiles.json convention of DESIGN.md, on the segment plane instead of mosaic.png):
an SR tile covers the region (x0, y0, width, height) of the segment plane, the pixel plane of
``seg_H_frame`` in /srmosaic/registration (with georeferencing, the shared north-up UTM raster);
it has ``height * factor`` rows and ``width * factor`` columns, and tile pixel (u, v) shows plane
point (x0 + (u + 0.5) / factor - 0.5, y0 + (v + 0.5) / factor - 0.5).
:class:`SRTilePlacement` writes and parses the text form carried in the tile's header.frame_id::

    srmosaic_segment_0;x0=256;y0=-128;width=128;height=128;factor=2
"""
from __future__ import annotations

import collections
import dataclasses
import math
import os
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..core.homography import translation as _translation
from ..core.metrics import apply_homography
from ..core.sr.reconstruct import SRConfig, SRError
from ..core.sr.self_check import reconstruct_checked_tile
from ..core.sr.scheduler import SRTileConfig, TilePlan, plan_tiles
from ..errors import SrMosaicError
from .placement import ImagePlacement, SRTilePlacement

__all__ = ['ImagePlacement', 'LiveFrame', 'LiveFrameStore', 'SRTilePlacement', 'plan_live_tiles', 'reconstruct_live_tile',
           'MAX_PLAN_SIDE_PX']

#: Planning grids larger than this (segment-plane pixels per side) are refused: an absurd
#: homography must not allocate a giant coverage raster.
MAX_PLAN_SIDE_PX = 20000
_UNCAPPED = 1 << 40

@dataclass
class LiveFrame:
    """A registered frame kept for SR: stamp (ns), payload (the image or a message to decode on
    demand), seg_H_frame (3, 3) frame pixels -> segment plane pixels, segment index."""

    stamp_ns: int
    payload: Any
    seg_H_frame: np.ndarray
    segment: int


class LiveFrameStore:
    """Bounded store: received images waiting for their registration, and registered frames.

    pending: at most this many images wait for a registration (older ones are dropped: the mosaic
        stage skipped them or is further behind than the store reaches).
    kept: at most this many registered frames per store (the oldest go first); a new segment
        drops the frames of the older ones (SR tiles come from one plane).
    Not thread-safe: callers lock around it.
    """

    def __init__(self, pending: int = 100, kept: int = 64) -> None:
        if pending < 1 or kept < 1:
            msg = f'the live SR store needs pending >= 1 and kept >= 1, got {pending} and {kept}.'
            raise SrMosaicError(msg)
        self._pending: collections.OrderedDict[int, Any] = collections.OrderedDict()
        self._pending_max = int(pending)
        self._frames: collections.deque[LiveFrame] = collections.deque(maxlen=int(kept))
        self.added = 0  # registered frames ever added (a change means new work for the planner)
        self.missed = 0  # registrations whose image was not (or no longer) in the store
        # of those, registrations of an image the store had dropped for room (pending too small for
        # how late the registrations come), as far as the newest stamp dropped tells
        self.missed_dropped = 0
        self._dropped_newest: int | None = None

    def add_image(self, stamp_ns: int, payload: Any) -> None:
        self._pending[int(stamp_ns)] = payload
        self._pending.move_to_end(int(stamp_ns))
        while len(self._pending) > self._pending_max:
            dropped, _ = self._pending.popitem(last=False)
            self._dropped_newest = max(dropped, self._dropped_newest or dropped)

    def add_registration(self, stamp_ns: int, segment: int, seg_H_frame: np.ndarray | None) -> bool:
        """The mosaic placed (segment >= 0, finite seg_H_frame) or skipped the frame at stamp_ns.

        Returns True when a frame was added to the registered store."""
        payload = self._pending.pop(int(stamp_ns), None)
        if segment < 0 or seg_H_frame is None or not np.all(np.isfinite(seg_H_frame)):
            return False
        if payload is None:
            self.missed += 1
            if self._dropped_newest is not None and int(stamp_ns) <= self._dropped_newest:
                self.missed_dropped += 1
            return False
        if self._frames and self._frames[-1].segment != segment:
            keep = [f for f in self._frames if f.segment == segment]
            self._frames.clear()
            self._frames.extend(keep)
        self._frames.append(LiveFrame(int(stamp_ns), payload, np.asarray(seg_H_frame, dtype=np.float64),
                                      int(segment)))
        self.added += 1
        return True

    @property
    def segment(self) -> int | None:
        """The segment of the newest registered frame (None while empty)."""
        return self._frames[-1].segment if self._frames else None

    def registered(self, segment: int | None = None) -> list[LiveFrame]:
        """Registered frames (of `segment`, default: the newest one), oldest first."""
        seg = self.segment if segment is None else segment
        return [f for f in self._frames if f.segment == seg]

    @property
    def pending(self) -> int:
        return len(self._pending)


def plan_live_tiles(frames: Sequence[LiveFrame], sizes: dict[int, tuple[int, int]], config: SRTileConfig,
                    done: Collection[tuple[int, int, int]] | Mapping[tuple[int, int, int], int] | None = None, *,
                    refresh_growth: float = 0.0) -> list[tuple[TilePlan, list[LiveFrame]]]:
    """Tiles of the segment plane that enough of `frames` cover (core/sr/scheduler.plan_tiles).

    frames: registered frames of one segment; sizes: stamp_ns -> (width, height) of each frame.
    The tile grid is anchored at plane pixel (0, 0) (tiles at multiples of tile_size, negative
    ones included); the coverage raster is the union of the frames' footprints over their
    bounding box.

    done: the tiles published already, as (segment, x0, y0) keys; a mapping gives for each the
    number of frames its last publication was reconstructed from. A published tile is left out,
    unless `refresh_growth` > 0, `done` is such a mapping and the plan would now use at least
    refresh_growth times as many frames (a revisit, or frames that arrived after the first
    publication): it is planned again, a refresh.
    Returns (plan with plane coordinates, the LiveFrames it uses): tiles never published first,
    best covered first, then refreshes, largest frame gain first.
    """
    if not frames:
        return []
    t = config.tile_size
    corners = []
    for f in frames:
        w, h = sizes[f.stamp_ns]
        quad = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], dtype=float)
        corners.append(apply_homography(f.seg_H_frame, quad))
    pts = np.concatenate(corners)
    if not np.all(np.isfinite(pts)):
        return []
    gx0 = int(math.floor(pts[:, 0].min() / t)) * t
    gy0 = int(math.floor(pts[:, 1].min() / t)) * t
    gw = int(math.ceil((pts[:, 0].max() + 1 - gx0) / t)) * t
    gh = int(math.ceil((pts[:, 1].max() + 1 - gy0) / t)) * t
    if max(gw, gh) > MAX_PLAN_SIDE_PX:
        return []
    coverage = np.zeros((gh, gw), np.uint8)
    for quad in corners:
        cv2.fillConvexPoly(coverage, np.round(quad - [gx0, gy0]).astype(np.int32), 1)
    shift = _translation(-gx0, -gy0)
    by_index = dict(enumerate(frames))
    # Every eligible tile, capped to max_tiles only after the published ones are left out (a cap
    # before would let tiles published long ago crowd the new ones out of every later plan).
    plans = plan_tiles({k: shift @ f.seg_H_frame for k, f in by_index.items()},
                       {k: sizes[f.stamp_ns] for k, f in by_index.items()}, coverage > 0,
                       dataclasses.replace(config, max_tiles=_UNCAPPED))
    fresh, refresh = [], []
    seg = frames[-1].segment
    counts = done if isinstance(done, Mapping) else None
    for p in plans:
        x0, y0 = p.x0 + gx0, p.y0 + gy0
        entry = (TilePlan(x0, y0, p.width, p.height, p.frames, p.frames_covering), [by_index[k] for k in p.frames])
        if done is None or (seg, x0, y0) not in done:
            fresh.append(entry)
        elif counts is not None and refresh_growth > 0 and len(p.frames) >= refresh_growth * counts[seg, x0, y0]:
            refresh.append((len(p.frames) / max(counts[seg, x0, y0], 1), entry))
    refresh.sort(key=lambda r: -r[0])  # stable: equal gains keep the best-covered-first order
    return (fresh + [entry for _, entry in refresh])[:config.max_tiles]


def reconstruct_live_tile(plan: TilePlan, images: Sequence[np.ndarray], seg_H_frames: Sequence[np.ndarray],
                          factor: int, config: SRConfig, segment: int) -> tuple[np.ndarray, SRTilePlacement, Any]:
    """Super-resolve one planned tile (core/sr/self_check.reconstruct_checked_tile).

    images: (h, w) or (h, w, 3) uint8/uint16 frames; seg_H_frames: their (3, 3) frame -> plane maps.
    Returns (tile (H s, W s[, 3]) uint8, its placement, the SRResult); raises SRError when no frame
    observes the tile, its frames disagree (core/sr/consistency.py) or it predicts a held-out frame
    no better than the mosaic (core/sr/self_check.py).
    """
    tile_H = [_translation(-plan.x0, -plan.y0) @ H for H in seg_H_frames]
    res = reconstruct_checked_tile(list(images), tile_H, (plan.height, plan.width), factor, config)
    image = res.to_numpy()
    if image.shape[2] == 1:
        image = image[:, :, 0]
    return image, SRTilePlacement(segment, plan.x0, plan.y0, plan.width, plan.height, factor), res


def reconstruct_live_tile_image(plan: TilePlan, images: Sequence[np.ndarray], seg_H_frames: Sequence[np.ndarray],
                                factor: int, config: SRConfig, segment: int) -> tuple[np.ndarray, SRTilePlacement, str]:
    """:func:`reconstruct_live_tile` for a worker process: (tile, placement, the solver's stop reason),
    leaving the SRResult's tensors in the worker."""
    image, placement, res = reconstruct_live_tile(plan, images, seg_H_frames, factor, config, segment)
    return image, placement, str(res.stop_reason)


def init_sr_worker_process(torch_threads: int, niceness: int = 10, parent_pid: int | None = None) -> None:
    """Initializer of the SR worker process: lowest priority (niceness, and SCHED_IDLE where Linux
    allows it: SR is background work and must not take the CPU from registration), torch threads, SIGINT left to the parent (which shuts the worker
    down), and the SR modules imported now rather than at the first tile. The worker ends itself
    when ``parent_pid`` (default: its parent at start) is no longer its parent."""
    import signal
    import threading
    import time

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A node killed outright (SIGKILL, OOM) cannot shut its pool down: the worker would finish its
    # tile and idle on for minutes, holding its memory. It leaves as soon as it is orphaned.
    parent = os.getppid() if parent_pid is None else parent_pid  # the node may have died while we started

    def watch_parent() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(0)

    threading.Thread(target=watch_parent, name='sr-worker-parent-watch', daemon=True).start()
    try:
        os.nice(niceness)
    except (AttributeError, OSError):
        pass
    try:  # Linux: run only on otherwise idle CPU time (a niceness still takes ~10% of a busy core)
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        pass
    import torch

    if torch_threads > 0:
        torch.set_num_threads(torch_threads)


def sr_worker_ready() -> bool:
    """A no-op task: submitted once at start so that the worker process is up before the first tile."""
    return True


__all__ += ['SRError', 'init_sr_worker_process', 'reconstruct_live_tile_image', 'sr_worker_ready']
