"""SRTileStream: the SR node's tiles on the wire as PNGs, within a bandwidth budget, with what was sent (no ROS).

The SR counterpart of live.map_tiles.MapTileStream, for /srmosaic/sr_map_tile, its latched summary
/srmosaic/sr_map_tiles and the service /srmosaic/get_sr_map:

    stream = SRTileStream(bytes_per_s=500_000)
    stream.offer(placement.frame_id(), image, now_s)     # worker: a tile made (RGB or grey uint8)
    for frame_id, data in stream.take(stamp_ns, now_s):  # timer: oldest first, as the budget allows
        publish(frame_id, data)

Each tile is an opaque PNG of the SR image as reconstructed (RGB or grey, ``height * factor`` by
``width * factor`` pixels), header.frame_id its live.sr.SRTilePlacement text. The budget is the
token bucket of live.map_tiles.ChangedTiles: tiles beyond it wait, oldest first; a tile made again
while it waits keeps its place and goes out in its newest version (none is lost). The summary and
the whole map are those of the map tiles (live.map_tiles.summary_text, whole_map_text) with level 0
and tile_px the side of the newest tile sent.
"""
from __future__ import annotations

import threading

import cv2
import numpy as np

from ..errors import SrMosaicError
from .map_tiles import ChangedTiles, MapTileKey, summary_text, whole_map_text
from .sr import SRTilePlacement

__all__ = ['SRTileStream', 'encode_sr_tile']


def encode_sr_tile(image: np.ndarray) -> bytes:
    """PNG bytes of an SR tile: ``image`` uint8 (h, w, 3) RGB or (h, w) grey (uint16: the high byte)."""
    img = np.asarray(image)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        msg = f'an SR tile must be an RGB or grey uint8 image, got {img.dtype} {img.shape}.'
        raise SrMosaicError(msg)
    ok, buf = cv2.imencode('.png', img[:, :, ::-1] if img.ndim == 3 else img, [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        msg = f'an SR tile of shape {img.shape} could not be encoded as PNG.'
        raise SrMosaicError(msg)
    return buf.tobytes()


class SRTileStream:
    """SR tiles waiting for the budget, and the newest version of each sent (module docstring).
    ``bytes_per_s``: the budget (0: none); ``burst_s``: the seconds of budget the bucket holds. Thread-safe."""

    def __init__(self, bytes_per_s: float = 0.0, *, burst_s: float = 1.0) -> None:
        self.queue = ChangedTiles(bytes_per_s, burst_s)
        self._lock = threading.Lock()
        self._waiting: dict[MapTileKey, tuple[str, bytes]] = {}  # frame_id, PNG of the newest version
        self._sent: dict[MapTileKey, tuple[str, int, bytes]] = {}  # frame_id, stamp_ns, PNG
        self.tile_px = 0  # side of the newest tile sent (0: none yet)

    def offer(self, frame_id: str, image: np.ndarray, now_s: float) -> None:
        """A tile made: encoded now (the caller's thread), sent when the budget allows."""
        p = SRTilePlacement.parse(frame_id)
        data = encode_sr_tile(image)
        key = (p.segment, p.x0, p.y0)
        with self._lock:
            self._waiting[key] = (frame_id, data)
            self.queue.mark([key], now_s)

    def take(self, stamp_ns: int, now_s: float) -> list[tuple[str, bytes]]:
        """The tiles to publish now (frame_id, PNG), oldest first, while the budget allows; they count as
        sent at ``stamp_ns``. The rest wait for a later call."""
        out = []
        with self._lock:
            for key in self.queue.candidates(now_s):
                if not self.queue.allowed():
                    break
                frame_id, data = self._waiting.pop(key)
                self.queue.sent(key, len(data))
                self._sent[key] = (frame_id, int(stamp_ns), data)
                placement = SRTilePlacement.parse(frame_id)
                self.tile_px = placement.width * placement.factor
                out.append((frame_id, data))
        return out

    @property
    def pending(self) -> int:
        with self._lock:
            return self.queue.pending

    def spend(self, nbytes: int) -> None:
        """Bytes sent besides the tiles (the summary) leave the budget too."""
        with self._lock:
            self.queue.spend(nbytes)

    def set_budget(self, bytes_per_s: float) -> None:
        with self._lock:
            self.queue.bytes_per_s = float(bytes_per_s)

    def summary(self) -> str:
        """The JSON of /srmosaic/sr_map_tiles (live.map_tiles.summary_text, level 0)."""
        with self._lock:
            return summary_text(0, self.tile_px, [(f, s) for f, s, _ in self._sent.values()], self.queue.pending,
                                self.queue.bytes_sent)

    def whole_map(self) -> str:
        """The JSON of the srmosaic/get_sr_map answer (live.map_tiles.whole_map_text, level 0)."""
        with self._lock:
            return whole_map_text(0, self.tile_px, list(self._sent.values()), self.queue.pending)
