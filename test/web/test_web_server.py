"""web/server.py and web/run_source.py over a real socket: status, tiles, the event stream, hostile URLs."""
from __future__ import annotations

import http.client
import json
import time

import cv2
import numpy as np
import pytest
from web_fixtures import SR_BOX, synthetic_run

from srmosaic_ros.errors import InputError
from srmosaic_ros.web import run_source
from srmosaic_ros.web.run_source import RunSource
from srmosaic_ros.web.server import STATIC_FILES, make_app, start_in_thread
from srmosaic_ros.web.tiles import tiles_covering
from cli_runner import run_cli


class Bumped:
    """A RunSource whose version the test raises (a live source's tiles changing)."""

    def __init__(self, inner: RunSource) -> None:
        self.inner, self.extra = inner, 0

    def tile_png(self, layer, z, x, y):
        return self.inner.tile_png(layer, z, x, y)

    def status(self):
        return {**self.inner.status(), 'version': self.version()}

    def version(self):
        return self.inner.version() + self.extra


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    return synthetic_run(tmp_path_factory.mktemp('run'))


@pytest.fixture(scope='module')
def server(run):
    source = Bumped(RunSource(run.out))
    with start_in_thread(source) as srv:
        srv.source = source
        yield srv


def get(srv, path: str, method: str = 'GET') -> tuple[int, dict[str, str], bytes]:
    """One request with ``path`` sent as is (http.client does not normalise it)."""
    conn = http.client.HTTPConnection('127.0.0.1', srv.port, timeout=30)
    try:
        conn.request(method, path)
        resp = conn.getresponse()
        return resp.status, {k.lower(): v for k, v in resp.getheaders()}, resp.read()
    finally:
        conn.close()


def test_status_fields(server, run):
    code, headers, body = get(server, '/status.json')
    assert code == 200 and headers['content-type'].startswith('application/json')
    status = json.loads(body)
    for key in ('frames', 'pose', 'footprint', 'track', 'bounds', 'minzoom', 'maxzoom', 'diagnostics', 'version', 'live'):
        assert key in status, key
    assert status['frames'] == 10 and status['live'] is False
    west, south, east, north = status['bounds']
    lon, lat = run.marker_lonlat
    assert west < lon < east and south < lat < north
    pose = status['pose']
    assert west < pose['lon'] < east and south < pose['lat'] < north and pose['alt'] == 120.0
    assert pose['yaw_deg'] == pytest.approx(-3.0) and pose['heading_deg'] == pytest.approx(93.0)  # ENU yaw -> compass
    assert status['track']['type'] == 'LineString' and len(status['track']['coordinates']) == 10
    assert status['footprint'] is None  # the synthetic run has no frames.csv
    assert status['minzoom'] < status['maxzoom'] < status['sr_maxzoom']


def _covered_tile(status, lonlat):
    from srmosaic_ros.web.tiles import _tms  # the grid's own lookup of the tile holding a point

    tile = _tms().tile(lonlat[0], lonlat[1], status['maxzoom'])
    return tile.z, tile.x, tile.y


def test_mosaic_tile_is_png_with_alpha(server, run):
    status = json.loads(get(server, '/status.json')[2])
    z, x, y = _covered_tile(status, run.marker_lonlat)
    code, headers, body = get(server, f'/tiles/{z}/{x}/{y}.png')
    assert code == 200 and headers['content-type'] == 'image/png' and body[:8] == b'\x89PNG\r\n\x1a\n'
    tile = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)
    assert tile.shape == (256, 256, 4) and tile[..., 3].max() == 255
    # the query string the page adds (?v=) is ignored
    assert get(server, f'/tiles/{z}/{x}/{y}.png?v=7')[2] == body


def test_empty_tiles_are_404(server, run):
    status = json.loads(get(server, '/status.json')[2])
    z, x, y = _covered_tile(status, (run.marker_lonlat[0] + 0.5, run.marker_lonlat[1]))
    assert get(server, f'/tiles/{z}/{x}/{y}.png')[0] == 404
    assert get(server, f'/sr/{z}/{x}/{y}.png')[0] == 404


def test_sr_layer_only_inside_the_sr_tiles(server, run):
    """The SR layer shows mosaic_sr.tif inside tiles.json's boxes, nothing elsewhere."""
    status = json.loads(get(server, '/status.json')[2])
    x0, y0, w, h = SR_BOX
    inside = run.raster.lonlat_from_pixels(np.array([[x0 + w / 2, y0 + h / 2]]))[0]
    z, x, y = _covered_tile({'maxzoom': status['sr_maxzoom']}, inside)
    code, _, body = get(server, f'/sr/{z}/{x}/{y}.png')
    assert code == 200
    assert cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)[..., 3].max() == 255
    outside = run.marker_lonlat  # covered by the mosaic, outside the SR box
    z, x, y = _covered_tile({'maxzoom': status['sr_maxzoom']}, outside)
    assert get(server, f'/tiles/{z}/{x}/{y}.png')[0] == 200
    assert get(server, f'/sr/{z}/{x}/{y}.png')[0] == 404


def test_page_config_and_files(server):
    code, headers, body = get(server, '/')
    assert code == 200 and headers['content-type'].startswith('text/html')
    html = body.decode()
    assert 'map_config.js' in html and 'map_files/leaflet.js' in html
    assert 'http://' not in html and 'https://' not in html  # nothing from the internet
    assert "default-src 'self'" in headers['content-security-policy'] and headers['x-content-type-options'] == 'nosniff'
    code, _, body = get(server, '/map_config.js')
    assert code == 200 and body.startswith(b'window.SRMOSAIC_CONFIG = ')
    config = json.loads(body.decode().split('=', 1)[1].strip().rstrip(';'))
    assert config['status_url'] == 'status.json' and config['layers']['sr'] == 'sr/{z}/{x}/{y}.png'
    for name in STATIC_FILES:
        code, _, body = get(server, f'/map_files/{name}')
        assert code == 200 and body, name


def test_events_stream_a_new_version(server):
    conn = http.client.HTTPConnection('127.0.0.1', server.port, timeout=30)
    conn.request('GET', '/events')
    resp = conn.getresponse()
    assert resp.status == 200 and resp.getheader('Content-Type') == 'text/event-stream'

    def next_version() -> int:
        while True:
            line = resp.readline()
            assert line, 'the event stream ended'
            if line.startswith(b'data: '):
                return json.loads(line[6:])['version']

    first = next_version()
    server.source.extra += 1
    assert next_version() == first + 1
    conn.close()


HOSTILE = ['/tiles/../../etc/passwd', '/tiles/99/0/0.png', '/tiles/27/0/0.png', '/tiles/3/8/0.png', '/tiles/3/0/8.png',
           '/tiles/1e9/1/1.png', '/tiles/a/b/c.png', '/tiles/-1/0/0.png', '/tiles/1/0/0.jpg', '/tiles/1/0/0.png/',
           '/tiles/01/0/0.png', '/tiles/1/0/' + '9' * 400 + '.png', '/tiles/' + '9' * 40 + '/0/0.png',
           '/tiles/%2e%2e/%2e%2e/etc/passwd', '/tiles/1/0/%2e%2e.png', '/sr/../report.json', '/sr/1/1/1.png.png',
           '/map_files/../server.py', '/map_files/%2e%2e/server.py', '/map_files/leaflet/leaflet.js',
           '/map_files/', '/map_files//etc/passwd', '/mosaic.tif', '/report.json', '/static/leaflet.js',
           '/status.json/..', '//etc/passwd', '/%00', '/tiles/1/0/0.png%00.png', '/events/../status.json.bak']


@pytest.mark.parametrize('path', HOSTILE)
def test_hostile_urls_are_404_or_400(server, path):
    code, _, body = get(server, path)
    assert code in (400, 404), (path, code)
    assert b'root:' not in body and b'import' not in body


@pytest.mark.parametrize('method', ['POST', 'PUT', 'DELETE', 'PATCH'])
@pytest.mark.parametrize('path', ['/', '/status.json', '/tiles/1/0/0.png', '/map_files/map.js', '/events'])
def test_nothing_writes(server, method, path):
    assert get(server, path, method)[0] == 405


def test_server_stays_up_after_hostile_urls(server):
    for path in HOSTILE:
        get(server, path)
    assert get(server, '/status.json')[0] == 200


def test_make_app_needs_a_map_source():
    with pytest.raises(TypeError, match='MapSource'):
        make_app(object())


def test_run_source_reloads_a_new_run(tmp_path, monkeypatch):
    monkeypatch.setattr(run_source, 'RELOAD_CHECK_S', 0.0)
    synthetic_run(tmp_path, sr=False)
    source = RunSource(tmp_path)
    assert source.version() == 1 and source.status()['frames'] == 10
    time.sleep(0.01)  # another modification time
    report = json.loads((tmp_path / 'report.json').read_text())
    (tmp_path / 'report.new').write_text(json.dumps({**report, 'frames_in': 12}))
    (tmp_path / 'report.new').replace(tmp_path / 'report.json')
    assert source.version() == 2 and source.status()['frames'] == 12


def test_not_georeferenced_folder_is_a_clear_error(tmp_path):
    (tmp_path / 'mosaic.png').write_bytes(b'')
    (tmp_path / 'report.json').write_text(json.dumps({'not_georeferenced_reason': 'the bag has no /fix messages'}))
    with pytest.raises(InputError, match='not georeferenced.*no /fix messages.*srmosaic process'):
        RunSource(tmp_path)
    with pytest.raises(InputError, match='no such folder'):
        RunSource(tmp_path / 'missing')
    cli = run_cli('serve', str(tmp_path))
    assert cli.returncode == 2
    assert cli.stderr.count('\n') == 1 and 'not georeferenced' in cli.stderr


def test_every_covered_tile_of_a_zoom_is_served(server, run):
    """Each tile of the mosaic's box at its deepest zoom is 200 (something painted) or 404 (nothing)."""
    status = json.loads(get(server, '/status.json')[2])
    codes = [get(server, f'/tiles/{z}/{x}/{y}.png')[0] for z, x, y in tiles_covering(status['bounds'], status['maxzoom'])]
    assert set(codes) <= {200, 404} and codes.count(200) >= 1


class Growing:
    """A live source that has nothing yet, then the synthetic run (a late first fix)."""

    def __init__(self, inner: RunSource) -> None:
        self.inner, self.ready = inner, False

    def tile_png(self, layer, z, x, y):
        return self.inner.tile_png(layer, z, x, y) if self.ready else None

    def status(self):
        if not self.ready:
            return {'frames': 0, 'pose': None, 'footprint': None, 'track': None, 'bounds': None, 'minzoom': None,
                    'maxzoom': None, 'diagnostics': {}, 'version': 1, 'live': True}
        return {**self.inner.status(), 'version': 2, 'live': True}

    def version(self):
        return 2 if self.ready else 1


def test_page_starts_empty_and_shows_the_map_when_it_comes(run, chromium):
    """The page opened before anything is painted shows the mosaic once the source has it, without a reload."""
    source = Growing(RunSource(run.out))
    with start_in_thread(source) as srv:
        page = chromium.new_page(viewport={'width': 800, 'height': 600})
        page.goto(srv.url)
        page.wait_for_function('() => srmosaic.statusLoads >= 1 && srmosaic.events >= 1', timeout=30_000)
        assert page.evaluate("document.querySelectorAll('.srm-layer-1 img').length") == 0
        source.ready = True
        page.wait_for_function("""() => srmosaic.fitted && Array.from(document.querySelectorAll('.srm-layer-1 img'))
            .some(img => img.complete && img.naturalWidth > 0)""", timeout=30_000)
        assert page.evaluate("document.querySelector('.srm-aircraft') !== null")
        assert 'live' in page.inner_text('#info')
        page.close()


def test_the_page_files_are_package_data():
    """Every file the server reads from its package is matched by setup.py's package_data (a wheel or a
    colcon install carries it), and exists."""
    import ast
    import fnmatch
    from pathlib import Path

    import srmosaic_ros.web as web_package
    from srmosaic_ros.web.server import PAGE_FILE

    setup = Path(__file__).resolve().parents[2] / 'setup.py'
    call = next(node for node in ast.walk(ast.parse(setup.read_text()))
                if isinstance(node, ast.Call) and getattr(node.func, 'id', '') == 'setup')
    package_data = next(kw.value for kw in call.keywords if kw.arg == 'package_data')
    globs = [elt.value for value in package_data.values for elt in value.elts]
    here = Path(web_package.__file__).parent
    for path in [PAGE_FILE] + [p for p, _ in STATIC_FILES.values()]:
        name = f'static/{path}'
        assert (here / name).is_file(), name
        assert any(fnmatch.fnmatch(name, g) and name.count('/') == g.count('/') for g in globs), name
