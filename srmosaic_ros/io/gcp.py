"""Ground control points in OpenDroneMap's ``gcp_list.txt`` format.

The first non-blank line names the coordinate system of the ground coordinates: a PROJ string
(``+proj=utm +zone=11 +datum=WGS84 +units=m``), an EPSG code (``EPSG:32611``), ``WGS84 UTM 16N``
or WKT. Every further line is one observation of a target in one still::

    geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extras...]

separated by tabs or spaces; geo_x, geo_y in the CRS's own axis order of easting/longitude first
(ODM's convention: EPSG:4326 gives longitude then latitude); im_x, im_y in pixels of the image as
stored (x right, y down, the first pixel's centre at (0, 0)). Lines starting with ``#`` are
comments. A line without gcp_name names its target by its ground coordinates.

Picks that contradict each other are kept out of the control and said so (``GcpObservation.excluded``):
- two names at the same pixel of one still (one of them is the wrong target);
- one name at two different pixels of one still.
The solve (core/survey/global_align.py) then tells which of them the stills agree with.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError

if TYPE_CHECKING:
    from pyproj import CRS

__all__ = ['GCP_FILE_NAME', 'SAME_PICK_PX', 'SAME_TARGET_M', 'GcpList', 'GcpObservation', 'find_gcp_file',
           'read_gcp_list']

#: The file `process` looks for beside and inside a folder of stills.
GCP_FILE_NAME = 'gcp_list.txt'
#: Two picks in one still closer than this (pixels) mark the same spot.
SAME_PICK_PX = 5.0
#: One name given two ground positions further apart than this (metres or degrees x 1e5) is refused.
SAME_TARGET_M = 0.01

_UTM_NAME = re.compile(r'^\s*WGS\s*84\s+UTM\s+(\d{1,2})\s*([NS])\s*$', re.IGNORECASE)


@dataclass(frozen=True)
class GcpObservation:
    """One line of the file: target ``name`` seen in still ``image`` at ``pixel_xy`` (x, y pixels of
    the stored image), surveyed at ``geo_xyz`` (the file's CRS). ``excluded``: why it is not used
    as control ('' when it is); ``line``: its line number in the file (1-based)."""

    line: int
    name: str
    image: str
    pixel_xy: tuple[float, float]
    geo_xyz: tuple[float, float, float]
    excluded: str = ''


@dataclass
class GcpList:
    """The file's CRS and observations, in file order; warnings: what was kept out and why."""

    path: Path
    crs: CRS
    observations: list[GcpObservation]
    warnings: list[str] = field(default_factory=list)

    def targets(self) -> list[str]:
        """Target names in order of first appearance."""
        return list(dict.fromkeys(o.name for o in self.observations))

    def ground_in(self, epsg: int) -> np.ndarray:
        """(M, 2) the observations' ground coordinates (x east, y north) in the projected CRS ``epsg``."""
        from pyproj import Transformer

        xy = np.array([o.geo_xyz[:2] for o in self.observations], dtype=np.float64).reshape(-1, 2)
        if self.crs.to_epsg() == epsg:
            return xy
        tr = Transformer.from_crs(self.crs, epsg, always_xy=True)
        e, n = tr.transform(xy[:, 0], xy[:, 1])
        return np.stack([np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64)], axis=1)

    def projected_epsg(self) -> int:
        """The EPSG code of a projected, metric CRS to work in: the file's own when it is one, else the
        UTM zone of the targets' centre."""
        from pyproj import Transformer

        from ..core.georef.georeferencer import utm_epsg

        code = self.crs.to_epsg(min_confidence=70)
        if code and self.crs.is_projected and all(a.unit_name in ('metre', 'meter') for a in self.crs.axis_info[:2]):
            return int(code)
        xy = np.array([o.geo_xyz[:2] for o in self.observations], dtype=np.float64)
        lon, lat = Transformer.from_crs(self.crs, 4326, always_xy=True).transform(*xy.mean(axis=0))
        return utm_epsg(float(lat), float(lon))


def find_gcp_file(folder: Path) -> Path | None:
    """``gcp_list.txt`` inside a folder of stills, in its ``images`` subfolder or beside it (its
    parent); None when there is none."""
    folder = Path(folder)
    for candidate in (folder / GCP_FILE_NAME, folder / 'images' / GCP_FILE_NAME, folder.parent / GCP_FILE_NAME):
        if candidate.is_file():
            return candidate
    return None


def _parse_crs(text: str, where: str) -> CRS:
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    m = _UTM_NAME.match(text)
    if m:
        zone, hemisphere = int(m.group(1)), m.group(2).upper()
        if not 1 <= zone <= 60:
            msg = f'{where}: UTM zone {zone} is not 1..60; write e.g. "WGS84 UTM 11N".'
            raise InputError(msg)
        return CRS.from_epsg((32600 if hemisphere == 'N' else 32700) + zone)
    try:
        return CRS.from_user_input(text)
    except CRSError:
        msg = (f'{where}: "{text[:60]}" is not a coordinate system; the first line must be a PROJ string '
               '(+proj=utm +zone=11 +datum=WGS84 +units=m), an EPSG code (EPSG:32611), "WGS84 UTM 11N" or WKT.')
        raise InputError(msg) from None


def read_gcp_list(path: str | Path, *, image_sizes: dict[str, tuple[int, int]] | None = None) -> GcpList:
    """Read an OpenDroneMap gcp_list.txt (module docstring).

    Args:
        path: the file.
        image_sizes: name -> (width, height) pixels of the stills it refers to; when given, an image
            not among them, or a pixel outside its image, is an error.

    Raises:
        InputError: one line saying where the file is malformed and what to write instead.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8-sig')
    except (OSError, UnicodeDecodeError) as exc:
        msg = f'{path}: the GCP file cannot be read ({exc}); give a text file in OpenDroneMap\'s gcp_list.txt format.'
        raise InputError(msg) from None
    lines = [(k + 1, raw.strip()) for k, raw in enumerate(text.splitlines())]
    lines = [(k, s) for k, s in lines if s and not s.startswith('#')]
    if not lines:
        msg = f'{path}: the GCP file is empty; its first line names the coordinate system (e.g. EPSG:32611).'
        raise InputError(msg)
    header_no, header = lines[0]
    if _looks_like_observation(header):
        msg = (f'{path}:{header_no}: the first line is an observation, not a coordinate system; add a first line '
               'such as "EPSG:32611" or "+proj=utm +zone=11 +datum=WGS84 +units=m".')
        raise InputError(msg)
    crs = _parse_crs(header, f'{path}:{header_no}')
    observations = []
    position_of: dict[str, tuple[int, tuple[float, float, float]]] = {}
    for no, s in lines[1:]:
        where = f'{path}:{no}'
        cols = s.split()
        if len(cols) < 6:
            msg = (f'{where}: {len(cols)} columns, expected at least 6 '
                   '(geo_x geo_y geo_z im_x im_y image_name [gcp_name]).')
            raise InputError(msg)
        try:
            gx, gy, gz, px, py = (float(c) for c in cols[:5])
        except ValueError:
            bad = next(c for c in cols[:5] if not _is_float(c))
            msg = (f'{where}: "{bad}" is not a number; the first five columns are geo_x geo_y geo_z im_x im_y '
                   '(a file whose image name holds a space cannot be read: rename the image).')
            raise InputError(msg) from None
        if not all(math.isfinite(v) for v in (gx, gy, gz, px, py)):
            msg = f'{where}: a coordinate is not finite; give numbers.'
            raise InputError(msg)
        image = cols[5]
        name = cols[6] if len(cols) > 6 else f'{gx:.3f},{gy:.3f}'
        if image_sizes is not None:
            if image not in image_sizes:
                msg = (f'{where}: image "{image}" is not among the stills ({len(image_sizes)} of them); check its name, '
                       'case and extension, or remove the line.')
                raise InputError(msg)
            w, h = image_sizes[image]
            if not (-0.5 <= px <= w - 0.5 and -0.5 <= py <= h - 0.5):
                msg = (f'{where}: pixel ({px:g}, {py:g}) is outside {image} ({w}x{h}); picks made on other-sized '
                       'copies of the stills must be scaled to these.')
                raise InputError(msg)
        if name in position_of:
            first_no, first = position_of[name]
            if math.hypot(first[0] - gx, first[1] - gy) > SAME_TARGET_M * (1e-5 if crs.is_geographic else 1.0):
                msg = (f'{where}: {name} is at ({gx:g}, {gy:g}) but line {first_no} puts it at ({first[0]:g}, '
                       f'{first[1]:g}); give each target one position, or different names.')
                raise InputError(msg)
        else:
            position_of[name] = (no, (gx, gy, gz))
        observations.append(GcpObservation(no, name, image, (px, py), (gx, gy, gz)))
    if not observations:
        msg = f'{path}: no observations after the coordinate system line; add lines geo_x geo_y geo_z im_x im_y image_name.'
        raise InputError(msg)
    observations, warnings = _contradicting_picks(observations)
    return GcpList(path, crs, observations, warnings)


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _looks_like_observation(s: str) -> bool:
    cols = s.split()
    return len(cols) >= 6 and all(_is_float(c) for c in cols[:5])


def _contradicting_picks(observations: list[GcpObservation]) -> tuple[list[GcpObservation], list[str]]:
    """Observations with ``excluded`` set where picks in one still contradict each other, and a
    warning for each contradiction; a target picked twice at one spot of a still keeps its first pick."""
    out = list(observations)
    warnings = []
    by_image: dict[str, list[int]] = {}
    for k, o in enumerate(out):
        by_image.setdefault(o.image, []).append(k)
    for image, idx in by_image.items():
        for a_pos, a in enumerate(idx):
            for b in idx[a_pos + 1:]:
                oa, ob = out[a], out[b]
                if oa.excluded.startswith('repeated') or ob.excluded.startswith('repeated'):
                    continue
                d = math.hypot(oa.pixel_xy[0] - ob.pixel_xy[0], oa.pixel_xy[1] - ob.pixel_xy[1])
                if oa.name != ob.name and d <= SAME_PICK_PX:
                    why = (f'{image} ({oa.pixel_xy[0]:.0f}, {oa.pixel_xy[1]:.0f}) is picked as both {oa.name} '
                           f'(line {oa.line}) and {ob.name} (line {ob.line})')
                    out[a] = replace(oa, excluded=f'same pixel as {ob.name}')
                    out[b] = replace(ob, excluded=f'same pixel as {oa.name}')
                    warnings.append(f'{why}: neither is used as control; the report says which one the stills agree with.')
                elif oa.name == ob.name and d > SAME_PICK_PX:
                    why = (f'{oa.name} is picked twice in {image}, {d:.0f} px apart (lines {oa.line} and {ob.line})')
                    out[a] = replace(oa, excluded=f'{oa.name} picked twice in {image}')
                    out[b] = replace(ob, excluded=f'{oa.name} picked twice in {image}')
                    warnings.append(f'{why}: neither is used as control; remove the wrong line.')
                elif oa.name == ob.name:
                    out[b] = replace(ob, excluded=f'repeated line {oa.line}')
                    warnings.append(f'{ob.name} in {image} is given twice (lines {oa.line} and {ob.line}): '
                                    'the second is ignored.')
    return out, warnings
