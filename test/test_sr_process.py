"""`srmosaic process --sr` on the demo bag: the sr/tiles.json contract and tiles that hold the mosaic."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

DEMO = Path(__file__).resolve().parent.parent / 'bags' / 'demo'


def test_process_sr_writes_tiles_contract(tmp_path):
    out = tmp_path / 'out'
    run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', 'process', str(DEMO), '--out', str(out), '--sr',
                          '--no-progress', '--checkpoint-every', '0'], capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr
    tiles = json.loads((out / 'sr' / 'tiles.json').read_text())
    assert len(tiles) >= 5
    mosaic = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    for entry in tiles[:5]:
        assert set(entry) == {'file', 'x0', 'y0', 'width', 'height', 'factor'} and entry['factor'] == 2
        tile = cv2.imread(str(out / 'sr' / entry['file']), cv2.IMREAD_COLOR)
        assert tile.shape[:2] == (entry['height'] * 2, entry['width'] * 2)
        # Downsampled back by the factor, the SR tile shows the same ground as the mosaic region.
        x0, y0, w, h = entry['x0'], entry['y0'], entry['width'], entry['height']
        back = cv2.resize(tile, (w, h), interpolation=cv2.INTER_AREA).astype(float)
        region = mosaic[y0:y0 + h, x0:x0 + w, :3].astype(float)
        assert np.abs(back[4:-4, 4:-4] - region[4:-4, 4:-4]).mean() < 4.0
    report = json.loads((out / 'report.json').read_text())
    assert report['sr']['tiles'] == len(tiles) and (out / 'sr' / 'preview.png').is_file()
