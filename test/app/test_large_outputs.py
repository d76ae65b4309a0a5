"""The final mosaic written tile by tile: mosaic.tif (tiled, overviewed GeoTIFF) from canvas strips,
mosaic.png from it by GDAL's CreateCopy, the strip-wise preview, atomic writes and bounded memory."""
from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

import rasterio  # a pinned dependency: a missing install must fail, not skip
import rasterio.shutil
from rasterio.enums import ColorInterp, Compression
from rio_cogeo.cogeo import cog_validate  # the field's validator of the COG layout

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.georef import GeoRaster
from srmosaic_ros.core.mosaic import TiledCanvas
from srmosaic_ros.core.types import Frame
from srmosaic_ros.io.geotiff import (MOSAIC_BLOCK_PX, overview_factors, png_from_geotiff, write_geotiff,
                                     write_geotiff_blocks)
from srmosaic_ros.io.mosaic_files import write_png
from srmosaic_ros.io.outputs import StripPreview, preview_image, write_canvas
from srmosaic_ros.app.process import open_source, write_outputs
from srmosaic_ros.pipeline import Pipeline
from repo_paths import REPO

ROOT = REPO
DEMO = ROOT / 'bags' / 'demo'
RASTER = GeoRaster(32633, 0.25, 500_000.0, 5_000_000.0)


def _texture(h: int, w: int, channels: int, seed: int) -> np.ndarray:
    """Smooth random texture, float32 (h, w, C) in [0, 1]."""
    noise = np.random.default_rng(seed).random((h, w, channels), dtype=np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), 2.0).reshape(h, w, channels)
    tex -= tex.min()
    return tex / tex.max()


def _painted_canvas(channels: int, blend: str) -> TiledCanvas:
    """A ~1390 x 700 px canvas of 320 x 240 crops of one texture, staggered so that some of it is uncovered."""
    world = _texture(760, 1460, channels, seed=channels)
    canvas = TiledCanvas(channels, 128, blend=blend)
    for k, (x, y) in enumerate([(x, y) for y in (0, 200, 440) for x in range(0, 1100, 180)]):
        x, y = x + 37 * (y // 200 % 2), y + (k % 3) * 7  # stagger
        crop = world[y:y + 240, x:x + 320]
        canvas.paint(crop if channels > 1 else crop[:, :, 0], np.array([[1, 0, x + 0.3], [0, 1, y + 0.6], [0, 0, 1.0]]))
    return canvas


def _read_png(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return img


@pytest.mark.parametrize(('channels', 'blend'), [(3, 'feather'), (1, 'feather'), (3, 'multiband')])
def test_mosaic_tif_written_in_strips_equals_the_whole_render(channels: int, blend: str, tmp_path: Path) -> None:
    canvas = _painted_canvas(channels, blend)
    image, covered = canvas.render()
    h, w = covered.shape
    assert h > 512 and w > 1024 and not covered.all() and covered.mean() > 0.7  # several strips, some holes
    preview = StripPreview(h, w, channels, 300)
    write_canvas(canvas, tmp_path / 'mosaic.tif', tmp_path / 'mosaic.png', RASTER, preview)
    write_geotiff(tmp_path / 'whole.tif', image, RASTER, coverage=covered)  # the whole-image writer
    with rasterio.open(tmp_path / 'mosaic.tif') as ds, rasterio.open(tmp_path / 'whole.tif') as whole:
        np.testing.assert_array_equal(ds.read(), whole.read())
        assert ds.count == channels + 1 and ds.colorinterp[-1] == ColorInterp.alpha
        assert ds.profile['tiled'] and set(ds.block_shapes) == {(MOSAIC_BLOCK_PX, MOSAIC_BLOCK_PX)}
        assert ds.overviews(1) == [2, 4] == overview_factors(h, w, MOSAIC_BLOCK_PX)
        assert ds.compression == Compression.deflate
        assert ds.crs.to_epsg() == 32633 and ds.transform.to_gdal() == pytest.approx(RASTER.geotransform)
        assert (ds.width, ds.height) == (w, h)
    assert cog_validate(tmp_path / 'mosaic.tif', quiet=True) == (True, [], [])  # a Cloud Optimized GeoTIFF
    # mosaic.png: the pixels of the previous writer (cv2, from the whole render), RGBA for grey too.
    write_png(tmp_path / 'before.png', image, covered)
    assert np.array_equal(_read_png(tmp_path / 'mosaic.png'), _read_png(tmp_path / 'before.png'))
    assert not list(tmp_path.glob('*.aux.xml')) and not list(tmp_path.glob('.*'))
    np.testing.assert_allclose(preview.image(), preview_image(image, covered, 300), atol=2e-6)


@pytest.mark.parametrize(('channels', 'blend'), [(3, 'feather'), (1, 'feather'), (3, 'multiband')])
@pytest.mark.parametrize('georeferenced', [True, False])
def test_the_threaded_writer_writes_the_pixels_of_the_one_thread_writer(channels: int, blend: str, georeferenced: bool,
                                                                        tmp_path: Path) -> None:
    """write_canvas(threads=2) (the survey's: the PNG streamed while rendering, GDAL compressing the
    GeoTIFF on threads at another DEFLATE level) gives the files of threads=1 pixel for pixel: PNG
    (RGBA, grey repeated), GeoTIFF bands, grid, overviews and alpha, and the same preview."""
    canvas = _painted_canvas(channels, blend)
    h, w = canvas.bounds()[3] - canvas.bounds()[1], canvas.bounds()[2] - canvas.bounds()[0]
    raster = RASTER if georeferenced else None
    previews = {}
    for threads in (1, 2):
        out = tmp_path / str(threads)
        previews[threads] = StripPreview(h, w, channels, 300)
        write_canvas(canvas, out / 'mosaic.tif' if georeferenced else None, out / 'mosaic.png', raster,
                     previews[threads], threads=threads, zlevel=None if threads == 1 else 3)
        assert sorted(p.name for p in out.iterdir()) == (['mosaic.png', 'mosaic.tif'] if georeferenced else ['mosaic.png'])
    one, two = tmp_path / '1', tmp_path / '2'
    assert np.array_equal(_read_png(one / 'mosaic.png'), _read_png(two / 'mosaic.png'))
    assert _read_png(two / 'mosaic.png').shape == (h, w, 4)
    np.testing.assert_array_equal(previews[1].image(), previews[2].image())
    if georeferenced:
        with rasterio.open(one / 'mosaic.tif') as a, rasterio.open(two / 'mosaic.tif') as b:
            np.testing.assert_array_equal(a.read(), b.read())
            assert (a.crs, a.transform, a.colorinterp, a.overviews(1), a.block_shapes, a.tags()) == \
                (b.crs, b.transform, b.colorinterp, b.overviews(1), b.block_shapes, b.tags())
            np.testing.assert_array_equal(a.read(1, out_shape=(h // 4, w // 4)), b.read(1, out_shape=(h // 4, w // 4)))
            assert b.compression == Compression.deflate
        for tif in (one / 'mosaic.tif', two / 'mosaic.tif'):
            assert cog_validate(tif, quiet=True) == (True, [], []), tif


def test_a_failing_render_leaves_no_file_with_the_threaded_writer(tmp_path: Path) -> None:
    canvas = _painted_canvas(3, 'feather')
    real = canvas.render_blocks

    def broken(rows: int, **kwargs: int) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        for k, strip in enumerate(real(rows, **kwargs)):
            if k == 1:
                raise RuntimeError('render failed')
            yield strip

    canvas.render_blocks = broken  # type: ignore[method-assign]
    with pytest.raises(RuntimeError, match='render failed'):
        write_canvas(canvas, tmp_path / 'mosaic.tif', tmp_path / 'mosaic.png', RASTER, threads=2)
    assert list(tmp_path.iterdir()) == []


def test_strip_preview_equals_preview_image_for_any_strips() -> None:
    image = _texture(301, 452, 3, seed=4)
    covered = np.ones((301, 452), bool)
    covered[:40, :100] = False
    for max_side, rows in [(226, 64), (100, 37), (1000, 100), (451, 301)]:  # exact half, fractional, none, ~1
        strips = StripPreview(301, 452, 3, max_side)
        for r in range(0, 301, rows):
            strips.add(r, image[r:r + rows], covered[r:r + rows])
        np.testing.assert_allclose(strips.image(), preview_image(image, covered, max_side), atol=2e-6)
    grey = StripPreview(301, 452, 1, 150)
    grey.add(0, image[:, :, 0], covered)
    assert grey.image().shape == preview_image(image[:, :, 0], covered, 150).shape == (100, 150)


def test_png_from_geotiff_keeps_grey_and_rgb_without_alpha(tmp_path: Path) -> None:
    for image in (_texture(70, 90, 3, seed=1), _texture(70, 90, 1, seed=2)[:, :, 0]):
        write_geotiff_blocks(tmp_path / 'm.tif', [(0, image[:50], None), (50, image[50:], None)], None, 70, 90,
                             overviews=False)
        png_from_geotiff(tmp_path / 'm.tif', tmp_path / 'm.png')
        write_png(tmp_path / 'before.png', image)
        assert np.array_equal(_read_png(tmp_path / 'm.png'), _read_png(tmp_path / 'before.png'))


def test_write_outputs_of_a_real_run_match_the_whole_image_writers(tmp_path: Path) -> None:
    """The demo bag's first 30 frames through the pipeline (georeferenced): mosaic.png and mosaic.tif
    as the whole render would give them."""
    items, _, _ = open_source(DEMO)
    config = pipeline_config()
    pipe = Pipeline(config)
    frames = 0
    for item in items:
        pipe.feed(item)
        frames += isinstance(item, Frame)
        if frames == 30:
            break
    result = pipe.finish()
    canvas = result.main_segment.canvas
    image, covered = canvas.render()
    write_png(tmp_path / 'before.png', image, covered)
    write_png(tmp_path / 'before_preview.png', preview_image(image, covered, config.mosaic.preview_max_side_px))

    geo = tmp_path / 'geo'
    report = write_outputs(result, geo, config, {})
    assert report['georeferenced'] is not None and report['georeferenced']['method'] == 'filter'
    assert {'mosaic.png', 'mosaic.tif', 'mosaic.kml', 'poses.csv', 'preview.png', 'frames.csv'} <= {
        p.name for p in geo.iterdir()}
    assert np.array_equal(_read_png(geo / 'mosaic.png'), _read_png(tmp_path / 'before.png'))
    before_preview = _read_png(tmp_path / 'before_preview.png').astype(int)
    assert np.abs(_read_png(geo / 'preview.png').astype(int) - before_preview).max() <= 1
    with rasterio.open(geo / 'mosaic.tif') as ds:
        assert (ds.width, ds.height) == covered.shape[::-1] and ds.crs.to_epsg() == report['georeferenced']['epsg']
        assert ds.profile['tiled'] and ds.block_shapes[0] == (512, 512)
        assert ds.overviews(1) == overview_factors(ds.height, ds.width, 512) != []
        np.testing.assert_array_equal(ds.read(4) > 0, covered)
        np.testing.assert_array_equal(ds.read([1, 2, 3]).transpose(1, 2, 0),
                                      cv2.cvtColor(_read_png(tmp_path / 'before.png'), cv2.COLOR_BGRA2RGB))

    plain = tmp_path / 'plain'  # the same run without georeferencing or fixes: no mosaic.tif, as before
    report = write_outputs(dataclasses.replace(result, georef=None, fixes=[]), plain, config, {})
    assert report['georeferenced'] is None
    assert sorted(p.name for p in plain.iterdir()) == ['frames.csv', 'mosaic.png', 'preview.png']
    assert np.array_equal(_read_png(plain / 'mosaic.png'), _read_png(tmp_path / 'before.png'))


def _strips(image: np.ndarray, covered: np.ndarray, rows: int, fail_after: int | None = None):
    for k, r in enumerate(range(0, image.shape[0], rows)):
        if fail_after is not None and k == fail_after:
            msg = 'rendering failed mid-way'
            raise RuntimeError(msg)
        yield r, image[r:r + rows], covered[r:r + rows]


def test_an_interrupted_write_leaves_no_mosaic_tif(tmp_path: Path) -> None:
    image = _texture(600, 700, 3, seed=5)
    covered = np.ones((600, 700), bool)
    path = tmp_path / 'mosaic.tif'
    with pytest.raises(RuntimeError, match='mid-way'):
        write_geotiff_blocks(path, _strips(image, covered, 256, fail_after=2), RASTER, 600, 700)
    assert list(tmp_path.iterdir()) == []  # neither mosaic.tif nor a temporary file
    write_geotiff_blocks(path, _strips(image, covered, 256), RASTER, 600, 700)
    complete = path.read_bytes()
    with pytest.raises(RuntimeError, match='mid-way'):  # a failed rewrite keeps the complete file
        write_geotiff_blocks(path, _strips(image * 0.5, covered, 256, fail_after=1), RASTER, 600, 700)
    assert path.read_bytes() == complete and [p.name for p in tmp_path.iterdir()] == ['mosaic.tif']
    for bad, match in [([(0, image[:256], covered[:256]), (300, image[300:], covered[300:])], 'contiguous'),
                       ([(0, image[:256], covered[:256])], 'incomplete'),
                       ([(0, image[:, :600], covered[:, :600])], 'contiguous'),
                       ([(0, image[:256], covered[:256]), (256, image[256:], None)], 'coverage')]:
        with pytest.raises(ValueError, match=match):
            write_geotiff_blocks(tmp_path / 'bad.tif', bad, RASTER, 600, 700)
    assert [p.name for p in tmp_path.iterdir()] == ['mosaic.tif']


@pytest.mark.parametrize(('channels', 'threads'), [(3, 2), (1, 1)])
def test_a_cog_staged_in_memory_has_the_pixels_of_one_staged_on_disk(channels: int, threads: int, tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Up to STAGE_IN_MEMORY_BYTES, mosaic.tif's stage lives in GDAL's memory, uncompressed: the COG has the
    pixels of every level (full size and overviews) of the one staged on disk, validates, and the
    in-memory stage is freed, after a complete write as after a failed one."""
    import srmosaic_ros.io.geotiff as geotiff

    image = _texture(1100, 1300, channels, seed=7)
    covered = np.ones((1100, 1300), bool)
    covered[:300, :400] = False
    stages: list[str] = []
    unlink = geotiff._unlink_vsimem
    monkeypatch.setattr(geotiff, '_unlink_vsimem', lambda path: (stages.append(path), unlink(path)))
    for name, budget in (('disk.tif', 0), ('memory.tif', geotiff.STAGE_IN_MEMORY_BYTES)):
        monkeypatch.setattr(geotiff, 'STAGE_IN_MEMORY_BYTES', budget)
        write_geotiff_blocks(tmp_path / name, _strips(image, covered, 512), RASTER, 1100, 1300, threads=threads, zlevel=3)
        assert cog_validate(tmp_path / name, quiet=True) == (True, [], []), name
    with pytest.raises(RuntimeError, match='mid-way'):
        write_geotiff_blocks(tmp_path / 'failed.tif', _strips(image, covered, 512, fail_after=1), RASTER, 1100, 1300)
    assert len(stages) == 2 and all(s.startswith('/vsimem/') and not rasterio.shutil.exists(s) for s in stages), stages
    assert sorted(p.name for p in tmp_path.iterdir()) == ['disk.tif', 'memory.tif']
    with rasterio.open(tmp_path / 'disk.tif') as disk, rasterio.open(tmp_path / 'memory.tif') as memory:
        assert disk.overviews(1) == memory.overviews(1) == overview_factors(1100, 1300, MOSAIC_BLOCK_PX) == [2, 4]
        assert disk.count == memory.count == channels + 1
    for level in (None, 0, 1):
        kw = {} if level is None else {'OVERVIEW_LEVEL': level}
        with rasterio.open(tmp_path / 'disk.tif', **kw) as disk, rasterio.open(tmp_path / 'memory.tif', **kw) as memory:
            assert np.array_equal(disk.read(), memory.read()), level


def test_kill_9_while_writing_leaves_no_mosaic_tif(tmp_path: Path) -> None:
    child = textwrap.dedent(f'''
        import sys, time
        import numpy as np
        from srmosaic_ros.io.geotiff import write_geotiff_blocks
        def strips():
            for r in range(0, 4096, 512):
                yield r, np.full((512, 2048, 3), r / 4096, np.float32), np.ones((512, 2048), bool)
                print('strip', r, flush=True)
                time.sleep(0.3)
        write_geotiff_blocks({str(tmp_path / 'mosaic.tif')!r}, strips(), None, 4096, 2048)
        print('done', flush=True)
    ''')
    proc = subprocess.Popen([sys.executable, '-c', child], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    lines = [proc.stdout.readline() for _ in range(3)]
    assert all(line.startswith('strip') for line in lines), lines
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    proc.stdout.close()
    names = [p.name for p in tmp_path.iterdir()]
    assert 'mosaic.tif' not in names and all(n.startswith('.mosaic.') for n in names), names


@pytest.mark.filterwarnings('ignore::rasterio.errors.NotGeoreferencedWarning')
def test_peak_memory_of_the_block_writer_does_not_grow_with_the_area(tmp_path: Path) -> None:
    """Two rasters 16x apart in area, written from lazy strips in child processes (mosaic.tif, then
    mosaic.png): their peak RSS differs by far less than the larger one held whole (192 MB as the
    float render, 64 MB as RGBA bytes)."""
    child = textwrap.dedent('''
        import resource, sys
        import numpy as np
        from srmosaic_ros.io.geotiff import png_from_geotiff, write_geotiff_blocks
        side, out = int(sys.argv[1]), sys.argv[2]
        ramp = np.linspace(0.0, 1.0, side, dtype=np.float32)
        def strips():
            for r in range(0, side, 512):
                img = np.empty((512, side, 3), np.float32)
                img[:] = ramp[None, :, None]
                img[:, :, 1] = r / side
                cov = np.ones((512, side), bool)
                cov[:, : r * side // (2 * side)] = False
                yield r, img, cov
        write_geotiff_blocks(out + '/m.tif', strips(), None, side, side)
        png_from_geotiff(out + '/m.tif', out + '/m.png')
        print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    ''')
    peaks = {}
    for side in (1024, 4096):
        run = subprocess.run([sys.executable, '-c', child, str(side), str(tmp_path)], capture_output=True, text=True,
                             cwd=ROOT, timeout=300, check=False)
        assert run.returncode == 0, run.stderr
        peaks[side] = float(run.stdout.split()[-1])
        with rasterio.open(tmp_path / 'm.tif') as ds:
            assert (ds.width, ds.height) == (side, side) and ds.overviews(1)[-1] >= side // 512
    render_mb = 4096 * 4096 * 3 * 4 / 2**20
    assert peaks[4096] - peaks[1024] < 0.5 * render_mb, peaks
    print(peaks)
