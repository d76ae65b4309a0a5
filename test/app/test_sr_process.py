"""`srmosaic process --sr` on the demo bag: the sr/tiles.json contract and tiles that hold the mosaic."""
from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
from repo_paths import REPO
from cli_runner import run_cli

DEMO = REPO / 'bags' / 'demo'


def test_process_sr_writes_tiles_contract(tmp_path):
    out = tmp_path / 'out'
    params = tmp_path / 'params.yaml'  # the contract holds for any number of tiles: six of the best covered
    params.write_text('/**:\n  ros__parameters:\n    sr_tiles:\n      max_tiles: 6\n')
    run = run_cli('process', str(DEMO), '--out', str(out), '--sr', '--no-progress', '--checkpoint-every', '0',
                  '--params', str(params))
    assert run.returncode == 0, run.stderr
    tiles = json.loads((out / 'sr' / 'tiles.json').read_text())
    assert len(tiles) >= 5
    mosaic = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    for entry in tiles[:5]:
        # the contract's keys first, then what the tile shows (SR, or its best frame upsampled and why)
        assert list(entry)[:6] == ['file', 'x0', 'y0', 'width', 'height', 'factor'] and entry['factor'] == 2
        assert list(entry)[6:] == ['source', 'fallback'] and entry['source'] in ('sr', 'frame')
        assert (entry['fallback'] is None) == (entry['source'] == 'sr')
        tile = cv2.imread(str(out / 'sr' / entry['file']), cv2.IMREAD_COLOR)
        assert tile.shape[:2] == (entry['height'] * 2, entry['width'] * 2)
        # Downsampled back by the factor, the SR tile shows the same ground as the mosaic region.
        x0, y0, w, h = entry['x0'], entry['y0'], entry['width'], entry['height']
        back = cv2.resize(tile, (w, h), interpolation=cv2.INTER_AREA).astype(float)
        region = mosaic[y0:y0 + h, x0:x0 + w, :3].astype(float)
        assert np.abs(back[4:-4, 4:-4] - region[4:-4, 4:-4]).mean() < 4.0
    report = json.loads((out / 'report.json').read_text())
    assert report['sr']['tiles'] == len(tiles) and (out / 'sr' / 'preview.png').is_file()
    # a simulated flight fits the model: SR is kept on most tiles, and the fallbacks are counted
    fell_back = [t for t in tiles if t['source'] == 'frame']
    assert report['sr']['tiles_fallback'] == len(fell_back) == sum(report['sr']['tiles_fallback_by_reason'].values())
    assert report['sr']['tiles_sr'] == len(tiles) - len(fell_back) >= len(tiles) // 2
    # report.html shows the tile made from the most frames beside the mosaic, and the gain of every
    # tile checked against a frame it was not given (or says that none was)
    frames = {t['file']: t['frames'] for t in report['sr']['per_tile'] if 'file' in t}
    checked = sum(1 for t in report['sr']['per_tile'] if all(t.get('held_out_rms') or [None]))
    page = (out / 'report.html').read_text(encoding='utf-8')
    example = re.search(r'data-figure="sr" data-example="([^"]+)"', page).group(1)
    assert frames[example] == max(frames.values())
    assert (f'data-figure="sr" data-tiles="{checked}"' in page) if checked else ('no gain to show' in page)
    check_sr_geotiffs(out, tiles, mosaic)


def check_sr_geotiffs(out: Path, tiles: list[dict], mosaic: np.ndarray) -> None:
    """The georeferenced SR outputs, read back with rasterio (GDAL): each tile's GeoTIFF and the SR
    mosaic sit on mosaic.tif's map grid refined by the factor, and hold the tiles' pixels."""
    import rasterio
    from rio_cogeo.cogeo import cog_validate

    assert cog_validate(out / 'mosaic.tif', quiet=True) == (True, [], [])  # a Cloud Optimized GeoTIFF
    with rasterio.open(out / 'mosaic.tif') as m:
        crs, mosaic_t = m.crs, m.transform
    s = tiles[0]['factor']

    def mosaic_map(x: float, y: float) -> tuple[float, float]:
        # mosaic pixel (x, y), centres at integers -> map (GDAL transforms take pixel corners)
        return mosaic_t @ (x + 0.5, y + 0.5)

    for entry in tiles[:3]:
        png = cv2.imread(str(out / 'sr' / entry['file']), cv2.IMREAD_COLOR)[:, :, ::-1]
        assert cog_validate(out / 'sr' / entry['file'].replace('.png', '.tif'), quiet=True)[0], entry['file']
        with rasterio.open(out / 'sr' / entry['file'].replace('.png', '.tif')) as t:
            assert t.crs == crs and (t.height, t.width) == png.shape[:2]
            np.testing.assert_array_equal(np.moveaxis(t.read(), 0, -1), png)
            for u, v in ((0, 0), (png.shape[1] - 1, 17)):   # tiles.json's convention, on the map
                expect = mosaic_map(entry['x0'] + (u + 0.5) / s - 0.5, entry['y0'] + (v + 0.5) / s - 0.5)
                np.testing.assert_allclose(t.transform @ (u + 0.5, v + 0.5), expect, atol=1e-6)
    with rasterio.open(out / 'sr' / 'mosaic_sr.tif') as sr:
        assert sr.crs == crs and (sr.height, sr.width) == (mosaic.shape[0] * s, mosaic.shape[1] * s)
        assert sr.count == 4 and sr.overviews(1)  # RGB + alpha, with overviews for GIS tools
        np.testing.assert_allclose(sr.transform @ (0.5, 0.5), mosaic_map(0.5 / s - 0.5, 0.5 / s - 0.5), atol=1e-6)
        entry = tiles[0]
        x0, y0, w, h = (entry[k] * s for k in ('x0', 'y0', 'width', 'height'))
        region = np.moveaxis(sr.read(window=rasterio.windows.Window(x0, y0, w, h)), 0, -1)
        png = cv2.imread(str(out / 'sr' / entry['file']), cv2.IMREAD_COLOR)[:, :, ::-1]
        np.testing.assert_array_equal(region[:, :, :3], png)
        assert (region[:, :, 3] == 255).all()
        alpha = sr.read(4, out_shape=(mosaic.shape[0], mosaic.shape[1]), resampling=rasterio.enums.Resampling.nearest)
        assert abs((alpha > 0).mean() - (mosaic[:, :, 3] > 0).mean()) < 0.01   # coverage kept


def test_sr_mosaic_strips_are_one_bicubic_resize_with_the_tiles_pasted_in():
    from srmosaic_ros.app.sr_process import sr_mosaic_strips

    rng = np.random.default_rng(0)
    mosaic = cv2.GaussianBlur(rng.uniform(0, 255, (70, 90, 3)).astype(np.float32), (0, 0), 2.0).astype(np.uint8)
    coverage = np.ones((70, 90), bool)
    coverage[:10, :20] = False
    tile = rng.integers(0, 256, (2 * 16, 2 * 24, 3), dtype=np.uint8)
    grey = rng.integers(0, 256, (2 * 8, 2 * 8), dtype=np.uint8)
    full = cv2.resize(mosaic, (180, 140), interpolation=cv2.INTER_CUBIC)
    full[2 * 25:2 * 41, 2 * 30:2 * 54] = tile
    full[2 * 60:2 * 68, 2 * 4:2 * 12] = grey[:, :, None]
    for rows in (7, 16, 128):
        parts = list(sr_mosaic_strips(mosaic, coverage, 2, [(30, 25, tile), (4, 60, grey)], rows=rows))
        assert [r for r, _, _ in parts] == list(range(0, 140, 2 * rows))
        np.testing.assert_array_equal(np.concatenate([p for _, p, _ in parts]), full)
        cov = np.concatenate([c for _, _, c in parts])
        assert cov.shape == (140, 180) and not cov[:20, :40].any() and cov[20:, :].all() and cov[:, 40:].all()
