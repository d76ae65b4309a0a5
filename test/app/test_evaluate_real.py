"""Truth-free evaluation of a real run (srmosaic_ros/app/evaluate_real.py) on the repository's real stills."""
from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from pyproj import Transformer

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.metrics import apply_homography
from srmosaic_ros.errors import InputError
from srmosaic_ros.app.evaluate_real import MAX_COMPARE_PX, evaluate_real, format_real_figures, read_meta_positions
from srmosaic_ros.io.mosaic_files import FRAMES_CSV_HEADER
from srmosaic_ros.app.process import process_input
from repo_paths import REPO

SEQUENCES = REPO / 'data' / 'sequences'
CALITERRA = SEQUENCES / 'caliterra'


@pytest.fixture(scope='module')
def caliterra_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The 14 real Caliterra stills processed once by the chained pipeline (georeferenced by their
    geotags): upscaled into its mosaic, they exercise the evaluation's subsampling (the global
    alignment of the same stills is tested in test_survey_process.py). Feather compositing: the
    figures below were measured on it (best view is judged in test_best_view_real.py)."""
    out = tmp_path_factory.mktemp('caliterra') / 'out'
    report = process_input(CALITERRA, out, pipeline_config({'survey.mode': 'chain', 'mosaic.blend': 'feather'}),
                           progress=False)
    return out, report


@pytest.fixture(scope='module')
def caliterra_figures(caliterra_run: tuple[Path, dict]) -> dict:
    return evaluate_real(caliterra_run[0], progress=False)


def _copy_run(src: Path, dst: Path) -> Path:
    dst.mkdir(parents=True)
    for name in ('frames.csv', 'report.json', 'mosaic.png', 'mosaic.tif'):
        if (src / name).is_file():
            shutil.copy(src / name, dst / name)
    return dst


def _rows(frames_csv: Path) -> list[dict[str, str]]:
    with open(frames_csv, newline='') as handle:
        return list(csv.DictReader(handle))


def _write_rows(frames_csv: Path, rows: list[dict[str, str]], meta: list[tuple[float, float]] | None = None) -> None:
    """frames.csv with the given rows, and with meta_latitude,meta_longitude columns when ``meta``."""
    header = FRAMES_CSV_HEADER + (['meta_latitude', 'meta_longitude'] if meta is not None else [])
    with open(frames_csv, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for i, row in enumerate(rows):
            extra = [repr(meta[i][0]), repr(meta[i][1])] if meta is not None else []
            writer.writerow([row[k] for k in FRAMES_CSV_HEADER] + extra)


def _H(row: dict[str, str]) -> np.ndarray:
    return np.array([float(row[f'h{r}{c}']) for r in range(3) for c in range(3)]).reshape(3, 3)


def test_real_stills_agree_with_their_mosaic(caliterra_run: tuple[Path, dict], caliterra_figures: dict) -> None:
    """All 14 frames in the mosaic, each agreeing with the composite, which is softer than the frames."""
    # measured: NCC median 0.989, p10 0.957; sharpness median 0.78 to 0.82
    fig = caliterra_figures
    assert fig['frames_rows'] == 14 and fig['frames_in_main'] == 14 and fig['fraction_in_main'] == 1.0
    assert fig['frames_compared'] == 14 and len(fig['per_frame']) == 14 and fig['frames_not_in_input'] == 0
    assert fig['input_kind'] == 'images' and fig['input'] == str(CALITERRA)
    assert fig['ncc_median'] > 0.97 and fig['ncc_p10'] > 0.92
    assert 0.0 < fig['sharpness_median'] <= 1.5
    # frames upscaled into the mosaic beyond MAX_COMPARE_PX are compared on every k-th pixel
    assert fig['frames_reduced'] >= 5
    assert all(p['pixels'] <= MAX_COMPARE_PX * 1.01 for p in fig['per_frame'])
    lines = format_real_figures(fig)
    assert lines[0] == 'frames in main mosaic: 14/14 (100%)'
    assert lines[1].startswith(f'consistency (NCC frame vs mosaic): median {fig["ncc_median"]:.3f}, p10 ')
    assert lines[2].startswith(f'sharpness (mosaic vs frame gradient energy): median {fig["sharpness_median"]:.3f}')
    assert lines[3].startswith('seen from the frames') and not any('much coarser' in x for x in lines)
    json.dumps(fig, allow_nan=False)  # figures are plain JSON


def test_misplaced_frames_lower_consistency(caliterra_run: tuple[Path, dict], caliterra_figures: dict,
                                            tmp_path: Path) -> None:
    """Half the homographies shifted by 8 mosaic px: those frames no longer agree with the mosaic,
    and the others' figures are unchanged."""
    # measured: NCC median 0.989 -> 0.948 and p10 0.957 -> 0.827 over all frames; the shifted
    # frames' median 0.976 -> 0.883, each down by 0.05 to 0.21
    out = _copy_run(caliterra_run[0], tmp_path / 'shifted')
    rows = _rows(out / 'frames.csv')
    shift = np.array([[1.0, 0.0, 8.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    for row in rows[1::2]:
        H = shift @ _H(row)
        row.update({f'h{r}{c}': repr(float(H[r, c])) for r in range(3) for c in range(3)})
    _write_rows(out / 'frames.csv', rows)   # without the meta columns
    fig = evaluate_real(out, progress=False)
    assert fig['frames_compared'] == 14
    assert fig['position'] is None and 'no meta_latitude' in fig['position_note']
    assert format_real_figures(fig)[-1].startswith('position vs metadata: not available (frames.csv has no meta')
    assert fig['ncc_median'] < caliterra_figures['ncc_median'] - 0.03
    assert fig['ncc_p10'] < caliterra_figures['ncc_p10'] - 0.08
    shifted = np.array([p['ncc'] for p in fig['per_frame'][1::2]])
    before = np.array([p['ncc'] for p in caliterra_figures['per_frame'][1::2]])
    assert np.all(shifted < before - 0.04) and np.median(shifted) < np.median(before) - 0.06
    for a, b in zip(fig['per_frame'][0::2], caliterra_figures['per_frame'][0::2]):
        assert a['ncc'] == pytest.approx(b['ncc'], abs=1e-9)


def _exif_positions() -> list[tuple[float, float]]:
    with open(CALITERRA / 'telemetry_from_exif.csv', newline='') as handle:
        tele = {r['file']: (float(r['lat']), float(r['lon'])) for r in csv.DictReader(handle)}
    return [tele[f.name] for f in sorted((CALITERRA / 'images').iterdir())]


def test_position_against_exif_geotags(caliterra_run: tuple[Path, dict], tmp_path: Path) -> None:
    """The EXIF GPS as meta positions: the frame centres lie as far from them as the geotag fit's
    own residual (report.json georeferenced.geotag_residual_rms_m) says."""
    # measured: 4.72 m RMS over these 13 frames (4.571 m over all 14, the fit's residual), max 7.95 m
    out = _copy_run(caliterra_run[0], tmp_path / 'meta')
    rows = _rows(out / 'frames.csv')
    meta = _exif_positions()
    assert len(meta) == len(rows) == 14
    meta[3] = (math.nan, math.nan)   # unknown position: left out, not an error
    _write_rows(out / 'frames.csv', rows, meta)
    assert len(read_meta_positions(out / 'frames.csv')) == 13
    fig = evaluate_real(out, progress=False, max_frames=3)   # positions use every frame regardless
    pos = fig['position']
    geo = caliterra_run[1]['georeferenced']
    assert pos['frames'] == 13 and pos['crs'] == f'EPSG:{geo["epsg"]}' == 'EPSG:32614'
    assert math.isfinite(pos['rms_m']) and pos['rms_m'] == pytest.approx(geo['geotag_residual_rms_m'], rel=0.15)
    assert pos['median_m'] <= pos['rms_m'] <= pos['max_m'] < 15.0
    assert fig['frames_compared'] == 3 and [p['stamp_ns'] for p in fig['per_frame']] == \
        [int(rows[i]['stamp_ns']) for i in (0, 6, 13)]
    assert all(p['position_error_m'] is not None for p in fig['per_frame'])
    assert format_real_figures(fig)[-1].startswith(f'position vs metadata (frame centres): RMS {pos["rms_m"]:.2f} m')
    # without mosaic.tif: no positions, and mosaic.png (read whole) gives the figures mosaic.tif gave
    (out / 'mosaic.tif').unlink()
    report = json.loads((out / 'report.json').read_text())
    report['not_georeferenced_reason'] = 'its geotags cannot place it: the frames look obliquely. Give the mount.'
    (out / 'report.json').write_text(json.dumps(report))
    png = evaluate_real(out, progress=False, max_frames=3)
    assert png['position'] is None   # and the note says why, from report.json, in its first clause
    assert png['position_note'] == 'no mosaic.tif (the run is not georeferenced: its geotags cannot place it)'
    for a, b in zip(png['per_frame'], fig['per_frame'], strict=True):
        assert a['ncc'] == pytest.approx(b['ncc'], abs=1e-6)
        assert a['sharpness_ratio'] == pytest.approx(b['sharpness_ratio'], rel=1e-5)


def test_position_is_zero_where_metadata_is_the_map_itself(caliterra_run: tuple[Path, dict], tmp_path: Path) -> None:
    """Meta positions set to where mosaic.tif puts each frame centre: RMS ~ 0."""
    out = _copy_run(caliterra_run[0], tmp_path / 'exact')
    rows = _rows(out / 'frames.csv')
    h, w = cv2.imread(str(next((CALITERRA / 'images').iterdir()))).shape[:2]
    with rasterio.open(out / 'mosaic.tif') as ds:
        affine, crs = ds.transform, ds.crs
    to_ll = Transformer.from_crs(crs, 'EPSG:4326', always_xy=True)
    meta = []
    for row in rows:
        x, y = apply_homography(_H(row), np.array([[(w - 1) / 2.0, (h - 1) / 2.0]]))[0]
        e, n = affine @ (x + 0.5, y + 0.5)   # GDAL affine: pixel corners
        lon, lat = to_ll.transform(e, n)
        meta.append((lat, lon))
    _write_rows(out / 'frames.csv', rows, meta)
    pos = evaluate_real(out, progress=False, max_frames=1)['position']
    assert pos['frames'] == 14 and pos['max_m'] < 1e-3
    _write_rows(out / 'frames.csv', rows, [(math.nan, math.nan)] * len(rows))   # metadata says nothing
    fig = evaluate_real(out, progress=False, max_frames=1)
    assert fig['position'] is None and 'all NaN' in fig['position_note']


def test_frame_alone_under_itself_scores_one(tmp_path: Path) -> None:
    """A one-frame "run" whose mosaic is exactly the canvas's warp of a real still (at full scale and,
    magnified 2.5x past MAX_COMPARE_PX, on every k-th pixel): NCC 1 and sharpness 1 (pixel conventions);
    the same mosaic at 70 % exposure (as exposure compensation may leave it) is as sharp, a blurred
    one is not."""
    src = next((CALITERRA / 'images').iterdir())
    (tmp_path / 'input').mkdir()
    shutil.copy(src, tmp_path / 'input' / src.name)
    frame = cv2.imread(str(src))
    h, w = frame.shape[:2]
    got = []
    for zoom, gain, blur in ((1.0, 1.0, 0.0), (2.5, 1.0, 0.0), (1.0, 0.7, 0.0), (1.0, 1.0, 1.5)):
        got.append(_one_frame_run(tmp_path, frame, zoom, gain, blur)['per_frame'][0])
    assert got[0]['scale'] == 1.0 and got[1]['scale'] < 1.0
    assert got[0]['ncc'] > 0.9999 and got[0]['sharpness_ratio'] == pytest.approx(1.0, abs=5e-3)
    assert got[1]['ncc'] > 0.9999 and got[1]['sharpness_ratio'] == pytest.approx(1.0, abs=5e-3)
    assert got[2]['ncc'] > 0.999 and got[2]['sharpness_ratio'] == pytest.approx(1.0, abs=0.02)  # raw: 0.49
    assert got[3]['sharpness_ratio'] < 0.6, got[3]
    # seen from the frame: the same up to the bilinear resampling there and back
    # measured: ncc_frame 0.998 / 0.999 / 0.998 / 0.987, sharpness_frame 0.855 / 0.881 / 0.857 / 0.448
    assert all(g['frame_pixels'] > 0.9 * h * w for g in got)
    assert got[0]['ncc_frame'] > 0.99 and 0.8 < got[0]['sharpness_frame'] < 1.0
    assert got[1]['ncc_frame'] > 0.99 and 0.8 < got[1]['sharpness_frame'] < 1.05  # finer mosaic, averaged onto the frame
    assert got[2]['ncc_frame'] > 0.99 and got[2]['sharpness_frame'] == pytest.approx(got[0]['sharpness_frame'], abs=0.02)
    assert got[3]['sharpness_frame'] < 0.6


def _one_frame_run(tmp_path: Path, frame: np.ndarray, zoom: float, gain: float = 1.0, blur: float = 0.0) -> dict:
    """evaluate_real's figures of a one-frame "run" (its input: tmp_path / 'input') whose mosaic is the
    frame turned by 0.3 rad and scaled by ``zoom`` (reduced by area first where zoom < 1, as the
    canvas reduces a frame that shrinks on it), times ``gain``, blurred by ``blur`` px."""
    h, w = frame.shape[:2]
    out = tmp_path / f'out_{zoom}_{gain}_{blur}'
    out.mkdir()
    src, k = frame, 1
    if zoom < 1:  # the frame averaged over k x k blocks, then warped at zoom * k
        k = int(1 / zoom)
        src = cv2.resize(frame, (w // k, h // k), interpolation=cv2.INTER_AREA)
    c, s = math.cos(0.3) * zoom, math.sin(0.3) * zoom
    H = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    corners = apply_homography(H, np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float))
    H[:2, 2] = 5.3 - corners.min(axis=0)   # sub-pixel offset into the mosaic
    far = apply_homography(H, np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float)).max(axis=0)
    size = (int(far[0]) + 8, int(far[1]) + 8)
    o = (k - 1) / 2.0
    H_src = H @ np.array([[k, 0.0, o], [0.0, k, o], [0.0, 0.0, 1.0]])
    mosaic = cv2.warpPerspective(src, H_src, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mosaic = np.clip(np.round(mosaic * gain), 0, 255).astype(np.uint8)
    mosaic = cv2.GaussianBlur(mosaic, (0, 0), blur) if blur else mosaic
    alpha = cv2.warpPerspective(np.full(src.shape[:2], 255, np.uint8), H_src, size, flags=cv2.INTER_NEAREST)
    cv2.imwrite(str(out / 'mosaic.png'), np.dstack([mosaic, alpha]))
    row = {'stamp_ns': '0', 'ok': '1', 'inliers': '0', 'rms_px': 'nan',
           **{f'h{r}{c}': repr(float(H[r, c])) for r in range(3) for c in range(3)}}
    _write_rows(out / 'frames.csv', [row])
    (out / 'report.json').write_text(json.dumps({'input': str(tmp_path / 'input'), 'input_kind': 'images'}))
    return evaluate_real(out, progress=False)


def test_a_mosaic_coarser_than_its_frame_is_seen_from_the_frame(tmp_path: Path) -> None:
    """A frame painted 4 times smaller than it is (an oblique forward flight's later frames in the
    first frame's plane): in the mosaic's pixels it agrees and is as sharp as the frame reduced
    there, so only the view from the frame shows what the mosaic lost of it."""
    # measured: ncc 0.997, sharpness 1.29; ncc_frame 0.978, sharpness_frame 0.26 (0.56 at half size)
    src = next((CALITERRA / 'images').iterdir())
    (tmp_path / 'input').mkdir()
    shutil.copy(src, tmp_path / 'input' / src.name)
    fig = _one_frame_run(tmp_path, cv2.imread(str(src)), 0.25)
    one = fig['per_frame'][0]
    assert one['ncc'] > 0.98 and one['sharpness_ratio'] > 0.9
    assert one['ncc_frame'] > 0.9 and one['sharpness_frame'] < 0.4  # the same ground, a quarter of the detail
    assert fig['sharpness_frame_median'] == pytest.approx(one['sharpness_frame'])
    lines = format_real_figures(fig)
    line = [x for x in lines if x.startswith('seen from the frames')]
    assert len(line) == 1 and f'sharpness median {one["sharpness_frame"]:.3f} over 1 frames' in line[0]
    assert any('much coarser than its frames' in x for x in lines)  # what the figure means, said


def test_errors(caliterra_run: tuple[Path, dict], tmp_path: Path) -> None:
    src = caliterra_run[0]
    for missing in ('frames.csv', 'report.json', 'mosaic.png'):
        out = _copy_run(src, tmp_path / f'no_{missing}')
        (out / missing).unlink()
        with pytest.raises(InputError, match=f'{missing} not found; run `srmosaic process'):
            evaluate_real(out, progress=False)
    # the input moved away: say so, and the input can be passed instead
    out = _copy_run(src, tmp_path / 'moved')
    report = json.loads((out / 'report.json').read_text())
    report['input'] = str(tmp_path / 'gone')
    (out / 'report.json').write_text(json.dumps(report))
    with pytest.raises(InputError, match='no longer exists; re-run process or pass the input'):
        evaluate_real(out, progress=False)
    assert evaluate_real(out, progress=False, max_frames=2, input_path=CALITERRA)['frames_compared'] == 2
    with pytest.raises(InputError, match='does not exist'):
        evaluate_real(out, progress=False, input_path=tmp_path / 'gone')
    # another input than the run's: no stamp matches
    with pytest.raises(InputError, match='no frame of .* has a stamp of'):
        evaluate_real(out, progress=False, input_path=SEQUENCES / 'brighton_beach')
    # no frame in the main mosaic
    out = _copy_run(src, tmp_path / 'none')
    rows = _rows(out / 'frames.csv')
    for row in rows:
        row['ok'] = '0'
    _write_rows(out / 'frames.csv', rows)
    with pytest.raises(InputError, match='no frame in the main mosaic'):
        evaluate_real(out, progress=False)
    # not a frames.csv
    (out / 'frames.csv').write_text('a,b\n1,2\n')
    with pytest.raises(InputError, match='is not a frames.csv'):
        evaluate_real(out, progress=False)
    with pytest.raises(InputError, match='max_frames must be at least 1'):
        evaluate_real(src, progress=False, max_frames=0)
