"""OpenDroneMap's gcp_list.txt (io/gcp.py): the coordinate system in each form ODM accepts, the
observations, contradicting picks kept out of the control, and one clear line for each way a file
can be malformed."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from srmosaic_ros.errors import InputError
from srmosaic_ros.io.gcp import find_gcp_file, read_gcp_list

SIZES = {'IMG_0001.jpg': (2000, 1500), 'IMG_0002.jpg': (2000, 1500)}
ROWS = ('235269.88\t3811198.11\t0.0\t1804.686\t1146.898\tIMG_0001.jpg\tgcp02\n'
        '235262.54 3811203.5 0.0 1736.0 500.2 IMG_0002.jpg gcp04 extra1 extra2\n'
        '235262.54 3811203.5 0.0 100.0 200.0 IMG_0001.jpg gcp04\n')


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / 'gcp_list.txt'
    path.write_text(text)
    return path


@pytest.mark.parametrize('header', ['+proj=utm +zone=11 +ellps=WGS84 +datum=WGS84 +units=m +no_defs', 'EPSG:32611',
                                    'WGS84 UTM 11N', 'epsg:32611'])
def test_the_coordinate_system_in_every_form_odm_accepts(tmp_path: Path, header: str) -> None:
    gcp = read_gcp_list(_write(tmp_path, f'{header}\n{ROWS}'), image_sizes=SIZES)
    assert gcp.projected_epsg() == 32611
    assert [o.name for o in gcp.observations] == ['gcp02', 'gcp04', 'gcp04']
    assert gcp.targets() == ['gcp02', 'gcp04']
    o = gcp.observations[1]
    assert (o.line, o.image, o.pixel_xy, o.geo_xyz, o.excluded) == (3, 'IMG_0002.jpg', (1736.0, 500.2),
                                                                      (235262.54, 3811203.5, 0.0), '')
    assert np.allclose(gcp.ground_in(32611)[0], [235269.88, 3811198.11])
    assert gcp.warnings == []


def test_wkt_and_geographic_coordinates_go_to_their_utm_zone(tmp_path: Path) -> None:
    from pyproj import CRS, Transformer

    lon, lat = Transformer.from_crs(32611, 4326, always_xy=True).transform(235269.88, 3811198.11)
    text = f'{CRS.from_epsg(4326).to_wkt()}\n{lon:.9f} {lat:.9f} 0 10 20 IMG_0001.jpg a\n'
    gcp = read_gcp_list(_write(tmp_path, text), image_sizes=SIZES)
    assert gcp.projected_epsg() == 32611
    assert np.allclose(gcp.ground_in(32611), [[235269.88, 3811198.11]], atol=1e-3)


def test_a_line_without_a_name_names_its_target_by_its_coordinates(tmp_path: Path) -> None:
    gcp = read_gcp_list(_write(tmp_path, 'EPSG:32611\n1.5 2.25 0 10 20 IMG_0001.jpg\n1.5 2.25 0 30 40 IMG_0002.jpg\n'))
    assert gcp.targets() == ['1.500,2.250']


def test_contradicting_picks_are_kept_out_of_the_control_with_a_warning(tmp_path: Path) -> None:
    text = ('EPSG:32611\n'
            '10 10 0 500 400 IMG_0001.jpg a\n'
            '30 10 0 501.5 399 IMG_0001.jpg b\n'     # b picked on a's spot
            '30 10 0 900 100 IMG_0002.jpg b\n'
            '50 10 0 100 100 IMG_0002.jpg c\n'
            '50 10 0 700 700 IMG_0002.jpg c\n'       # c picked twice, far apart
            '10 10 0 300 300 IMG_0002.jpg a\n'
            '10 10 0 300.5 300 IMG_0002.jpg a\n')    # a given twice at one spot
    gcp = read_gcp_list(_write(tmp_path, text), image_sizes=SIZES)
    excluded = {(o.line, o.excluded) for o in gcp.observations if o.excluded}
    assert excluded == {(2, 'same pixel as b'), (3, 'same pixel as a'), (5, 'c picked twice in IMG_0002.jpg'),
                        (6, 'c picked twice in IMG_0002.jpg'), (8, 'repeated line 7')}
    assert len(gcp.warnings) == 3
    assert 'IMG_0001.jpg (500, 400) is picked as both a (line 2) and b (line 3)' in gcp.warnings[0]


@pytest.mark.parametrize(('text', 'says'), [
    ('', 'the GCP file is empty'),
    (ROWS, 'the first line is an observation, not a coordinate system; add a first line such as "EPSG:32611"'),
    ('not a crs at all\n' + ROWS, 'is not a coordinate system; the first line must be a PROJ string'),
    ('EPSG:32611\n', 'no observations after the coordinate system line'),
    ('EPSG:32611\n1 2 3 4 IMG_0001.jpg\n', ':2: 5 columns, expected at least 6'),
    ('EPSG:32611\n1 2 3 4 five IMG_0001.jpg a\n', ':2: "five" is not a number'),
    ('EPSG:32611\n1 2 nan 4 5 IMG_0001.jpg a\n', ':2: a coordinate is not finite'),
    ('EPSG:32611\n1 2 0 4 5 IMG_0009.jpg a\n', ':2: image "IMG_0009.jpg" is not among the stills'),
    ('EPSG:32611\n1 2 0 4000 5 IMG_0001.jpg a\n', ':2: pixel (4000, 5) is outside IMG_0001.jpg (2000x1500)'),
    ('EPSG:32611\n1 2 0 4 5 IMG_0001.jpg a\n7 2 0 4 5 IMG_0002.jpg a\n', ':3: a is at (7, 2) but line 2 puts it at (1, 2)'),
    ('WGS84 UTM 61N\n' + ROWS, 'UTM zone 61 is not 1..60'),
])
def test_a_malformed_file_is_refused_in_one_line_that_says_what_to_fix(tmp_path: Path, text: str, says: str) -> None:
    with pytest.raises(InputError) as info:
        read_gcp_list(_write(tmp_path, text), image_sizes=SIZES)
    message = str(info.value)
    assert says in message and '\n' not in message, message


def test_the_file_is_found_inside_beside_or_in_the_images_of_a_stills_folder(tmp_path: Path) -> None:
    (tmp_path / 'survey' / 'images').mkdir(parents=True)
    assert find_gcp_file(tmp_path / 'survey') is None
    for where in (tmp_path, tmp_path / 'survey' / 'images', tmp_path / 'survey'):
        _write(where, 'EPSG:32611\n')
        assert find_gcp_file(tmp_path / 'survey') == where / 'gcp_list.txt'
    assert find_gcp_file(tmp_path / 'survey' / 'images') == tmp_path / 'survey' / 'images' / 'gcp_list.txt'
