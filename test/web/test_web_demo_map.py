"""The web map of a real run: `srmosaic process bags/demo --tiles --kmz`, served by `srmosaic serve` and
opened in headless Chromium, and its offline page opened from file://; mosaic.kmz against mosaic.tif."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from urllib.parse import urlparse

import cv2
import numpy as np
import pytest
import rasterio
from rasterio.warp import transform as warp_transform

from srmosaic_ros.io.poses_csv import read_poses_csv
from srmosaic_ros.web.run_source import RunSource
from srmosaic_ros.web.server import start_in_thread
from cli_runner import run_cli

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / 'bags' / 'demo'
KML = '{http://www.opengis.net/kml/2.2}'
GX = '{http://www.google.com/kml/ext/2.2}'
BACKGROUND = (0x2b, 0x2d, 0x31)  # map.css: the map's background where no tile is


@pytest.fixture(scope='module')
def demo_run(tmp_path_factory):
    """The demo flight processed as a user would, with the web tiles and the KMZ (one run for the module)."""
    out = tmp_path_factory.mktemp('demo') / 'out'
    run = run_cli('process', str(DEMO), '--out', str(out), '--tiles', '--kmz', '--no-progress')
    assert run.returncode == 0, run.stderr[-2000:]
    assert 'web map:' in run.stdout and 'KMZ:' in run.stdout
    return out


def test_report_times_the_map_outputs(demo_run):
    report = json.loads((demo_run / 'report.json').read_text())
    outputs = report['stage_times']['outputs']
    assert outputs['tiles_s'] > 0 and outputs['kmz_s'] > 0 and outputs['total_s'] >= outputs['tiles_s'] + outputs['kmz_s']
    tiles = report['map_outputs']['tiles']['layers']['mosaic']
    written = sorted((demo_run / 'tiles').rglob('*.png'))
    assert len(written) == tiles['tiles'] > 0
    zooms = {int(p.relative_to(demo_run / 'tiles').parts[0]) for p in written}
    assert zooms == set(range(tiles['minzoom'], tiles['maxzoom'] + 1))
    for path in written[:: max(1, len(written) // 10)]:
        tile = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert tile.shape == (256, 256, 4) and tile[..., 3].max() == 255
    for name in ('map.html', 'map_config.js', 'map_files/leaflet.js', 'map_files/leaflet.css', 'map_files/map.js'):
        assert (demo_run / name).is_file(), name


def test_run_source_status_of_the_demo(demo_run):
    status = RunSource(demo_run).status()
    report = json.loads((demo_run / 'report.json').read_text())
    poses = [p for p in read_poses_csv(demo_run / 'poses.csv') if np.isfinite(p['latitude'])]
    assert status['frames'] == report['frames_in']
    assert status['pose']['lat'] == pytest.approx(poses[-1]['latitude']) and status['pose']['lon'] == pytest.approx(
        poses[-1]['longitude'])
    assert len(status['track']['coordinates']) == len(poses)
    west, south, east, north = status['bounds']
    ring = status['footprint']['coordinates'][0]
    assert len(ring) == 5 and ring[0] == ring[-1]
    # the last frame's footprint lies on the mosaic, around the aircraft
    lons, lats = zip(*ring, strict=True)
    assert west - 1e-6 <= min(lons) < max(lons) <= east + 1e-6 and south - 1e-6 <= min(lats) < max(lats) <= north + 1e-6
    assert min(lons) < status['pose']['lon'] < max(lons) and min(lats) < status['pose']['lat'] < max(lats)


def _served_tile(url: str) -> np.ndarray | None:
    """RGBA of a tile fetched over HTTP, None for a 404."""
    try:
        with urllib.request.urlopen(url, timeout=30) as resp:
            bgra = cv2.imdecode(np.frombuffer(resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
    except urllib.error.HTTPError as exc:
        assert exc.code == 404
        return None
    return bgra[:, :, [2, 1, 0, 3]]


def test_tiles_agree_with_mosaic_tif(demo_run):
    """At covered pixels of mosaic.tif, the served tile's pixel at the same lon/lat has the mosaic's colour
    (within the range of the pixel's 3x3 neighbourhood: the tile is resampled on another grid)."""
    from srmosaic_ros.web.tiles import _tms

    source = RunSource(demo_run)
    z = source.status()['maxzoom']
    with start_in_thread(source) as srv:
        _compare_tiles(demo_run, z, lambda x, y: _served_tile(f'{srv.url}tiles/{z}/{x}/{y}.png'), _tms)


def _compare_tiles(demo_run, z, tile_at, _tms):
    with rasterio.open(demo_run / 'mosaic.tif') as ds:
        img = ds.read()
        crs, t = ds.crs, ds.transform
    rng = np.random.default_rng(0)
    covered = np.argwhere(img[3, 2:-2, 2:-2] == 255) + 2
    checked = 0
    for r, c in covered[rng.choice(len(covered), 40, replace=False)]:
        ex, ny = t @ (c + 0.5, r + 0.5)
        lon, lat = (v[0] for v in warp_transform(crs, 'EPSG:4326', [ex], [ny]))
        tile = _tms().tile(lon, lat, z)
        b = _tms().xy_bounds(tile)
        mx, my = (v[0] for v in warp_transform('EPSG:4326', 'EPSG:3857', [lon], [lat]))
        col, row = int((mx - b.left) / (b.right - b.left) * 256), int((b.top - my) / (b.top - b.bottom) * 256)
        rgba = tile_at(tile.x, tile.y)
        if rgba is None or rgba[row, col, 3] < 255:
            continue
        near = img[:3, r - 1:r + 2, c - 1:c + 2].reshape(3, -1).astype(int)
        value = rgba[row, col, :3].astype(int)
        assert np.all(value >= near.min(axis=1) - 3) and np.all(value <= near.max(axis=1) + 3), (r, c, value, near)
        checked += 1
    assert checked >= 30


def test_kmz_overlay_matches_mosaic_tif(demo_run):
    with zipfile.ZipFile(demo_run / 'mosaic.kmz') as zf:
        names = zf.namelist()
        assert names[0] == 'doc.kml'
        doc = ET.fromstring(zf.read('doc.kml'))
        href = doc.find(f'.//{KML}GroundOverlay/{KML}Icon/{KML}href').text
        assert href in names
        image = cv2.imdecode(np.frombuffer(zf.read(href), np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.ndim == 3 and image.shape[2] == 4 and image[..., 3].min() == 0 and image[..., 3].max() == 255
    quad = [tuple(map(float, p.split(',')[:2]))
            for p in doc.find(f'.//{GX}LatLonQuad/{KML}coordinates').text.split()]
    with rasterio.open(demo_run / 'mosaic.tif') as ds:
        t, w, h, crs = ds.transform, ds.width, ds.height, ds.crs
    assert image.shape[1] / image.shape[0] == pytest.approx(w / h, rel=0.01)
    # gx:LatLonQuad: lower-left, lower-right, upper-right, upper-left of the image's outer corners
    corners = [t @ (0, h), t @ (w, h), t @ (w, 0), t @ (0, 0)]
    lons, lats = warp_transform(crs, 'EPSG:4326', [c[0] for c in corners], [c[1] for c in corners])
    for (qlon, qlat), lon, lat in zip(quad, lons, lats, strict=True):
        assert qlon == pytest.approx(lon, abs=1e-8) and qlat == pytest.approx(lat, abs=1e-8)


def _wait_for_map(page) -> None:
    page.wait_for_function("""() => {
        const loaded = Array.from(document.querySelectorAll('.srm-layer-1 img'))
            .filter(img => img.complete && img.naturalWidth > 0);
        return loaded.length >= 2 && document.querySelector('.srm-aircraft') !== null
            && document.querySelector('path.srm-footprint') !== null && document.querySelector('path.srm-track') !== null;
    }""", timeout=60_000)


def _painted_where_the_mosaic_is(page, lonlat) -> None:
    """The screenshot's pixel at a covered point of the mosaic is not the map's bare background."""
    point = page.evaluate('([lat, lon]) => { const p = srmosaic.map.latLngToContainerPoint([lat, lon]); '
                          'return [Math.round(p.x), Math.round(p.y)]; }', [lonlat[1], lonlat[0]])
    shot = cv2.imdecode(np.frombuffer(page.screenshot(), np.uint8), cv2.IMREAD_COLOR)
    x, y = point
    assert 0 <= x < shot.shape[1] and 0 <= y < shot.shape[0]
    patch = shot[y - 2:y + 3, x - 2:x + 3, ::-1].reshape(-1, 3).astype(int)
    assert np.abs(patch - np.array(BACKGROUND)).max(axis=1).min() > 10, patch


def _covered_lonlat(demo_run) -> tuple[float, float]:
    with rasterio.open(demo_run / 'mosaic.tif') as ds:
        alpha = ds.read(4)
        r, c = np.argwhere(alpha == 255)[len(np.argwhere(alpha == 255)) // 2]
        ex, ny = ds.transform @ (c + 0.5, r + 0.5)
        lon, lat = warp_transform(ds.crs, 'EPSG:4326', [ex], [ny])
    return lon[0], lat[0]


class Bumped:
    """The run's source with a version the test raises, as a live source's grows."""

    def __init__(self, inner):
        self.inner, self.extra = inner, 0

    def tile_png(self, *args):
        return self.inner.tile_png(*args)

    def status(self):
        return {**self.inner.status(), 'version': self.version()}

    def version(self):
        return self.inner.version() + self.extra


def test_served_page_in_chromium(demo_run, chromium):
    """`/` of the served run shows mosaic tiles, the aircraft, the footprint and the track, asks nothing
    of any host but the server, and reloads its tiles and status on a new version."""
    source = Bumped(RunSource(demo_run))
    with start_in_thread(source) as srv:
        page = chromium.new_page(viewport={'width': 1000, 'height': 700})
        hosts: set[str] = set()
        page.on('request', lambda r: hosts.add(urlparse(r.url).netloc))
        page.goto(srv.url)
        _wait_for_map(page)
        _painted_where_the_mosaic_is(page, _covered_lonlat(demo_run))
        loads = page.evaluate('srmosaic.statusLoads')
        source.extra += 1
        page.wait_for_function(f'() => srmosaic.refreshes >= 1 && srmosaic.statusLoads > {loads}', timeout=30_000)
        assert page.evaluate("document.querySelector('.srm-layer-1 img').src").endswith(f'?v={source.version()}')
        page.close()
    assert hosts == {f'127.0.0.1:{srv.port}'}, hosts


def test_offline_page_from_file(demo_run, chromium):
    """DIR/map.html opened from file:// shows the tiles, aircraft, footprint and track with no request
    outside the folder."""
    page = chromium.new_page(viewport={'width': 1000, 'height': 700})
    urls: list[str] = []
    page.on('request', lambda r: urls.append(r.url))
    page.goto((demo_run / 'map.html').as_uri())
    _wait_for_map(page)
    _painted_where_the_mosaic_is(page, _covered_lonlat(demo_run))
    page.close()
    folder = demo_run.resolve().as_uri()
    assert urls and all(u.startswith(folder + '/') for u in urls), [u for u in urls if not u.startswith(folder)]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_serve_command(demo_run):
    """`srmosaic serve DIR --port N` serves the run on 127.0.0.1 until stopped."""
    port = _free_port()
    proc = subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.cli', 'serve', str(demo_run), '--port', str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith(f'srmosaic map: http://127.0.0.1:{port}/'), (line, proc.stderr.read() if proc.poll() else '')
        deadline = time.monotonic() + 60
        while True:
            try:
                with urllib.request.urlopen(f'http://127.0.0.1:{port}/status.json', timeout=10) as resp:
                    status = json.loads(resp.read())
                break
            except OSError:
                assert time.monotonic() < deadline and proc.poll() is None
                time.sleep(0.2)
        assert status['frames'] == json.loads((demo_run / 'report.json').read_text())['frames_in']
    finally:
        proc.terminate()
        proc.wait(timeout=30)
