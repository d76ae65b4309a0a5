"""Sensor sizes of common UAS cameras, and the pinhole intrinsics a still's metadata implies.

The table maps an EXIF (make, model) to the active sensor area in millimetres and its native
pixel count; the pixel pitch follows (square pixels). Each entry's source is in a comment beside
it: the maker's published specification (sensor type, effective pixels, pixel size) or, for the
Canon, the camera's own EXIF. Where a maker gives only the optical type (1/2.3", 1"), the width
is that type's customary active width (1/2.3" 6.17 mm, 1/2" 6.4 mm, 1/1.7" 7.6 mm, 1" 13.2 mm,
4/3" 17.3 mm) and the height follows from the native aspect ratio.

Lookup (:func:`lookup_sensor`) ignores case, spaces and punctuation, and matches the model with
or without the make in front ('FC300S', 'DJI FC300S', make 'DJI' + model 'FC300S'). A model with
several cameras behind one name (a thermal and a visual sensor under 'XT2' or 'ZH20T') picks the
sensor whose native size or aspect ratio fits the image.

:func:`intrinsics_from_metadata` turns a :class:`~srmosaic_ros.io.still_metadata.StillMetadata` into a
:class:`~srmosaic_ros.core.types.CameraIntrinsics` for the image as decoded (as stored, before any
EXIF orientation is applied), in this order of preference:

1. DJI's ``CalibratedFocalLength`` (XMP, pixels of the image as the camera wrote it);
2. ``FocalLength`` with the EXIF ``FocalPlaneXResolution`` (pixels per mm of the EXIF width);
3. ``FocalLength`` with the sensor width of this table;
4. ``FocalLengthIn35mmFilm``: the 35 mm equivalent is taken over the diagonal,
   ``f_px = f35_mm / 43.27 mm * hypot(width_px, height_px)`` (43.27 mm is the diagonal of the
   36 x 24 mm frame). A 16:9 picture cut from a 4:3 sensor has a shorter diagonal than the
   sensor the maker computed f35 over, so this underestimates f there (DJI FC300S 4000x2250,
   f35 20 mm: 2121 px against 2340 px from its 3.61 mm over 6.17 mm); it is the last resort.

Convention: pixels, x right, y down, pixel centres at integers; fy = fx (square pixels); the
principal point is the image centre ``((width - 1) / 2, (height - 1) / 2)`` unless calibrated.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..core.types import CameraIntrinsics

if TYPE_CHECKING:
    from .still_metadata import StillMetadata

__all__ = [
    'CAMERAS',
    'FULL_FRAME_DIAGONAL_MM',
    'SensorSpec',
    'intrinsics_from_metadata',
    'lookup_sensor',
]

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)  # 43.27 mm: what "35 mm equivalent" is measured over

# Widths outside this range are not a camera sensor: a FocalPlaneXResolution that implies one is
# a wrong tag (some firmware writes the screen's dpi there), not a reason to trust it.
_PLAUSIBLE_SENSOR_WIDTH_MM = (1.0, 60.0)


@dataclass(frozen=True)
class SensorSpec:
    """One camera sensor: active area ``width_mm`` x ``height_mm`` read out as
    ``native_width_px`` x ``native_height_px`` (the full-resolution still).

    ``camera`` names the product (and which of its cameras, for multi-sensor payloads);
    ``aliases`` are other EXIF model strings for the same sensor.
    """

    make: str
    model: str
    width_mm: float
    height_mm: float
    native_width_px: int
    native_height_px: int
    camera: str = ''
    aliases: tuple[str, ...] = ()

    @property
    def pixel_pitch_um(self) -> float:
        """Native pixel size in micrometres (square pixels)."""
        return self.width_mm / self.native_width_px * 1000.0

    @property
    def name(self) -> str:
        return f'{self.make} {self.model}'.strip()


def _by_width(make: str, model: str, width_mm: float, w_px: int, h_px: int, camera: str,
              aliases: tuple[str, ...] = ()) -> SensorSpec:
    """An entry given by its active width; the height follows from the pixel aspect (square pixels)."""
    return SensorSpec(make, model, width_mm, round(width_mm * h_px / w_px, 3), w_px, h_px, camera, aliases)


def _by_pitch(make: str, model: str, pitch_um: float, w_px: int, h_px: int, camera: str,
              aliases: tuple[str, ...] = ()) -> SensorSpec:
    """An entry given by its pixel size (how thermal cores and multispectral imagers are specified)."""
    return SensorSpec(make, model, round(w_px * pitch_um / 1000.0, 3), round(h_px * pitch_um / 1000.0, 3),
                      w_px, h_px, camera, aliases)


CAMERAS: tuple[SensorSpec, ...] = (
    # --- DJI consumer and prosumer aircraft (dji.com product specs, "Camera: Sensor") ---
    # Phantom 3 Advanced / Professional: 1/2.3" CMOS, 12.4 MP effective, 4000x3000
    _by_width('DJI', 'FC300S', 6.17, 4000, 3000, 'Phantom 3 Advanced'),
    _by_width('DJI', 'FC300X', 6.17, 4000, 3000, 'Phantom 3 Professional'),
    # Phantom 3 Standard: 1/2.3" CMOS, 12 MP, 4000x3000
    _by_width('DJI', 'FC300C', 6.17, 4000, 3000, 'Phantom 3 Standard'),
    # Inspire 1 Zenmuse X3: 1/2.3" CMOS, 12.4 MP, 4000x3000
    _by_width('DJI', 'FC350', 6.17, 4000, 3000, 'Zenmuse X3'),
    # Phantom 4: 1/2.3" CMOS, 12.4 MP, 4000x3000
    _by_width('DJI', 'FC330', 6.17, 4000, 3000, 'Phantom 4'),
    # Phantom 4 Pro / Advanced, Pro V2.0, Phantom 4 RTK: 1" CMOS 20 MP, 5472x3648 (13.2 x 8.8 mm;
    # the P4 RTK manual gives 2.41 um pixels)
    _by_width('DJI', 'FC6310', 13.2, 5472, 3648, 'Phantom 4 Pro'),
    _by_width('DJI', 'FC6310S', 13.2, 5472, 3648, 'Phantom 4 Pro V2.0'),
    _by_width('DJI', 'FC6310R', 13.2, 5472, 3648, 'Phantom 4 RTK'),
    # Inspire 2 Zenmuse X4S: 1" CMOS 20 MP, 5472x3648
    _by_width('DJI', 'FC6510', 13.2, 5472, 3648, 'Zenmuse X4S'),
    # Inspire 2 Zenmuse X5S: 4/3" CMOS 20.8 MP, 5280x3956 (17.3 x 13.0 mm)
    _by_width('DJI', 'FC6520', 17.3, 5280, 3956, 'Zenmuse X5S'),
    # Mavic Pro: 1/2.3" CMOS, 12.35 MP, 4000x3000
    _by_width('DJI', 'FC220', 6.17, 4000, 3000, 'Mavic Pro'),
    # Mavic Air: 1/2.3" CMOS, 12 MP, 4056x3040
    _by_width('DJI', 'FC2103', 6.17, 4056, 3040, 'Mavic Air'),
    # Mavic 2 Pro (Hasselblad L1D-20c): 1" CMOS 20 MP, 5472x3648
    _by_width('Hasselblad', 'L1D-20c', 13.2, 5472, 3648, 'Mavic 2 Pro'),
    # Mavic 2 Zoom: 1/2.3" CMOS, 12 MP, 4000x3000
    _by_width('DJI', 'FC2204', 6.17, 4000, 3000, 'Mavic 2 Zoom'),
    # Mavic Air 2: 1/2" CMOS 48 MP, 8000x6000 (0.8 um Quad Bayer pixels: 6.4 x 4.8 mm)
    _by_width('DJI', 'FC3170', 6.4, 8000, 6000, 'Mavic Air 2'),
    # Mini 2: 1/2.3" CMOS, 12 MP, 4000x3000
    _by_width('DJI', 'FC7303', 6.17, 4000, 3000, 'Mini 2'),
    # Air 2S: 1" CMOS 20 MP, 5472x3648 (2.4 um pixels)
    _by_width('DJI', 'FC3411', 13.2, 5472, 3648, 'Air 2S'),
    # Mavic 3 (Hasselblad L2D-20c): 4/3 CMOS 20 MP, 5280x3956 (17.3 x 13.0 mm, 3.3 um)
    _by_width('Hasselblad', 'L2D-20c', 17.3, 5280, 3956, 'Mavic 3'),
    # Mavic 3 Enterprise wide camera: 4/3 CMOS 20 MP, 5280x3956
    _by_width('DJI', 'M3E', 17.3, 5280, 3956, 'Mavic 3 Enterprise'),
    # --- DJI enterprise payloads ---
    # Zenmuse P1: full frame 35.9 x 24 mm, 45 MP, 8192x5460, 4.4 um pixels (the maker's rounded
    # figures: 35.9 mm / 8192 px is 4.38 um, 24 mm / 5460 px 4.40 um)
    SensorSpec('DJI', 'ZenmuseP1', 35.9, 24.0, 8192, 5460, 'Zenmuse P1'),
    # Zenmuse XT2: thermal FLIR Tau 2 640x512 at 17 um; visual 1/1.7" CMOS 12 MP, 4000x3000
    _by_pitch('DJI', 'XT2', 17.0, 640, 512, 'Zenmuse XT2 thermal'),
    _by_width('DJI', 'XT2', 7.6, 4000, 3000, 'Zenmuse XT2 visual'),
    # Zenmuse H20T (EXIF model ZH20T): thermal 640x512 at 12 um; wide 1/2.3" 12 MP 4056x3040;
    # zoom 1/1.7" 20 MP 5184x3888
    _by_pitch('DJI', 'ZH20T', 12.0, 640, 512, 'Zenmuse H20T thermal', ('H20T',)),
    _by_width('DJI', 'ZH20T', 6.17, 4056, 3040, 'Zenmuse H20T wide', ('H20T',)),
    _by_width('DJI', 'ZH20T', 7.6, 5184, 3888, 'Zenmuse H20T zoom', ('H20T',)),
    # Mavic 2 Enterprise Advanced (EXIF model MAVIC2-ENTERPRISE-ADVANCED): thermal 640x512 at
    # 12 um; visual 1/2" CMOS 48 MP, 8000x6000
    _by_pitch('DJI', 'MAVIC2-ENTERPRISE-ADVANCED', 12.0, 640, 512, 'Mavic 2 Enterprise Advanced thermal',
              ('M2EA',)),
    _by_width('DJI', 'MAVIC2-ENTERPRISE-ADVANCED', 6.4, 8000, 6000, 'Mavic 2 Enterprise Advanced visual',
              ('M2EA',)),
    # Matrice 30T: thermal 640x512 at 12 um; wide and zoom 1/2" CMOS 48 MP, 8000x6000
    _by_pitch('DJI', 'M30T', 12.0, 640, 512, 'Matrice 30T thermal'),
    _by_width('DJI', 'M30T', 6.4, 8000, 6000, 'Matrice 30T wide/zoom'),
    # --- Parrot (parrot.com product specs) ---
    # ANAFI: 1/2.4" CMOS 21 MP (Sony IMX230), 5344x4016 at 1.12 um
    _by_pitch('Parrot', 'ANAFI', 1.12, 5344, 4016, 'ANAFI'),
    # Sequoia: four 1.2 MP monochrome bands, 1280x960 at 3.75 um (4.8 x 3.6 mm); RGB 16 MP
    # 4608x3456 at 1.34 um
    _by_pitch('Parrot', 'Sequoia', 3.75, 1280, 960, 'Sequoia multispectral band'),
    _by_pitch('Parrot', 'Sequoia', 1.34, 4608, 3456, 'Sequoia RGB'),
    # --- MicaSense (RedEdge user guide: 1280x960 global shutter, 3.75 um, 4.8 x 3.6 mm) ---
    _by_pitch('MicaSense', 'RedEdge', 3.75, 1280, 960, 'RedEdge band', ('RedEdge-M', 'RedEdge-MX')),
    # --- senseFly S.O.D.A.: 1" 20 MP, 5472x3648, 2.4 um pixels ---
    _by_width('senseFly', 'S.O.D.A.', 13.2, 5472, 3648, 'S.O.D.A.'),
    # --- Canon PowerShot SX260 HS: 1/2.3" CMOS 12.1 MP, 4000x3000; the width is the one its own
    # EXIF states (FocalPlaneXResolution 16393.44 px/inch at 4000 px = 6.198 mm) ---
    _by_width('Canon', 'PowerShot SX260 HS', 6.198, 4000, 3000, 'PowerShot SX260 HS'),
)


def _key(text: str) -> str:
    """Case-, space- and punctuation-insensitive form of a name ('S.O.D.A.' == 'soda')."""
    return re.sub(r'[^0-9a-z]', '', text.lower())


def _entry_keys(spec: SensorSpec) -> set[str]:
    make = _key(spec.make)
    keys = set()
    for model in (spec.model, *spec.aliases):
        keys.add(_key(model))
        keys.add(make + _key(model))
    return keys


def _build_index() -> dict[str, list[SensorSpec]]:
    index: dict[str, list[SensorSpec]] = {}
    for spec in CAMERAS:
        for key in _entry_keys(spec):
            index.setdefault(key, []).append(spec)
    return index


_INDEX = _build_index()


def lookup_sensor(make: str, model: str, *, width_px: int | None = None,
                  height_px: int | None = None) -> SensorSpec | None:
    """The table's sensor for an EXIF make and model, or None.

    Case, spaces and punctuation are ignored; the model may carry the make in front or not
    ('Canon PowerShot SX260 HS' under make 'Canon', or 'DJI FC300S' with no make). When a name
    covers several sensors, the one whose native width equals ``width_px`` wins, then the one
    with the same aspect ratio as ``width_px`` x ``height_px`` (a downscaled still keeps it), then
    the first listed.
    """
    mk, md = _key(make or ''), _key(model or '')
    candidates: list[SensorSpec] = []
    for k in (md, mk + md, md[len(mk):] if mk and md.startswith(mk) else ''):
        if k and k in _INDEX:
            candidates = _INDEX[k]
            break
    if not candidates:
        return None
    if len(candidates) == 1 or not width_px:
        return candidates[0]
    for spec in candidates:
        if width_px in (spec.native_width_px, spec.native_height_px):
            return spec
    if height_px:
        aspect = max(width_px, height_px) / min(width_px, height_px)
        for spec in candidates:
            native = max(spec.native_width_px, spec.native_height_px) / min(spec.native_width_px,
                                                                           spec.native_height_px)
            if abs(native - aspect) < 0.01:
                return spec
    return candidates[0]


def intrinsics_from_metadata(meta: StillMetadata) -> tuple[CameraIntrinsics | None, str]:
    """Pinhole intrinsics of the still as decoded, and where the focal length came from.

    Returns ``(CameraIntrinsics(width, height, fx, fy, cx, cy), reason)`` in pixels, or
    ``(None, reason)`` when nothing gives a focal length; ``reason`` is one short phrase
    ('calibrated focal length (XMP)', 'focal length 4.5 mm over a 6.20 mm sensor (focal plane
    resolution)', 'focal length 3.61 mm over a 6.17 mm sensor (camera table: DJI FC300S)',
    '35 mm equivalent 24 mm', 'no focal length in the EXIF'). See the module docstring for the
    order of preference and the formulas.
    """
    w, h = meta.width_px, meta.height_px
    centre = ((w - 1) / 2.0, (h - 1) / 2.0)

    def pinhole(f_px: float, c: tuple[float, float] = centre) -> CameraIntrinsics:
        return CameraIntrinsics(w, h, f_px, f_px, c[0], c[1])

    if meta.calibrated_focal_length_px and meta.calibrated_focal_length_px > 0:
        c = meta.calibrated_optical_center_px or centre
        return pinhole(meta.calibrated_focal_length_px, c), 'calibrated focal length (XMP)'

    f_mm = meta.focal_length_mm
    if f_mm:
        res = meta.focal_plane_x_res_px_per_mm
        if res:
            # the resolution is per mm of the image the camera wrote (PixelXDimension wide)
            sensor_w_mm = (meta.exif_width_px or w) / res
            lo, hi = _PLAUSIBLE_SENSOR_WIDTH_MM
            if lo <= sensor_w_mm <= hi:
                return (pinhole(f_mm / sensor_w_mm * w),
                        f'focal length {f_mm:g} mm over a {sensor_w_mm:.2f} mm sensor (focal plane resolution)')
        spec = lookup_sensor(meta.make, meta.model, width_px=meta.exif_width_px or w,
                             height_px=_exif_height(meta, w, h))
        if spec is not None:
            # a still spans the full sensor width (16:9 modes crop rows, not columns)
            return (pinhole(f_mm / spec.width_mm * w),
                    f'focal length {f_mm:g} mm over a {spec.width_mm:.2f} mm sensor (camera table: {spec.name})')
    f35 = meta.focal_length_35mm_mm
    if f35:
        return pinhole(f35 / FULL_FRAME_DIAGONAL_MM * math.hypot(w, h)), f'35 mm equivalent {f35:g} mm'
    if f_mm:
        return None, (f'focal length {f_mm:g} mm but no sensor width (no focal plane resolution, '
                      f'{meta.make} {meta.model} not in the camera table) and no 35 mm equivalent')
    return None, 'no focal length in the EXIF'


def _exif_height(meta: StillMetadata, w: int, h: int) -> int:
    """Height matching ``exif_width_px`` at the decoded aspect (the table match needs an aspect)."""
    if meta.exif_width_px:
        return round(meta.exif_width_px * h / w)
    return h
