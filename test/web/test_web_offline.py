"""web/offline.py on a small georeferenced run: WebP tiles with the page's settings, the KMZ; and process's
map outputs on a run without georeferencing."""
from __future__ import annotations

import json
import zipfile

import cv2
import numpy as np
from web_fixtures import synthetic_run

from srmosaic_ros.web.offline import write_kmz, write_tiles


def _config(out):
    text = (out / 'map_config.js').read_text()
    assert text.startswith('window.SRMOSAIC_CONFIG = ')
    return json.loads(text.split('=', 1)[1].strip().rstrip(';'))


def test_webp_tiles_and_their_page(tmp_path):
    run = synthetic_run(tmp_path / 'run', rotation_rad=0.2)
    figures = write_tiles(run.out, 'webp', threads=2, name='flight 7')
    for layer, folder in (('mosaic', 'tiles'), ('sr', 'sr')):
        files = sorted((run.out / folder).rglob('*.webp'))
        assert len(files) == figures['layers'][layer]['tiles'] > 0
        assert not list((run.out / folder).rglob('*.png'))
        tile = cv2.imdecode(np.frombuffer(files[len(files) // 2].read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
        assert tile.shape == (256, 256, 4)
    config = _config(run.out)
    assert config['mode'] == 'static' and config['title'] == 'srmosaic map: flight 7'
    assert config['layers'] == {'mosaic': 'tiles/{z}/{x}/{y}.webp', 'sr': 'sr/{z}/{x}/{y}.webp'}
    status = config['status']
    assert status['frames'] == 10 and 'out_dir' not in status['diagnostics']
    assert (status['minzoom'], status['maxzoom']) == (figures['layers']['mosaic']['minzoom'],
                                                     figures['layers']['mosaic']['maxzoom'])
    assert (run.out / 'map.html').read_bytes().count(b'map_files/') == 4


def test_kmz_of_a_grey_run(tmp_path):
    from srmosaic_ros.core.georef import GeoRaster
    from srmosaic_ros.io.geotiff import write_geotiff

    grey = np.tile(np.linspace(0, 1, 300, dtype=np.float32), (200, 1))
    covered = np.zeros((200, 300), bool)
    covered[20:180, 20:280] = True
    write_geotiff(tmp_path / 'mosaic.tif', grey, GeoRaster(32614, 0.5, 587500.0, 3338200.0, 0.1), coverage=covered)
    figures = write_kmz(tmp_path)
    assert figures['image_px'] == [300, 200]
    with zipfile.ZipFile(tmp_path / 'mosaic.kmz') as zf:
        assert zf.namelist() == ['doc.kml', 'mosaic.png']
        image = cv2.imdecode(np.frombuffer(zf.read('mosaic.png'), np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.shape == (200, 300, 4)
    assert image[100, 150, 3] == 255 and image[5, 5, 3] == 0
    assert image[100, 150, 0] == image[100, 150, 1] == image[100, 150, 2]  # grey as R = G = B


def test_map_outputs_of_a_run_without_georeferencing(tmp_path):
    from srmosaic_ros.app.map_outputs import map_outputs

    report = {'frames_in': 3, 'not_georeferenced_reason': 'no fixes'}
    out = map_outputs(tmp_path, report, 0.0, tiles='png', kmz=True)
    assert 'no fixes' in out['map_outputs']['skipped'] and 'mosaic.tif' in out['map_outputs']['skipped']
    assert json.loads((tmp_path / 'report.json').read_text())['map_outputs'] == out['map_outputs']
    assert not (tmp_path / 'tiles').exists() and not (tmp_path / 'mosaic.kmz').exists()
