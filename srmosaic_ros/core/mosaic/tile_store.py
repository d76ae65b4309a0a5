"""Tile storage of the mosaic canvas: a bounded LRU of tiles in memory, the rest spilled to disk.

A tile is one contiguous ``uint8`` buffer holding its float32 / int32 arrays back to back (the
arrays of :class:`Tile` are views into it, see :class:`TileLayout`), so spilling a tile is one
``np.save`` of that buffer and loading it back one ``np.load``: the bytes come back unchanged and a
spilled canvas renders bit for bit as an unbounded one.

Policy:

- ``get(key)`` is for writing: the tile comes into memory (created, or loaded from its spill
  file), becomes the most recently used one and is marked dirty. It evicts nothing, so every tile
  an operation asked for stays valid until the operation calls ``trim()``.
- ``trim()`` spills the least recently used tiles until at most ``max_in_memory`` remain: a dirty
  tile is written to ``<key>.npy`` (to a temporary name first, then renamed, so a file is always
  a whole tile), a clean one (loaded and only read since) is simply dropped, its file being
  current.
- ``peek(key)`` is for reading (rendering): a tile in memory is returned without touching the LRU
  order, a spilled one is loaded for the caller only and not kept, so rendering any region holds
  at most one tile beyond the bound and does not push the tiles being painted out of memory.

Spill files live in a directory of their own, created on the first spill (``tempfile.mkdtemp``
under ``spill_dir``; when that is '', under :func:`default_spill_root`: $TMPDIR, else /var/tmp,
which is on disk where /tmp is often a RAM-backed tmpfs that would hold the "spilled" tiles in
memory after all), and removed by ``close()``, when the store is garbage-collected or at
interpreter exit (``weakref.finalize``).

A store pickles with all its tiles, spilled ones included, streamed one tile at a time (see
``TileStore.__reduce__``), so a checkpoint of a bounded canvas stays within the bound too;
unpickled, it spills beyond its bound into a new directory of its own.
"""
from __future__ import annotations

import math
import os
import shutil
import tempfile
import weakref
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from srmosaic_ros.errors import SrMosaicError

__all__ = ['Tile', 'TileKey', 'TileLayout', 'TileStore', 'TileStoreError', 'default_spill_root']

TileKey = tuple[int, int]


class TileStoreError(SrMosaicError, OSError):
    """Spilled canvas tiles cannot be written or read back (disk full, spill directory removed...)."""


@dataclass(frozen=True)
class TileLayout:
    """Arrays of one tile of side ``size`` with ``channels`` colour channels.

    Feather: ``acc`` float32 (T, T, C) and ``wsum`` float32 (T, T); ``multiband`` adds ``best``
    float32 (T, T, C), ``best_w`` float32 (T, T) and ``best_id`` int32 (T, T) (-1: no frame).
    ``best_view`` (the best-view compositor, :mod:`.best_view`): ``acc``, ``wsum`` (the feather
    composite, which keyframes register to: it holds the first pass under a revisit), ``best``
    (the mean of the winner's consensus), ``best_w`` (the winner's log score, -inf: none),
    ``best_id``, ``best_q`` (the consensus's quality sum), ``second`` float32 (T, T, C) and
    ``second_w`` (the runner-up's colour and log score); with ``history`` K > 0 (best view's vote on
    moving objects, :func:`.best_view.update_best`) also ``hist`` uint8 (K, T, T, C), the last K
    colour samples of each pixel (a ring; slots not yet written hold 0 and 255 alternately, so that the
    median of the K slots is a median of the samples), ``hist_n`` uint8 (T, T) the samples taken
    (saturating at 255) and ``moved`` uint8 (T, T) the frames whose pixel was kept out as moving
    (saturating).
    """

    size: int
    channels: int
    multiband: bool
    best_view: bool = False
    history: int = 0

    @property
    def fields(self) -> tuple[tuple[str, tuple[int, ...], type], ...]:
        t, c = self.size, self.channels
        if self.best_view:
            return (('acc', (t, t, c), np.float32), ('wsum', (t, t), np.float32), ('best', (t, t, c), np.float32),
                    ('best_w', (t, t), np.float32), ('best_id', (t, t), np.int32), ('best_q', (t, t), np.float32),
                    ('second', (t, t, c), np.float32), ('second_w', (t, t), np.float32)) + (
                    (('hist', (self.history, t, t, c), np.uint8), ('hist_n', (t, t), np.uint8), ('moved', (t, t), np.uint8))
                    if self.history > 0 else ())  # 1-byte fields last: the float32 views stay aligned
        out: list[tuple[str, tuple[int, ...], type]] = [('acc', (t, t, c), np.float32), ('wsum', (t, t), np.float32)]
        if self.multiband:
            out += [('best', (t, t, c), np.float32), ('best_w', (t, t), np.float32), ('best_id', (t, t), np.int32)]
        return tuple(out)

    @property
    def nbytes(self) -> int:
        """Bytes of one tile."""
        return sum(np.dtype(dtype).itemsize * math.prod(shape) for _, shape, dtype in self.fields)


class Tile:
    """One tile: the arrays of its :class:`TileLayout` as views into one ``uint8`` buffer ``buf``."""

    __slots__ = ('acc', 'best', 'best_id', 'best_q', 'best_w', 'buf', 'hist', 'hist_n', 'moved', 'second', 'second_w',
                 'wsum')

    def __init__(self, layout: TileLayout, buf: np.ndarray | None = None) -> None:
        fresh = buf is None
        self.buf = np.zeros(layout.nbytes, np.uint8) if buf is None else buf
        self.acc: np.ndarray | None = None
        self.best: np.ndarray | None = None
        self.best_w: np.ndarray | None = None
        self.best_id: np.ndarray | None = None
        self.best_q: np.ndarray | None = None
        self.second: np.ndarray | None = None
        self.second_w: np.ndarray | None = None
        self.hist: np.ndarray | None = None
        self.hist_n: np.ndarray | None = None
        self.moved: np.ndarray | None = None
        off = 0
        for name, shape, dtype in layout.fields:
            n = np.dtype(dtype).itemsize * math.prod(shape)
            setattr(self, name, self.buf[off:off + n].view(dtype).reshape(shape))
            off += n
        if fresh and self.best_id is not None:
            self.best_id.fill(-1)
        if fresh and self.second_w is not None:  # best view: log scores, -inf where no frame
            self.best_w.fill(-np.inf)
            self.second_w.fill(-np.inf)
        if fresh and self.hist is not None:  # unwritten slots: 0 and 255 alternately (see TileLayout)
            self.hist[1::2] = 255

    @property
    def nbytes(self) -> int:
        return int(self.buf.nbytes)

    @property
    def best_view_tile(self) -> bool:
        """Whether the tile has the best-view layout (a runner-up)."""
        return self.second is not None


def default_spill_root() -> str:
    """Where spill directories go when none is given: $TMPDIR if set, else /var/tmp (disk-backed by
    convention, unlike a tmpfs /tmp) if writable, else the system temporary directory."""
    env = os.environ.get('TMPDIR', '')
    if env and os.path.isdir(env):
        return env
    if os.path.isdir('/var/tmp') and os.access('/var/tmp', os.W_OK | os.X_OK):
        return '/var/tmp'
    return tempfile.gettempdir()


def _file_name(key: TileKey) -> str:
    return f'{key[0]}_{key[1]}.npy'


class TileStore:
    """Tiles by key (tx, ty): at most ``max_in_memory`` in memory (0: no bound), the rest on disk.

    See the module docstring for the policy. Not thread-safe (neither is the canvas).
    """

    def __init__(self, layout: TileLayout, *, max_in_memory: int = 0, spill_dir: str | os.PathLike[str] = '') -> None:
        if int(max_in_memory) != max_in_memory or max_in_memory < 0:
            msg = f'max_tiles_in_memory must be an integer >= 0 (0: no bound), got {max_in_memory!r}.'
            raise ValueError(msg)
        self.layout = layout
        self.max_in_memory = int(max_in_memory)
        self.spill_root = os.fspath(spill_dir)
        self._mem: OrderedDict[TileKey, Tile] = OrderedDict()  # LRU first, MRU last
        self._dirty: set[TileKey] = set()  # in memory and newer than its file (or without one)
        self._files: set[TileKey] = set()  # keys with a spill file
        self._dir: Path | None = None
        self._finalizer: weakref.finalize | None = None
        self._closed = False
        self._rx: dict[str, Any] | None = None  # unpickling: the tile being received
        self.loads = 0  # tiles read back from disk
        self.writes = 0  # tiles written to disk

    # ---------------------------------------------------------------- queries
    def __contains__(self, key: object) -> bool:
        return key in self._mem or key in self._files

    def __len__(self) -> int:
        return len(self._mem) + sum(1 for k in self._files if k not in self._mem)

    def keys(self) -> Iterator[TileKey]:
        yield from self._mem
        yield from (k for k in self._files if k not in self._mem)

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def directory(self) -> Path | None:
        """The spill directory, or None while nothing has been spilled (or after close)."""
        return self._dir

    @property
    def in_memory(self) -> int:
        return len(self._mem)

    @property
    def on_disk_only(self) -> int:
        """Tiles held only on disk (spilled and not in memory)."""
        return sum(1 for k in self._files if k not in self._mem)

    @property
    def memory_bytes(self) -> int:
        return sum(t.nbytes for t in self._mem.values())

    @property
    def disk_bytes(self) -> int:
        """Bytes of the spill files (tile data plus the .npy headers)."""
        if self._dir is None:
            return 0
        total = 0
        for key in self._files:
            try:
                total += (self._dir / _file_name(key)).stat().st_size
            except OSError:
                pass
        return total

    def stats(self) -> dict[str, Any]:
        return {'tiles': len(self), 'in_memory': self.in_memory, 'on_disk_only': self.on_disk_only,
                'files': len(self._files), 'memory_bytes': self.memory_bytes, 'disk_bytes': self.disk_bytes,
                'loads': self.loads, 'writes': self.writes, 'max_in_memory': self.max_in_memory,
                'spill_dir': str(self._dir) if self._dir is not None else ''}

    # ---------------------------------------------------------------- access
    def _check_open(self) -> None:
        if self._closed:
            msg = 'the canvas is closed: its tiles were released; create a new canvas.'
            raise TileStoreError(msg)

    def get(self, key: TileKey, *, create: bool = False) -> Tile:
        """The tile ``key`` in memory, for writing (created when absent and ``create``; else KeyError).

        It becomes the most recently used tile and is marked dirty. Nothing is evicted: call
        :meth:`trim` when the operation that asked for tiles is done.
        """
        self._check_open()
        tile = self._mem.get(key)
        if tile is not None:
            self._mem.move_to_end(key)
        elif key in self._files:
            tile = self._mem[key] = self._load(key)
        elif create:
            tile = self._mem[key] = Tile(self.layout)
        else:
            raise KeyError(key)
        self._dirty.add(key)
        return tile

    def peek(self, key: TileKey) -> Tile | None:
        """The tile ``key`` for reading, None when absent; a spilled tile is loaded but not kept."""
        self._check_open()
        tile = self._mem.get(key)
        if tile is None and key in self._files:
            tile = self._load(key)
        return tile

    def trim(self, keep: int | None = None) -> int:
        """Spill least recently used tiles until at most ``keep`` (default: the bound) are in memory.

        Returns the number of tiles evicted. With no bound and ``keep`` None this does nothing.
        Raises TileStoreError when a tile cannot be written (it then stays in memory).
        """
        self._check_open()
        limit = self.max_in_memory if keep is None else int(keep)
        if keep is None and limit <= 0:
            return 0
        evicted = 0
        while len(self._mem) > max(limit, 0):
            key, tile = next(iter(self._mem.items()))
            if key in self._dirty:
                self._write(key, tile)
                self._dirty.discard(key)
            del self._mem[key]
            evicted += 1
        return evicted

    # ---------------------------------------------------------------- disk
    def _ensure_dir(self) -> Path:
        if self._dir is None:
            root = self.spill_root or default_spill_root()
            try:
                Path(root).mkdir(parents=True, exist_ok=True)
                path = Path(tempfile.mkdtemp(prefix='srmosaic-tiles-', dir=root))
            except OSError as exc:
                msg = (f'cannot create a spill directory for canvas tiles under {root!r} ({exc}); set '
                       'mosaic.spill_dir to a writable directory, or mosaic.max_tiles_in_memory: 0 to keep every '
                       'tile in memory.')
                raise TileStoreError(msg) from None
            self._dir = path
            self._finalizer = weakref.finalize(self, shutil.rmtree, str(path), ignore_errors=True)
        return self._dir

    def _write(self, key: TileKey, tile: Tile) -> None:
        directory = self._ensure_dir()
        name = _file_name(key)
        tmp = directory / f'.{name}.tmp'
        try:
            with open(tmp, 'wb') as handle:
                np.save(handle, tile.buf, allow_pickle=False)
            os.replace(tmp, directory / name)
        except OSError as exc:
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass
            msg = (f'cannot spill canvas tile {key} to {directory} ({exc}); free disk space there, set '
                   'mosaic.spill_dir to a larger disk, or raise mosaic.max_tiles_in_memory (0: keep every tile in '
                   'memory).')
            raise TileStoreError(msg) from None
        self._files.add(key)
        self.writes += 1

    def _load(self, key: TileKey) -> Tile:
        path = (self._dir or Path('.')) / _file_name(key)
        try:
            buf = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            msg = (f'cannot read spilled canvas tile {key} back from {path} ({exc}); was the spill directory '
                   'removed or the disk full while writing? The mosaic cannot be completed.')
            raise TileStoreError(msg) from None
        if buf.dtype != np.uint8 or buf.shape != (self.layout.nbytes,):
            msg = (f'spilled canvas tile {path} holds {buf.dtype} {buf.shape}, not the {self.layout.nbytes} bytes of a '
                   'tile; the spill directory was tampered with. The mosaic cannot be completed.')
            raise TileStoreError(msg)
        if not (buf.flags.writeable and buf.flags.c_contiguous):
            buf = np.array(buf, np.uint8, order='C')
        self.loads += 1  # a lost count at worst when render threads read tiles at once (peek)
        return Tile(self.layout, buf)

    # ---------------------------------------------------------------- life cycle
    def close(self) -> None:
        """Release every tile and remove the spill directory. Idempotent."""
        self._mem.clear()
        self._dirty.clear()
        self._files.clear()
        if self._finalizer is not None:
            self._finalizer()
        self._dir = None
        self._closed = True

    # ---------------------------------------------------------------- pickling
    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle with every tile, streamed: spilled tiles are read back one at a time while pickling.

        The tiles travel as "list items" (the documented ``listitems`` iterator of ``__reduce__``):
        ``tx, ty, n``, then the tile's bytes as ``n`` Python ints of at most _PICKLE_CHUNK bytes
        each. Ints are the one variable-size type the pickler does not memoize, so each chunk is
        freed as soon as it is written: ``pickle.dump`` of a spilled canvas to a file holds about
        one tile more than the canvas does, not the whole canvas. Unpickling spills beyond the
        bound as the tiles arrive (into a new spill directory of its own).
        """
        self._check_open()
        args = ((self.layout.size, self.layout.channels, self.layout.multiband, self.layout.best_view, self.layout.history),
                self.max_in_memory,
                self.spill_root, self.loads, self.writes)
        return (_restore_store, args, None, self._pickle_items())

    def _pickle_items(self) -> Iterator[int]:
        order = [k for k in sorted(self._files) if k not in self._mem] + list(self._mem)  # oldest first
        loads = self.loads
        for key in order:
            tile = self._mem.get(key)
            buf = (tile if tile is not None else self._load(key)).buf
            n = -(-buf.nbytes // _PICKLE_CHUNK)
            yield from (key[0], key[1], n)
            for i in range(n):
                yield int.from_bytes(memoryview(buf[i * _PICKLE_CHUNK:(i + 1) * _PICKLE_CHUNK]), 'little')
            del tile, buf
        self.loads = loads  # reading for a pickle is no load of the run

    def append(self, item: int) -> None:
        """Unpickling only: one item of :meth:`_pickle_items`."""
        rx = self._rx
        if rx is None:
            msg = 'TileStore.append is for unpickling only.'
            raise TypeError(msg)
        if len(rx['head']) < 3:
            rx['head'].append(int(item))
            if len(rx['head']) == 3:
                rx['buf'] = np.empty(self.layout.nbytes, np.uint8)
                rx['pos'] = 0
            return
        buf, pos = rx['buf'], rx['pos']
        size = min(_PICKLE_CHUNK, buf.nbytes - pos)
        buf[pos:pos + size] = np.frombuffer(int(item).to_bytes(size, 'little'), np.uint8)
        rx['pos'] = pos + size
        if rx['pos'] == buf.nbytes:
            key = (rx['head'][0], rx['head'][1])
            self._mem[key] = Tile(self.layout, buf)
            self._dirty.add(key)
            self._rx = {'head': []}
            self.trim()

    def extend(self, items: Any) -> None:  # unpickling only
        for item in items:
            self.append(item)


#: Bytes of tile data per pickled int (bounds what an unpickler holds: 1000 items per batch).
_PICKLE_CHUNK = 1 << 16


def _restore_store(layout: tuple[int, ...], max_in_memory: int, spill_root: str, loads: int,
                   writes: int) -> TileStore:
    store = TileStore(TileLayout(*layout), max_in_memory=max_in_memory, spill_dir=spill_root)
    store.loads, store.writes = loads, writes
    store._rx = {'head': []}
    return store
