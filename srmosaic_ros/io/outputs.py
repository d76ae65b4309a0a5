"""Output images of a run: the mosaic rendered strip by strip into GeoTIFF and PNG, its preview
downscaled on the way, and the process's peak memory for the report."""
from __future__ import annotations

import math
import os
import resource
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..core.georef import GeoRaster
    from ..core.mosaic import TiledCanvas

__all__ = ['MOSAIC_TIF_ZLEVEL', 'OUTPUT_THREADS_MAX', 'STRIP_ROWS', 'StripPreview', 'output_threads', 'peak_rss_mb',
           'preview_image', 'process_age_s', 'write_canvas']

#: Most threads that write the mosaic files (write_canvas).
OUTPUT_THREADS_MAX = 4
#: DEFLATE level of mosaic.tif (GDAL's default, 6, makes the 37-still 12 MP survey's 9 % smaller: 69.0 vs 75.8 MB).
MOSAIC_TIF_ZLEVEL = 3


def output_threads() -> int:
    """Threads writing the mosaic files (the CPUs this process may use, at most OUTPUT_THREADS_MAX)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    return max(1, min(cpus, OUTPUT_THREADS_MAX))


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


def process_age_s() -> float | None:
    """Seconds since this process started (Linux: /proc/self/stat's start time, in clock ticks
    since boot, against CLOCK_BOOTTIME; to the tick, 10 ms), None where that is not known."""
    import time

    try:
        stat = Path('/proc/self/stat').read_text()
        start_ticks = int(stat[stat.rindex(')') + 2:].split()[19])  # field 22; the name in () may hold spaces
        return max(0.0, time.clock_gettime(time.CLOCK_BOOTTIME) - start_ticks / os.sysconf('SC_CLK_TCK'))
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def preview_image(image: np.ndarray, coverage: np.ndarray, max_side: int) -> np.ndarray:
    """The mosaic downscaled so that its longer side is at most max_side, uncovered pixels black."""
    import cv2

    image = np.where(coverage[..., None] if image.ndim == 3 else coverage, image, 0.0).astype(np.float32)
    h, w = image.shape[:2]
    scale = min(1.0, max_side / max(h, w))
    if scale >= 1.0:
        return image
    return cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


def _area_table(src: int, dst: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """cv2.INTER_AREA's weights along one axis (OpenCV's computeResizeAreaTab), sparse.

    Output sample d averages the source interval [d s, (d + 1) s), s = src / dst >= 1, each source
    sample weighted by its overlap with the interval over the interval's length. Returns
    (d (K,) int, source sample (K,) int, weight (K,) float32), K <= src + dst, source samples
    non-decreasing.
    """
    scale = 1.0 / (dst / src)  # as cv2.resize computes it
    d_idx: list[int] = []
    s_idx: list[int] = []
    alpha: list[float] = []

    def put(d: int, s: int, a: float) -> None:
        d_idx.append(d)
        s_idx.append(s)
        alpha.append(a)

    for d in range(dst):
        f1 = d * scale
        f2 = f1 + scale
        cell = min(scale, src - f1)
        s1, s2 = math.ceil(f1), min(math.floor(f2), src - 1)
        s1 = min(s1, s2)
        if s1 - f1 > 1e-3:
            put(d, s1 - 1, (s1 - f1) / cell)
        for s_ in range(s1, s2):
            put(d, s_, 1.0 / cell)
        if f2 - s2 > 1e-3:
            put(d, s2, min(min(f2 - s2, 1.0), cell) / cell)
    return np.array(d_idx, np.int64), np.array(s_idx, np.int64), np.array(alpha, np.float32)


class StripPreview:
    """``preview_image`` of a mosaic rendered in strips of rows, without holding the mosaic.

    Feed ``add(row, image, coverage)`` strips (as ``TiledCanvas.render_blocks`` yields them) for
    rows 0 .. height - 1 of a (height, width) mosaic, in any order, then ``image()`` is
    ``preview_image`` of the whole (float32 (h', w'[, C]), uncovered pixels black), to float
    rounding (~1e-6): INTER_AREA's weights are separable, so each strip is downscaled across by
    cv2.INTER_AREA and summed down with the same weights. Memory: the preview (at most
    max_side^2 C floats), one strip and the row weights (about height + max_side entries).
    """

    CHUNK_ROWS = 128

    def __init__(self, height: int, width: int, channels: int, max_side: int) -> None:
        scale = min(1.0, max_side / max(height, width, 1))
        self._down = scale < 1.0
        self._w = max(1, round(width * scale)) if self._down else width
        h_out = max(1, round(height * scale)) if self._down else height
        self._rows = _area_table(height, h_out) if self._down else None
        self._squeeze = channels == 1
        self._out = np.zeros((h_out, self._w, channels), np.float32)

    def add(self, row: int, image: np.ndarray, coverage: np.ndarray) -> None:
        """Strip rows row .. row + len(image): image (rows, W[, C]) float, coverage (rows, W) bool."""
        for r in range(0, len(image), self.CHUNK_ROWS):  # small temporaries whatever the strip's height
            self._add(row + r, image[r:r + self.CHUNK_ROWS], coverage[r:r + self.CHUNK_ROWS])

    def _add(self, row: int, image: np.ndarray, coverage: np.ndarray) -> None:
        import cv2

        src = np.ascontiguousarray(image, np.float32).reshape(image.shape[0], image.shape[1], -1)
        strip = np.zeros(src.shape, np.float32)
        cv2.copyTo(src, coverage.view(np.uint8), strip)  # np.where's broadcast is ~5x slower
        n = strip.shape[0]
        if self._rows is None:
            self._out[row:row + n] = strip
            return
        across = cv2.resize(strip, (self._w, n), interpolation=cv2.INTER_AREA).reshape(n, -1)
        d_idx, s_idx, alpha = self._rows
        lo, hi = np.searchsorted(s_idx, [row, row + n])
        if lo == hi:
            return
        d0, d1 = int(d_idx[lo:hi].min()), int(d_idx[lo:hi].max()) + 1
        weights = np.zeros((d1 - d0, n), np.float32)  # (preview rows touched, strip rows)
        weights[d_idx[lo:hi] - d0, s_idx[lo:hi] - row] = alpha[lo:hi]
        self._out[d0:d1] += (weights @ across).reshape(d1 - d0, self._w, -1)

    def image(self) -> np.ndarray:
        """The preview, float32 (h', w', C), or (h', w') for one channel."""
        return self._out[:, :, 0] if self._squeeze else self._out


#: Rows of the mosaic rendered, written and downscaled at a time (one tile row of mosaic.tif).
STRIP_ROWS = 512


def write_canvas(canvas: TiledCanvas, tif: Path | None, png: Path, raster: GeoRaster | None = None,
                  preview: StripPreview | None = None, *, threads: int = 1, zlevel: int | None = None,
                  on_rendered: Callable[[], None] | None = None) -> None:
    """Render ``canvas`` (its bounds) strip by strip into a tiled GeoTIFF, then PNG from that.

    With ``tif`` (and ``raster``, its grid) that GeoTIFF is an output (mosaic.tif: 512 px tiles,
    DEFLATE, internal overviews); without, a temporary TIFF beside ``png`` is written and removed.
    The PNG has the pixels ``mosaic_files.write_png(render(), covered)`` would write. Both files
    are written atomically. ``preview`` receives every strip. Memory: one strip of STRIP_ROWS
    rows (multiband: one RENDER_BLOCK_PX row of blocks) and GDAL's bounded cache; never the mosaic.

    ``threads`` > 1 (see :func:`_write_canvas_streamed`): the same pixels, written on that many
    threads while the canvas renders: each strip is converted to 8 bits once, the PNG streamed from
    it (no TIFF written and read back for it), the GeoTIFF's blocks and overviews compressed by GDAL
    threads at DEFLATE level ``zlevel`` (None: 6). The files' bytes differ from the one-thread
    writer's (filters, block order); their pixels do not.

    ``on_rendered``: called once every strip is rendered (``preview`` complete), while GDAL may still
    be compressing the GeoTIFF's last blocks and overviews; an exception there fails the write.
    """
    import tempfile

    from .geotiff import MOSAIC_BLOCK_PX, png_from_geotiff, write_geotiff_blocks

    if threads > 1:
        _write_canvas_streamed(canvas, tif, png, raster, preview, threads=threads, zlevel=zlevel, on_rendered=on_rendered)
        return
    x0, y0, x1, y1 = canvas.bounds()

    def strips() -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        for row, image, covered in canvas.render_blocks(STRIP_ROWS):
            if preview is not None:
                preview.add(row, image, covered)
            yield row, image, covered

    if tif is not None:
        write_geotiff_blocks(tif, strips(), raster, y1 - y0, x1 - x0, block_px=MOSAIC_BLOCK_PX)
        png_from_geotiff(tif, png)
    else:
        png.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix=f'.{png.stem}.', dir=png.parent) as tmp:
            scratch = Path(tmp) / 'mosaic.tif'
            write_geotiff_blocks(scratch, strips(), None, y1 - y0, x1 - x0, block_px=MOSAIC_BLOCK_PX, overviews=False,
                                 cog=False)
            png_from_geotiff(scratch, png)
    if on_rendered is not None:
        on_rendered()


def _rgba_u8(image: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """uint8 (rows, W, C + 1) of a rendered strip (float (rows, W[, C])): colour as mosaic.tif stores
    it (geotiff's rounding), alpha 255 where covered, 0 elsewhere."""
    from .geotiff import CONVERT_ROWS, _to_u8

    img = image if image.ndim == 3 else image[:, :, None]
    out = np.empty((*img.shape[:2], img.shape[2] + 1), np.uint8)
    for r in range(0, len(img), CONVERT_ROWS):  # small float temporaries
        out[r:r + CONVERT_ROWS, :, :-1] = _to_u8(img[r:r + CONVERT_ROWS])
    out[:, :, -1] = covered
    out[:, :, -1] *= 255
    return out


def _write_canvas_streamed(canvas: TiledCanvas, tif: Path | None, png: Path, raster: GeoRaster | None,
                           preview: StripPreview | None, *, threads: int, zlevel: int | None,
                           on_rendered: Callable[[], None] | None = None) -> None:
    """write_canvas on ``threads`` threads: one pass over the rendered strips feeds the preview, the
    PNG (:class:`.png_stream.StreamingPngWriter`, grey + alpha as RGBA with the grey repeated, as
    png_from_geotiff writes it) and, with ``tif``, the GeoTIFF (GDAL compressing on its threads)."""
    import queue
    import threading

    from .geotiff import MOSAIC_BLOCK_PX, write_geotiff_blocks
    from .png_stream import StreamingPngWriter

    x0, y0, x1, y1 = canvas.bounds()
    height, width = y1 - y0, x1 - x0
    grey = canvas.channels == 1
    tif_strips: queue.Queue[tuple[int, np.ndarray, None] | None] = queue.Queue(maxsize=2)
    failure: list[BaseException] = []
    ended = threading.Event()  # the producer's end mark (None) was taken

    def tif_writer() -> None:  # GDAL's writes and the overviews on a thread of their own
        def strips() -> Iterator[tuple[int, np.ndarray, None]]:
            while (item := tif_strips.get()) is not None:
                yield item
            ended.set()
        try:
            write_geotiff_blocks(tif, strips(), raster, height, width, block_px=MOSAIC_BLOCK_PX, threads=threads,
                                 zlevel=zlevel)
        except BaseException as exc:  # noqa: BLE001 -- handed to the caller's thread and raised there
            failure.append(exc)
            while not ended.is_set() and tif_strips.get() is not None:  # let the producer finish
                pass

    writer = threading.Thread(target=tif_writer, name='mosaic.tif') if tif is not None else None
    if writer is not None:
        writer.start()
    try:
        with StreamingPngWriter(png, width, height, 4 if grey else canvas.channels + 1, threads=threads) as out:
            for row, image, covered in canvas.render_blocks(STRIP_ROWS, threads=threads):
                if preview is not None:
                    preview.add(row, image, covered)
                rgba = _rgba_u8(image, covered)
                out.write(np.concatenate([rgba[:, :, :1]] * 3 + [rgba[:, :, 1:]], axis=2) if grey else rgba)
                if writer is not None:
                    tif_strips.put((row, rgba, None))
                if failure:
                    raise failure[0]
        if on_rendered is not None:  # while GDAL finishes mosaic.tif
            on_rendered()
    finally:
        if writer is not None:
            tif_strips.put(None)
            writer.join()
    if failure:
        raise failure[0]
