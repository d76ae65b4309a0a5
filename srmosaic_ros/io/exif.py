"""EXIF and XMP of survey stills: capture time, GNSS position, attitude and camera optics.

Reader: Pillow (already a dependency) rather than exifread: it parses EXIF, the GPS and Exif
sub-IFDs and hands over the raw XMP packet from the file header without decoding any pixels.
XMP is parsed with the standard library's ``xml.etree`` (expat, which refuses entity-expansion
bombs); a packet that is not well-formed XML is read by pattern instead (DJI-style
``prefix:Name="value"`` pairs), and the notes say so.

EXIF (CIPA DC-008): ``DateTimeOriginal`` + ``SubSecTimeOriginal`` + ``OffsetTimeOriginal`` give
the capture time. Without an offset the GPS ``GPSDateStamp`` + ``GPSTimeStamp`` (UTC by
definition) are used when present, else the naive local time is taken as UTC; ``notes`` says
which. GPS latitude/longitude are degrees, minutes, seconds rationals with N/S, E/W refs
(S and W negative); ``GPSAltitudeRef`` 1 is below sea level (Exif 3.0 adds 2/3: ellipsoidal
height above/below). A zero denominator, a missing or unknown ref, a void fix
(``GPSStatus`` V) or the (0, 0) placeholder leave the value NaN with a note, never a crash.

XMP namespaces read (attribute form ``ns:Name="v"``, element form ``<ns:Name>v</ns:Name>`` and
structs in either ``rdf:parseType="Resource"`` or nested ``rdf:Description``):

- DJI ``http://www.dji.com/drone-dji/1.0/`` (also written by DJI's Hasselblad/Sony-sensor
  cameras and by newer Autel firmware): ``RelativeAltitude`` (m above take-off),
  ``GimbalYaw/Pitch/RollDegree``, ``FlightYaw/Pitch/RollDegree`` (NED, ZYX order: yaw clockwise
  from north, pitch -90 = nadir / nose up +, roll right side down +), ``CalibratedFocalLength``
  and ``CalibratedOpticalCenterX/Y`` (pixels of the image as written, per DJI's XMP field lists),
  and ``GpsLatitude``/``GpsLongitude``/``GpsLongtitude``/``AbsoluteAltitude`` used only when the
  EXIF has no position.
- Parrot ``http://www.parrot.com/drone-parrot/1.0/`` (ANAFI): ``CameraYaw/Pitch/RollDegree``
  (gimbal, same convention as DJI) and ``DroneYaw/Pitch/RollDegree`` (aircraft).
- Skydio ``https://www.skydio.com/drone-skydio/1.0/``: struct ``CameraOrientationNED``
  ``Yaw/Pitch/Roll`` (gimbal, NED as DJI).
- Pix4D camera ``http://pix4d.com/camera/1.0/`` (Parrot Sequoia, MicaSense, older Autel) and
  senseFly ``http://ns.sensefly.com/Camera/1.0/``: ``Camera:Yaw/Pitch/Roll``, Pix4D's
  convention (pitch 0 = nadir, 90 = forward), returned here as pitch - 90 so that -90 is nadir
  everywhere; roll is kept as written (senseFly's roll sign is not documented).
  ``Camera:AboveGroundAltitude`` fills ``relative_altitude_m`` when no DJI value exists (it is
  above ground, not above take-off; the notes say so).
"""
from __future__ import annotations

import calendar
import math
import re
import warnings
import xml.etree.ElementTree as ET  # the usual alias
from datetime import datetime
from pathlib import Path
from typing import Any

from PIL import Image, UnidentifiedImageError

from ..errors import MetadataError
from .camera_db import intrinsics_from_metadata
from .still_metadata import StillMetadata

__all__ = ['StillMetadata', 'intrinsics_from_metadata', 'parse_xmp', 'read_still_metadata']

NAN = float('nan')

# EXIF tag numbers (CIPA DC-008)
_IFD_EXIF, _IFD_GPS, _IFD_INTEROP = 0x8769, 0x8825, 0xA005
_IMAGE_WIDTH, _MAKE, _MODEL, _ORIENTATION, _DATETIME = 0x0100, 0x010F, 0x0110, 0x0112, 0x0132
_DATETIME_ORIGINAL, _OFFSET_TIME, _OFFSET_TIME_ORIGINAL = 0x9003, 0x9010, 0x9011
_SUBSEC_ORIGINAL, _FOCAL_LENGTH = 0x9291, 0x920A
_PIXEL_X_DIMENSION, _PIXEL_Y_DIMENSION = 0xA002, 0xA003
_FOCAL_PLANE_X_RES, _FOCAL_PLANE_UNIT = 0xA20E, 0xA210
_FOCAL_35MM = 0xA405
_RELATED_IMAGE_WIDTH = 0x1001
_GPS_LAT_REF, _GPS_LAT, _GPS_LON_REF, _GPS_LON = 1, 2, 3, 4
_GPS_ALT_REF, _GPS_ALT, _GPS_TIME, _GPS_STATUS, _GPS_DATE = 5, 6, 7, 9, 29

# FocalPlaneResolutionUnit -> millimetres per unit (1 = none is not a length)
_MM_PER_UNIT = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}

_RDF = 'http://www.w3.org/1999/02/22-rdf-syntax-ns#'

# normalised namespace URIs (see _ns)
_NS_DJI = 'dji.com/drone-dji/1.0'
_NS_PARROT = 'parrot.com/drone-parrot/1.0'
_NS_SKYDIO = 'skydio.com/drone-skydio/1.0'
_NS_PIX4D = 'pix4d.com/camera/1.0'
_NS_SENSEFLY = 'ns.sensefly.com/camera/1.0'
_NS_TIFF = 'ns.adobe.com/tiff/1.0'
# prefixes these namespaces are written under, for a packet that is not well-formed XML
_PREFIX_NS = {'drone-dji': _NS_DJI, 'drone-parrot': _NS_PARROT, 'drone-skydio': _NS_SKYDIO,
              'camera': _NS_PIX4D, 'tiff': _NS_TIFF}


def read_still_metadata(path: str | Path) -> StillMetadata:
    """Read the EXIF and XMP of one still (JPEG, MPO, TIFF, PNG, WebP) without decoding pixels.

    Raises MetadataError only when the file is missing or is not an image at all; anything
    missing, malformed or assumed inside the metadata is a NaN/None field and a note.
    """
    path = Path(path)
    notes: list[str] = []
    try:
        with warnings.catch_warnings():
            # no pixels are decoded here: Pillow's warning about a large picture is not this reader's
            warnings.simplefilter('ignore', Image.DecompressionBombWarning)
            im = Image.open(path)
    except FileNotFoundError:
        msg = f'{path} does not exist; pass the path of a survey still (JPEG/TIFF/PNG).'
        raise MetadataError(msg) from None
    except (PermissionError, IsADirectoryError) as exc:
        msg = f'{path} cannot be read ({exc.strerror}); pass a readable still file.'
        raise MetadataError(msg) from None
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
        msg = (f'{path} is not an image Pillow can open ({exc}); its EXIF/XMP cannot be read. '
               'Check that the file is a still (JPEG/TIFF/PNG) and not truncated or renamed.')
        raise MetadataError(msg) from None
    with im:
        width, height = im.size
        ifd0, exif_ifd, gps, interop = _read_exif(im, notes)
        xmp = _read_xmp(im, notes)

    make = _text(ifd0.get(_MAKE)) or xmp.get((_NS_TIFF, 'Make'), '').strip()
    model = _text(ifd0.get(_MODEL)) or xmp.get((_NS_TIFF, 'Model'), '').strip()
    if not make and not model:
        notes.append('no camera make/model')

    orientation = _int(ifd0.get(_ORIENTATION))
    if orientation is None:
        orientation = 1
    elif not 1 <= orientation <= 8:
        notes.append(f'EXIF orientation {orientation} is not 1-8: 1 assumed')
        orientation = 1

    exif_width = _int(exif_ifd.get(_PIXEL_X_DIMENSION)) or _int(ifd0.get(_IMAGE_WIDTH)) \
        or _int(interop.get(_RELATED_IMAGE_WIDTH))
    if exif_width is not None and exif_width <= 0:
        exif_width = None
    if exif_width and exif_width != width:
        notes.append(f'EXIF width {exif_width} px, decoded {width} px (resized after capture)')

    stamp_ns = _capture_stamp(ifd0, exif_ifd, gps, notes)
    lat, lon, alt = _gps_position(gps, notes)
    if not (math.isfinite(lat) and math.isfinite(lon)):
        lat, lon, alt = _xmp_position(xmp, lat, lon, alt, notes)

    rel_alt = _xmp_float(xmp, _NS_DJI, 'RelativeAltitude')
    if rel_alt is None:
        rel_alt = _xmp_float(xmp, _NS_PIX4D, 'AboveGroundAltitude')
        if rel_alt is not None:
            notes.append('relative altitude is Camera:AboveGroundAltitude (above ground, not take-off)')

    focal = _positive(exif_ifd.get(_FOCAL_LENGTH))
    focal35 = _positive(exif_ifd.get(_FOCAL_35MM))
    if focal is None:
        notes.append('no focal length')
    res_px_per_mm = _focal_plane_resolution(exif_ifd, notes)

    # DJI's calibrated values are pixels of the image as the camera wrote it
    scale_x = width / exif_width if exif_width else 1.0
    exif_height = _int(exif_ifd.get(_PIXEL_Y_DIMENSION))
    scale_y = height / exif_height if exif_width and exif_height and exif_height > 0 else scale_x
    cal_f = _xmp_float(xmp, _NS_DJI, 'CalibratedFocalLength')
    cal_f = cal_f * scale_x if cal_f and cal_f > 0 else None
    cal_c = None
    cx = _xmp_float(xmp, _NS_DJI, 'CalibratedOpticalCenterX')
    cy = _xmp_float(xmp, _NS_DJI, 'CalibratedOpticalCenterY')
    if cx is not None and cy is not None:
        # DJI puts the centre of a W-wide image at W/2 (corner origin): shift to centres at integers
        cal_c = (cx * scale_x - 0.5, cy * scale_y - 0.5)

    gimbal, flight = _xmp_attitude(xmp, notes)
    return StillMetadata(
        path=path, width_px=width, height_px=height, exif_width_px=exif_width, stamp_ns=stamp_ns,
        gps_stamp_ns=_gps_stamp(gps),
        latitude_deg=lat, longitude_deg=lon, altitude_m=alt,
        relative_altitude_m=NAN if rel_alt is None else rel_alt,
        make=make, model=model, focal_length_mm=focal, focal_length_35mm_mm=focal35,
        focal_plane_x_res_px_per_mm=res_px_per_mm, calibrated_focal_length_px=cal_f,
        calibrated_optical_center_px=cal_c, gimbal_ypr_deg=gimbal, flight_ypr_deg=flight,
        exif_orientation=orientation, notes=tuple(notes),
    )


# ----------------------------------------------------------------------------------------------
# EXIF

def _read_exif(im: Image.Image, notes: list[str]) -> tuple[dict, dict, dict, dict]:
    """IFD0, Exif, GPS and Interop IFDs as {tag: value} (empty when absent or unreadable)."""
    try:
        # Pillow's PNG getexif() decodes the image to look for an eXIf chunk after the pixels;
        # the base method reads what the header gave (eXIf before IDAT, ImageMagick's text chunk)
        exif = Image.Image.getexif(im) if im.format == 'PNG' else im.getexif()
        ifd0 = dict(exif)
        sub = []
        for tag in (_IFD_EXIF, _IFD_GPS, _IFD_INTEROP):
            try:
                sub.append(dict(exif.get_ifd(tag)))
            except Exception:  # noqa: BLE001 - one broken sub-IFD must not lose the others
                notes.append(f'EXIF IFD 0x{tag:04X} unreadable')
                sub.append({})
    except Exception as exc:  # noqa: BLE001 - a corrupt EXIF block is missing metadata, not an error
        notes.append(f'EXIF unreadable ({type(exc).__name__})')
        return {}, {}, {}, {}
    # Pillow may list the sub-IFD pointers themselves among IFD0's tags: not metadata
    for tag in (_IFD_EXIF, _IFD_GPS, _IFD_INTEROP):
        ifd0.pop(tag, None)
    if not ifd0 and not any(sub):
        notes.append('no EXIF')
    elif not sub[1]:
        notes.append('no GPS in the EXIF')
    return ifd0, sub[0], sub[1], sub[2]


def _scalar(value: Any) -> Any:
    if isinstance(value, (tuple, list)):
        return value[0] if len(value) >= 1 else None
    return value


def _float(value: Any) -> float | None:
    """A finite float from an EXIF number (IFDRational with a zero denominator is NaN -> None)."""
    value = _scalar(value)
    if value is None or isinstance(value, (str, bytes)):
        return None
    try:
        out = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return out if math.isfinite(out) else None


def _positive(value: Any) -> float | None:
    out = _float(value)
    return out if out is not None and out > 0 else None  # 0 means "unknown" in EXIF


def _int(value: Any) -> int | None:
    value = _scalar(value)
    if isinstance(value, bytes):
        return value[0] if value else None
    if isinstance(value, str):
        return int(value) if value.strip().isdigit() else None
    out = _float(value)
    return int(out) if out is not None else None


def _text(value: Any) -> str:
    if value is None:
        return ''
    if isinstance(value, bytes):
        value = value.decode('latin-1')
    return str(value).replace('\x00', '').strip()


def _focal_plane_resolution(exif_ifd: dict, notes: list[str]) -> float | None:
    res = _positive(exif_ifd.get(_FOCAL_PLANE_X_RES))
    if res is None:
        return None
    unit = _int(exif_ifd.get(_FOCAL_PLANE_UNIT))
    if unit is None:
        notes.append('FocalPlaneResolutionUnit missing: inches assumed (the EXIF default)')
        unit = 2
    if unit not in _MM_PER_UNIT:
        notes.append(f'FocalPlaneResolutionUnit {unit} is not a length: focal plane resolution ignored')
        return None
    return res / _MM_PER_UNIT[unit]


_EXIF_DATETIME = re.compile(r'^\s*(\d{4})[:-](\d\d)[:-](\d\d)[ T](\d\d):(\d\d):(\d\d)')
_OFFSET = re.compile(r'^\s*([+-])(\d\d):(\d\d)\s*$')


def _parse_datetime_s(text: str) -> int | None:
    """'YYYY:MM:DD HH:MM:SS' as seconds since the epoch, the clock reading taken as UTC."""
    m = _EXIF_DATETIME.match(text)
    if not m:
        return None
    try:
        dt = datetime(*(int(g) for g in m.groups()))  # naive on purpose, see callers
    except ValueError:
        return None  # '0000:00:00 00:00:00', month 13...
    return calendar.timegm(dt.timetuple())


def _subsec_ns(text: str) -> int:
    digits = re.sub(r'\D', '', text)[:9]
    return int(digits.ljust(9, '0')) if digits else 0


def _capture_stamp(ifd0: dict, exif_ifd: dict, gps: dict, notes: list[str]) -> int | None:
    """UTC ns of the capture: DateTimeOriginal + SubSec - offset, else GPS date/time, else naive."""
    local_s = None
    raw = _text(exif_ifd.get(_DATETIME_ORIGINAL))
    if raw:
        local_s = _parse_datetime_s(raw)
        if local_s is None:
            notes.append(f'DateTimeOriginal {raw!r} unreadable')
    if local_s is None:
        raw_dt = _text(ifd0.get(_DATETIME))
        local_s = _parse_datetime_s(raw_dt) if raw_dt else None
        if local_s is not None:
            notes.append('no DateTimeOriginal: DateTime (file change time) used')
    local_ns = None if local_s is None else local_s * 10**9 + _subsec_ns(_text(exif_ifd.get(_SUBSEC_ORIGINAL)))

    offset = _text(exif_ifd.get(_OFFSET_TIME_ORIGINAL)) or _text(exif_ifd.get(_OFFSET_TIME))
    m = _OFFSET.match(offset) if offset else None
    if local_ns is not None and m:
        sign = 1 if m.group(1) == '+' else -1
        return local_ns - sign * (int(m.group(2)) * 3600 + int(m.group(3)) * 60) * 10**9

    gps_ns = _gps_stamp(gps)
    if gps_ns is not None and local_ns is not None:
        # the camera clock, in UTC by the time zone that GPS time implies (rounded to 15 min): GPS time
        # tags can be stale (a still repeating the previous one's fix), the camera clock keeps its spacing
        zone_ns = round((local_ns - gps_ns) / 900e9) * 900 * 10**9
        notes.append('time from the camera clock, in UTC by the zone its GPS time implies: no OffsetTimeOriginal')
        notes.append(_camera_clock_note(local_ns, gps_ns))
        return local_ns - zone_ns
    if gps_ns is not None:
        notes.append('time from GPSDateStamp/GPSTimeStamp (UTC): no OffsetTimeOriginal nor camera clock')
        return gps_ns
    if local_ns is not None:
        notes.append('no time offset nor GPS time: local time treated as UTC')
        return local_ns
    notes.append('no capture time')
    return None


def _camera_clock_note(local_ns: int, gps_ns: int) -> str:
    """How the camera clock reads against GPS time: the zone (a multiple of 15 min) and the rest."""
    off_s = (local_ns - gps_ns) / 1e9
    if abs(off_s) > 14 * 3600:  # no time zone is that far: the camera clock was never set
        return f'camera clock is {off_s:+.0f} s off GPS time (unset?)'
    zone_s = round(off_s / 900.0) * 900
    hh, mm = divmod(abs(zone_s) // 60, 60)
    sign = '-' if zone_s < 0 else '+'
    return f'camera clock is UTC{sign}{hh:02d}:{mm:02d} {off_s - zone_s:+.0f} s by GPS time'


def _gps_stamp(gps: dict) -> int | None:
    date = _text(gps.get(_GPS_DATE))
    hms = gps.get(_GPS_TIME)
    if not date or not isinstance(hms, (tuple, list)) or len(hms) != 3:
        return None
    m = re.match(r'^\s*(\d{4})[:-](\d\d)[:-](\d\d)', date)
    parts = [_float(v) for v in hms]
    if not m or any(p is None or p < 0 for p in parts):
        return None
    try:
        day_s = calendar.timegm(datetime(int(m[1]), int(m[2]), int(m[3])).timetuple())
    except ValueError:
        return None
    h, mi, s = parts
    return day_s * 10**9 + round((h * 3600 + mi * 60 + s) * 1e9)


def _ref(value: Any) -> str:
    return _text(value).upper()[:1]


def _dms(value: Any) -> float | None:
    """Degrees from an EXIF (deg, min, sec) triple of rationals (or fewer components)."""
    if not isinstance(value, (tuple, list)) or not 1 <= len(value) <= 3:
        return None
    parts = [_float(v) for v in value]
    if any(p is None for p in parts):
        return None
    return sum(p / 60.0**i for i, p in enumerate(parts))


def _gps_position(gps: dict, notes: list[str]) -> tuple[float, float, float]:
    if not gps:
        return NAN, NAN, NAN
    lat = lon = alt = NAN
    if _ref(gps.get(_GPS_STATUS)) == 'V':
        notes.append('GPSStatus V (void fix): position ignored')
        return lat, lon, alt
    for name, tag_ref, tag_val, signs, limit in (('latitude', _GPS_LAT_REF, _GPS_LAT, 'NS', 90.0),
                                                 ('longitude', _GPS_LON_REF, _GPS_LON, 'EW', 180.0)):
        if tag_val not in gps:
            notes.append(f'no GPS {name}')
            continue
        deg = _dms(gps[tag_val])
        ref = _ref(gps.get(tag_ref))
        if deg is None:
            notes.append(f'GPS {name} unreadable (zero denominator?)')
        elif not ref or ref not in signs:
            notes.append(f'GPS {name} ref missing or unknown' + (f' ({ref!r})' if ref else ''))
        elif deg > limit:
            notes.append(f'GPS {name} {deg:g} out of range')
        else:
            value = -deg if ref == signs[1] else deg
            if name == 'latitude':
                lat = value
            else:
                lon = value
    if lat == 0.0 and lon == 0.0:
        notes.append('GPS position (0, 0): no fix, ignored')
        lat = lon = NAN
    elif math.isfinite(lat) != math.isfinite(lon):
        lat = lon = NAN  # half a position places the still nowhere: the note above says which half
    if _GPS_ALT in gps:
        value = _float(gps[_GPS_ALT])
        ref_raw = gps.get(_GPS_ALT_REF)
        ref = _int(ref_raw) if ref_raw is not None else 0  # 0 (above sea level) is the EXIF default
        if value is None:
            notes.append('GPS altitude unreadable (zero denominator?)')
        elif ref not in (0, 1, 2, 3):
            notes.append(f'GPSAltitudeRef {ref} unknown: altitude ignored')
        else:
            alt = -value if ref in (1, 3) else value
            if ref in (2, 3):
                notes.append('GPS altitude is ellipsoidal height (GPSAltitudeRef 2/3)')
    elif math.isfinite(lat):
        notes.append('no GPS altitude')
    return lat, lon, alt


# ----------------------------------------------------------------------------------------------
# XMP

def _ns(uri: str) -> str:
    """A namespace URI as compared here: no scheme, no 'www.', no trailing slash, lower case."""
    uri = uri.strip().lower()
    uri = re.sub(r'^[a-z]+://', '', uri)
    if uri.startswith('www.'):
        uri = uri[4:]
    return uri.rstrip('/')


def _split(tag: str) -> tuple[str, str]:
    if tag.startswith('{'):
        uri, _, local = tag[1:].partition('}')
        return _ns(uri), local
    return '', tag


def _read_xmp(im: Image.Image, notes: list[str]) -> dict[tuple[str, str], str]:
    raw = im.info.get('xmp') or im.info.get('XML:com.adobe.xmp')
    if not raw:
        notes.append('no XMP')
        return {}
    packet = raw if isinstance(raw, bytes) else str(raw).encode('utf-8')
    return parse_xmp(packet, notes)


def parse_xmp(packet: bytes, notes: list[str] | None = None) -> dict[tuple[str, str], str]:
    """Flatten an XMP packet to {(namespace, name): text}; struct fields as 'Struct/Field'.

    The namespace is normalised (see ``_ns``: 'http://www.dji.com/drone-dji/1.0/' ->
    'dji.com/drone-dji/1.0'). Arrays (rdf:Seq/Bag/Alt) become their items joined by a space.
    """
    notes = [] if notes is None else notes
    packet = packet.strip(b'\x00 \t\r\n')
    try:
        root = ET.fromstring(packet)
    except ET.ParseError:
        start = packet.find(b'<x:xmpmeta')
        end = packet.rfind(b'</x:xmpmeta>')
        try:
            root = ET.fromstring(packet[start:end + 12]) if 0 <= start < end else None
        except ET.ParseError:
            root = None
        if root is None:
            notes.append('XMP is not well-formed XML: read by pattern')
            return _xmp_by_pattern(packet)
    out: dict[tuple[str, str], str] = {}
    for rdf_root in root.iter(f'{{{_RDF}}}RDF'):
        for desc in rdf_root:
            if desc.tag == f'{{{_RDF}}}Description':  # nested ones are struct values, read in place
                _collect(desc, '', out)
    return out


def _collect(desc: ET.Element, prefix: str, out: dict[tuple[str, str], str]) -> None:
    """Properties of one rdf:Description (attributes and child elements) into ``out``."""
    for name, value in desc.attrib.items():
        ns, local = _split(name)
        if ns and ns != _ns(_RDF) and not ns.startswith('w3.org/xml'):
            out.setdefault((ns, prefix + local), value.strip())
    for child in desc:
        _property(child, prefix, out)


def _property(elem: ET.Element, prefix: str, out: dict[tuple[str, str], str]) -> None:
    ns, local = _split(elem.tag)
    key = prefix + local
    rdf = _ns(_RDF)
    kids = list(elem)
    if elem.get(f'{{{_RDF}}}parseType') == 'Resource':
        for kid in kids:
            _property(kid, key + '/', out)
        return
    for kid in kids:
        kns, klocal = _split(kid.tag)
        if kns == rdf and klocal == 'Description':
            _collect(kid, key + '/', out)
            return
        if kns == rdf and klocal in ('Seq', 'Bag', 'Alt'):
            items = [(li.text or '').strip() for li in kid if _split(li.tag) == (rdf, 'li')]
            out.setdefault((ns, key), ' '.join(items[:1] if klocal == 'Alt' else items))
            return
    # <ns:Struct ns:Field="v"/> is the shorthand form of a struct
    fields = {n: v for n, v in elem.attrib.items() if _split(n)[0] not in ('', rdf)}
    if fields and not kids:
        for name, value in fields.items():
            out.setdefault((_split(name)[0], key + '/' + _split(name)[1]), value.strip())
        return
    if kids:
        for kid in kids:
            _property(kid, key + '/', out)
        return
    resource = elem.get(f'{{{_RDF}}}resource')
    out.setdefault((ns, key), (elem.text or resource or '').strip())


_ATTR_PATTERN = re.compile(rb'([A-Za-z][\w.-]*):(\w+)\s*=\s*"([^"]*)"')
_ELEM_PATTERN = re.compile(rb'<([A-Za-z][\w.-]*):(\w+)>([^<]*)</\1:\2>')


def _xmp_by_pattern(packet: bytes) -> dict[tuple[str, str], str]:
    """Last resort for a broken packet: known prefixes' ``p:Name="v"`` and ``<p:Name>v</p:Name>``."""
    out: dict[tuple[str, str], str] = {}
    for pattern in (_ATTR_PATTERN, _ELEM_PATTERN):
        for m in pattern.finditer(packet):
            ns = _PREFIX_NS.get(m.group(1).decode('ascii', 'replace').lower())
            if ns:
                out.setdefault((ns, m.group(2).decode('ascii')), m.group(3).decode('utf-8', 'replace').strip())
    return out


def _xmp_float(xmp: dict[tuple[str, str], str], ns: str, name: str) -> float | None:
    text = xmp.get((ns, name))
    if text is None:
        return None
    text = text.strip()
    try:
        if '/' in text:  # some writers use EXIF-style rationals: '4971569/65536'
            num, den = text.split('/', 1)
            value = float(num) / float(den)
        else:
            value = float(text)
    except (ValueError, ZeroDivisionError):
        return None
    return value if math.isfinite(value) else None


def _triple(xmp: dict[tuple[str, str], str], ns: str, names: tuple[str, str, str],
            ) -> tuple[tuple[float, float, float] | None, bool]:
    """((yaw, pitch, roll) or None, whether some but not all three were there and readable)."""
    yaw, pitch, roll = (_xmp_float(xmp, ns, n) for n in names)
    if yaw is not None and pitch is not None and roll is not None:
        return (yaw, pitch, roll), False
    return None, any((ns, n) in xmp for n in names)


# (namespace, (yaw, pitch, roll) names, pitch offset to make -90 nadir, label)
_GIMBAL_SOURCES = (
    (_NS_DJI, ('GimbalYawDegree', 'GimbalPitchDegree', 'GimbalRollDegree'), 0.0, 'DJI gimbal'),
    (_NS_PARROT, ('CameraYawDegree', 'CameraPitchDegree', 'CameraRollDegree'), 0.0, 'Parrot camera'),
    (_NS_SKYDIO, ('CameraOrientationNED/Yaw', 'CameraOrientationNED/Pitch', 'CameraOrientationNED/Roll'),
     0.0, 'Skydio camera'),
    (_NS_PIX4D, ('Yaw', 'Pitch', 'Roll'), -90.0, 'Camera:Yaw/Pitch/Roll'),
    (_NS_SENSEFLY, ('Yaw', 'Pitch', 'Roll'), -90.0, 'senseFly Camera:Yaw/Pitch/Roll'),
)
_FLIGHT_SOURCES = (
    (_NS_DJI, ('FlightYawDegree', 'FlightPitchDegree', 'FlightRollDegree'), 'DJI flight'),
    (_NS_PARROT, ('DroneYawDegree', 'DronePitchDegree', 'DroneRollDegree'), 'Parrot drone'),
)


def _xmp_attitude(xmp: dict[tuple[str, str], str], notes: list[str],
                  ) -> tuple[tuple[float, float, float] | None, tuple[float, float, float] | None]:
    gimbal = flight = None
    for ns, names, pitch_offset, label in _GIMBAL_SOURCES:
        got, partial = _triple(xmp, ns, names)
        if got is not None:
            gimbal = (got[0], got[1] + pitch_offset, got[2])
            break
        if partial:
            notes.append(f'{label} angles incomplete: ignored')
    for ns, names, label in _FLIGHT_SOURCES:
        got, partial = _triple(xmp, ns, names)
        if got is not None:
            flight = got
            break
        if partial:
            notes.append(f'{label} angles incomplete: ignored')
    if xmp and gimbal is None:
        notes.append('no gimbal angles in the XMP')
    return gimbal, flight


def _xmp_position(xmp: dict[tuple[str, str], str], lat: float, lon: float, alt: float,
                  notes: list[str]) -> tuple[float, float, float]:
    """DJI's XMP position, used only when the EXIF has none."""
    x_lat = _xmp_float(xmp, _NS_DJI, 'GpsLatitude') or _xmp_float(xmp, _NS_DJI, 'Latitude')
    x_lon = (_xmp_float(xmp, _NS_DJI, 'GpsLongitude') or _xmp_float(xmp, _NS_DJI, 'GpsLongtitude')
             or _xmp_float(xmp, _NS_DJI, 'Longitude'))
    if x_lat is None or x_lon is None or not (abs(x_lat) <= 90 and abs(x_lon) <= 180) or x_lat == x_lon == 0:
        return lat, lon, alt
    x_alt = _xmp_float(xmp, _NS_DJI, 'AbsoluteAltitude')
    notes.append('position from DJI XMP (none in the EXIF)')
    return x_lat, x_lon, (alt if x_alt is None else x_alt)
