"""The live map's changed tiles: which canvas tiles go on the wire, when, and how they are encoded.

ROS-free helpers of the mosaic node (nodes/mosaic_node.py) and of the map server's source
(web/live_source.py):

    queue = ChangedTiles(bytes_per_s=1e6)
    queue.mark(keys, now_s)                     # tiles the canvas painted (canvas.pop_touched())
    for key in queue.candidates(now_s):         # oldest change first, as many as the budget may take
        data = encode_tile(*canvas.tile_blocks(key[1:], 2 ** level))
        if not queue.allowed(now_s):
            break                               # the rest wait for the next round (none is lost)
        publish(key, data); queue.sent(key, len(data), now_s)

A tile on the wire is a PNG (RGBA, alpha 0 where nothing is painted) of one canvas tile reduced by
2^level, with its place on the live plane as an :class:`ImagePlacement` (the header.frame_id of
/srmosaic/map_tile): ``srmosaic_segment_<k>;x0=<int>;y0=<int>;width=<T>;height=<T>`` with the
image T / 2^level pixels on a side; /srmosaic/raster (live/raster.py) puts the plane on the map
(``LiveRaster.image_geotransform(frame_id, n, n)``).

The budget is a token bucket (bytes): it fills at ``bytes_per_s`` up to ``burst_s`` seconds of it,
a tile is sent while the bucket holds more than nothing, and its bytes are taken out (the bucket may
go below zero by the last tile, which the next rounds pay back). Over any interval of T seconds the
bytes sent are then at most ``bytes_per_s * (T + burst_s)`` plus one tile.
"""
from __future__ import annotations

import base64
import collections
import json
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..errors import SrMosaicError
from .raster import ImagePlacement

__all__ = ['FOOTPRINT_FRAME', 'MAP_TILE_FORMAT', 'SUMMARY_VERSION', 'ChangedTiles', 'MapTileKey', 'MapTileStream', 'encode_tile', 'decode_tile',
           'placement_of', 'summary_text', 'whole_map_text', 'parse_whole_map']

#: header.frame_id of /srmosaic/footprint (geometry_msgs/PolygonStamped): its points are pixels (x right,
#: y down, centres at integers) of the /srmosaic/raster grid: LiveRaster.utm_H_raster puts them in UTM.
FOOTPRINT_FRAME = 'srmosaic_raster'
#: CompressedImage.format of /srmosaic/map_tile
MAP_TILE_FORMAT = 'png'
#: 'version' of the summary (/srmosaic/map_tiles) and of the whole map (the srmosaic/get_map service):
#: keys are only ever added.
SUMMARY_VERSION = 1

#: (segment that owns the canvas, tile column tx, tile row ty)
MapTileKey = tuple[int, int, int]


def placement_of(key: MapTileKey, tile_size: int) -> ImagePlacement:
    """The live-plane region of canvas tile ``key`` (tiles of ``tile_size`` plane pixels)."""
    segment, tx, ty = key
    return ImagePlacement(int(segment), int(tx) * tile_size, int(ty) * tile_size, tile_size, tile_size)


def encode_tile(image: np.ndarray, covered: np.ndarray, level: int = 6) -> bytes:
    """PNG bytes (RGBA, 8 bits) of a reduced tile: ``image`` float32 (n, n, C) or (n, n) in [0, 1]
    (C = 1 grey, 3 RGB; other C: the mean as grey), ``covered`` bool (n, n) -> alpha 255 / 0 (and
    the colour 0 where uncovered, so that empty pixels compress to nothing). ``level``: zlib's 0..9."""
    img = np.asarray(image, np.float32)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] != 3:
        img = img.mean(axis=2)
    u8 = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    rgb = np.repeat(u8[:, :, None], 3, axis=2) if u8.ndim == 2 else u8
    alpha = np.where(covered, 255, 0).astype(np.uint8)
    bgra = np.dstack([rgb[:, :, ::-1], alpha])
    bgra[~covered] = 0
    ok, buf = cv2.imencode('.png', bgra, [cv2.IMWRITE_PNG_COMPRESSION, int(level)])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 BGRA array
        msg = f'a map tile of shape {bgra.shape} could not be encoded as PNG.'
        raise SrMosaicError(msg)
    return buf.tobytes()


def decode_tile(data: bytes) -> np.ndarray:
    """RGBA uint8 (n, m, 4) of a tile's PNG (or any image OpenCV reads; opaque when it has no alpha);
    SrMosaicError when the bytes are not an image."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if img is None:
        msg = f'a map tile of {len(data)} bytes is not an image OpenCV can read.'
        raise SrMosaicError(msg)
    if img.dtype != np.uint8:
        img = (img >> 8).astype(np.uint8) if img.dtype == np.uint16 else np.clip(img, 0, 255).astype(np.uint8)
    if img.ndim == 2:
        return np.dstack([img, img, img, np.full_like(img, 255)])
    if img.shape[2] == 3:
        return np.dstack([img[:, :, ::-1], np.full(img.shape[:2], 255, np.uint8)])
    return np.ascontiguousarray(img[:, :, [2, 1, 0, 3]])


@dataclass
class _Budget:
    rate: float  # bytes per second; 0: no budget
    burst_s: float
    credit: float = 0.0
    last_s: float | None = None

    def refill(self, now_s: float) -> None:
        if self.last_s is None:
            self.credit = self.rate * self.burst_s
        else:
            self.credit = min(self.credit + self.rate * max(now_s - self.last_s, 0.0), self.rate * self.burst_s)
        self.last_s = now_s


class ChangedTiles:
    """Tiles changed and not yet sent, oldest change first, and the bandwidth budget (module docstring).

    bytes_per_s: the budget (0: none, every changed tile goes each round); burst_s: the seconds of
    budget the bucket holds at most. A tile changed again while it waits keeps its place (its first
    change); a tile sent and changed again joins the end. Not thread-safe: callers lock around it.
    """

    def __init__(self, bytes_per_s: float = 0.0, burst_s: float = 1.0) -> None:
        if not (bytes_per_s >= 0 and np.isfinite(bytes_per_s)) or not burst_s > 0:
            msg = f'the map tile budget needs bytes_per_s >= 0 (0: none) and burst_s > 0, got {bytes_per_s} and {burst_s}.'
            raise SrMosaicError(msg)
        self._budget = _Budget(float(bytes_per_s), float(burst_s))
        self._pending: collections.OrderedDict[MapTileKey, float] = collections.OrderedDict()
        self.bytes_sent = 0
        self.tiles_sent = 0
        self._mean_bytes = 0.0  # of the tiles sent, a running mean (how many to render for a round)

    @property
    def bytes_per_s(self) -> float:
        return self._budget.rate

    @bytes_per_s.setter
    def bytes_per_s(self, value: float) -> None:
        self._budget.rate = float(value)

    def mark(self, keys: Iterable[MapTileKey], now_s: float) -> None:
        """Tiles painted since the last call; those already waiting keep their place."""
        for key in keys:
            self._pending.setdefault(key, now_s)

    @property
    def pending(self) -> int:
        return len(self._pending)

    def waiting_since(self) -> float | None:
        """When the oldest waiting tile changed (None: none waits)."""
        return next(iter(self._pending.values()), None)

    def candidates(self, now_s: float, most: int = 256) -> list[MapTileKey]:
        """The waiting tiles this round may send, oldest change first: all of them (up to ``most``)
        without a budget; else about as many as the budget holds at the mean size sent so far, plus one."""
        self._budget.refill(now_s)
        keys = list(self._pending)
        if self._budget.rate <= 0:
            return keys[:most]
        if self._budget.credit <= 0:
            return []
        n = int(self._budget.credit / self._mean_bytes) + 1 if self._mean_bytes > 0 else 1
        return keys[:min(n, most)]

    def allowed(self) -> bool:
        """Whether the budget takes another tile this round (it holds more than nothing)."""
        return self._budget.rate <= 0 or self._budget.credit > 0

    def sent(self, key: MapTileKey, nbytes: int) -> None:
        """``key`` went out in ``nbytes``: it leaves the queue, its bytes leave the budget."""
        self._pending.pop(key, None)
        self.spend(nbytes)
        self.tiles_sent += 1
        self._mean_bytes += (nbytes - self._mean_bytes) / min(self.tiles_sent, 50)

    def spend(self, nbytes: int) -> None:
        """Bytes sent besides tiles (the summary) also leave the budget."""
        self.bytes_sent += int(nbytes)
        if self._budget.rate > 0:
            self._budget.credit -= int(nbytes)


def summary_text(level: int, tile_px: int, tiles: Iterable[tuple[str, int]], pending: int, bytes_sent: int) -> str:
    """The JSON of /srmosaic/map_tiles (transient local: a late subscriber gets the last one)::

        {"version": 1, "format": "png", "level": 1, "tile_px": 128, "pending": 3, "bytes_sent": 123456,
         "tiles": [["srmosaic_segment_0;x0=0;y0=256;width=256;height=256", 1733590000000000000], ...]}

    tiles: every tile sent so far, with the stamp (ns) of its latest version; pending: changed tiles
    still waiting for the budget; tile_px: the side of each tile's image."""
    return json.dumps({'version': SUMMARY_VERSION, 'format': MAP_TILE_FORMAT, 'level': int(level), 'tile_px': int(tile_px),
                       'pending': int(pending), 'bytes_sent': int(bytes_sent),
                       'tiles': [[frame_id, int(stamp)] for frame_id, stamp in tiles]})


def whole_map_text(level: int, tile_px: int, tiles: Iterable[tuple[str, int, bytes]], pending: int) -> str:
    """The JSON the srmosaic/get_map service answers (std_srvs/Trigger's message): every tile sent
    so far, its newest version, with its PNG in base64, and how many changed tiles still wait::

        {"version": 1, "format": "png", "level": 1, "tile_px": 128,
         "tiles": [{"frame_id": "...", "stamp_ns": 1733590000000000000, "data": "<base64 PNG>"}, ...],
         "pending": 3}"""
    return json.dumps({'version': SUMMARY_VERSION, 'format': MAP_TILE_FORMAT, 'level': int(level), 'tile_px': int(tile_px),
                       'tiles': [{'frame_id': f, 'stamp_ns': int(s), 'data': base64.b64encode(d).decode('ascii')}
                                 for f, s, d in tiles],
                       'pending': int(pending)})


def parse_whole_map(text: str) -> list[tuple[str, int, bytes]]:
    """The tiles (frame_id, stamp_ns, PNG bytes) of :func:`whole_map_text`; SrMosaicError on other text."""
    try:
        doc = json.loads(text)
        return [(str(t['frame_id']), int(t['stamp_ns']), base64.b64decode(t['data'], validate=True)) for t in doc['tiles']]
    except (ValueError, KeyError, TypeError) as exc:
        msg = f'not a srmosaic/get_map answer ({type(exc).__name__}: {exc}); expected the JSON of live/map_tiles.py.'
        raise SrMosaicError(msg) from None


class MapTileStream:
    """The mosaic node's side of /srmosaic/map_tile, without ROS: changed tiles of the pipeline's
    canvases, reduced, encoded, under the budget; what was sent (the summary and the whole map).

        batch = stream.collect(pipeline.segments, now_s)       # under the pipeline lock: cheap copies
        for frame_id, data in stream.encode(batch, stamp_ns):  # outside it: PNG, within the budget
            publish(frame_id, data)

    level: each canvas tile is reduced by 2^level (at most to the largest power of two that divides
    the tile size); bytes_per_s: the budget (0: none). The sent tiles' newest bytes are kept (for
    the whole map a late joiner asks for): about the map's size as PNGs at that level. Thread-safe.
    """

    def __init__(self, level: int = 1, bytes_per_s: float = 0.0, *, burst_s: float = 1.0) -> None:
        if not 0 <= int(level) <= 12:
            msg = f'live.map_level must be in 0..12 (each tile reduced by 2^level), got {level}.'
            raise SrMosaicError(msg)
        self.level = int(level)
        self.queue = ChangedTiles(bytes_per_s, burst_s)
        self._lock = threading.Lock()
        self._owners: dict[int, int] = {}  # id(canvas) -> the first segment painted on it
        self._sent: dict[MapTileKey, tuple[str, int, bytes]] = {}  # frame_id, stamp_ns, PNG
        self.tile_px = 0  # side of the images sent (0: none yet)

    def reduction(self, tile_size: int) -> int:
        """The factor f = 2^l (l <= level) tiles of ``tile_size`` are reduced by."""
        f = 1
        while f < (1 << self.level) and tile_size % (2 * f) == 0:
            f *= 2
        return f

    def collect(self, segments: Sequence[Any], now_s: float, *,
                send: bool = True) -> list[tuple[MapTileKey, ImagePlacement, np.ndarray, np.ndarray]]:
        """Mark the tiles the segments' canvases painted since the last call (``canvas.pop_touched``),
        and take the reduced images of those this round may send, oldest change first:
        (key, placement, image float32 (n, n[, C]), covered bool (n, n)); ``send`` False: only mark
        (nobody listens: they wait, and go to the first subscriber). Call under the lock that guards
        the canvases (the pipeline's)."""
        canvases = {}
        for seg in segments:
            canvas = seg.canvas
            if canvas.closed:
                continue
            owner = self._owners.setdefault(id(canvas), int(seg.index))
            canvases[owner] = canvas
        with self._lock:
            for owner, canvas in canvases.items():
                self.queue.mark(((owner, tx, ty) for tx, ty in sorted(canvas.pop_touched(), key=lambda k: (k[1], k[0]))),
                                now_s)
            keys = self.queue.candidates(now_s) if send else []
        batch = []
        for key in keys:
            canvas = canvases.get(key[0])
            blocks = canvas.tile_blocks(key[1:], self.reduction(canvas.tile_size)) if canvas is not None else None
            if blocks is None:  # its canvas is gone (closed): nothing to send, ever
                with self._lock:
                    self.queue.sent(key, 0)
                continue
            batch.append((key, placement_of(key, canvas.tile_size), *blocks))
        return batch

    def encode(self, batch: Sequence[tuple[MapTileKey, ImagePlacement, np.ndarray, np.ndarray]],
               stamp_ns: int) -> list[tuple[str, bytes]]:
        """PNG of each tile of ``batch`` in order, while the budget allows: (frame_id, PNG bytes) to
        publish now; the rest wait for a later round."""
        out = []
        for key, placement, image, covered in batch:
            with self._lock:
                if not self.queue.allowed():
                    break
            data = encode_tile(image, covered)
            frame_id = placement.frame_id()
            with self._lock:
                self.queue.sent(key, len(data))
                self._sent[key] = (frame_id, int(stamp_ns), data)
                self.tile_px = int(covered.shape[0])
            out.append((frame_id, data))
        return out

    def spend(self, nbytes: int) -> None:
        """Bytes sent besides the tiles (the summary) leave the budget too."""
        with self._lock:
            self.queue.spend(nbytes)

    @property
    def pending(self) -> int:
        """Changed tiles waiting (for the budget, or for a subscriber)."""
        with self._lock:
            return self.queue.pending

    def set_budget(self, bytes_per_s: float) -> None:
        with self._lock:
            self.queue.bytes_per_s = float(bytes_per_s)

    def summary(self) -> str:
        """The JSON of /srmosaic/map_tiles (:func:`summary_text`)."""
        with self._lock:
            return summary_text(self.level, self.tile_px, [(f, s) for f, s, _ in self._sent.values()],
                                self.queue.pending, self.queue.bytes_sent)

    def whole_map(self) -> str:
        """The JSON of the srmosaic/get_map answer (:func:`whole_map_text`)."""
        with self._lock:
            return whole_map_text(self.level, self.tile_px, list(self._sent.values()), self.queue.pending)
