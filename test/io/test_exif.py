"""EXIF/XMP of survey stills and the intrinsics they imply, on real Canon and DJI stills.

Fixtures: three Caliterra stills copied into test/data/real/exif/ (see its README.md), and the two
stills already in data/worlds/ read in place. Files that must be broken are written into tmp_path.
Expected values are the EXIF's own rationals, decoded by hand here.
"""
from __future__ import annotations

import calendar
import dataclasses
import math
from datetime import datetime
from pathlib import Path

import pytest
from PIL import Image
from PIL.TiffImagePlugin import IFDRational

from srmosaic_ros.errors import InputError, MetadataError
from srmosaic_ros.io.camera_db import CAMERAS, FULL_FRAME_DIAGONAL_MM, lookup_sensor
from srmosaic_ros.io.exif import intrinsics_from_metadata, parse_xmp, read_still_metadata
from repo_paths import REPO

REPO = REPO
FIXTURES = REPO / 'test' / 'data' / 'real' / 'exif'
BRIGHTON = REPO / 'data' / 'worlds' / 'brighton_DJI_0025.jpg'
CALITERRA_FULL = REPO / 'data' / 'worlds' / 'caliterra_IMG_9360.jpg'

# Canon SX260 HS: FocalPlaneXResolution 4000000/244 px per inch (unit 2) at PixelXDimension 4000
CANON_PX_PER_MM = 4000000 / 244 / 25.4
CANON_FX_2000 = 4.5 * CANON_PX_PER_MM * 2000 / 4000


def utc_ns(*fields: int) -> int:
    return calendar.timegm(datetime(*fields).timetuple()) * 10**9  # fields are UTC


def dms(deg: float, minutes: float, seconds: float) -> float:
    return deg + minutes / 60 + seconds / 3600


# name: (GPS UTC time, latitude, longitude, altitude, camera clock minus GPS time beyond the -5 h zone)
CALITERRA = {
    'IMG_9354.jpg': ((2014, 10, 19, 18, 20, 51), dms(30, 10, 16404 / 1000), -dms(98, 5, 23970 / 1000), 3173 / 10, 0),
    'IMG_9370.jpg': ((2014, 10, 19, 18, 21, 25), dms(30, 10, 16428 / 1000), -dms(98, 5, 21108 / 1000), 3489 / 10, 0),
    # a stale fix: the same GPS tags as IMG_9370, while the camera clock moved on 2 s
    'IMG_9371.jpg': ((2014, 10, 19, 18, 21, 25), dms(30, 10, 16428 / 1000), -dms(98, 5, 21108 / 1000), 3489 / 10, 2),
}


@pytest.mark.parametrize('name', sorted(CALITERRA))
def test_caliterra_halved_still(name):
    gps_time, lat, lon, alt, clock_s = CALITERRA[name]
    meta = read_still_metadata(FIXTURES / name)
    assert (meta.width_px, meta.height_px, meta.exif_width_px) == (2000, 1500, 4000)
    # the camera clock (steady 2 s spacing) in UTC by the zone its GPS time implies
    assert meta.stamp_ns == utc_ns(*gps_time) + clock_s * 10**9
    assert meta.latitude_deg == pytest.approx(lat, abs=1e-12)
    assert meta.longitude_deg == pytest.approx(lon, abs=1e-12)
    assert meta.altitude_m == pytest.approx(alt, abs=1e-9)
    assert (meta.make, meta.model) == ('Canon', 'Canon PowerShot SX260 HS')
    assert meta.focal_length_mm == 4.5
    assert meta.focal_length_35mm_mm is None
    assert meta.focal_plane_x_res_px_per_mm == pytest.approx(CANON_PX_PER_MM, rel=1e-12)
    assert meta.exif_orientation == 1
    assert math.isnan(meta.relative_altitude_m)
    assert meta.gimbal_ypr_deg is None and meta.flight_ypr_deg is None
    assert meta.calibrated_focal_length_px is None
    assert meta.notes == (
        'no XMP',
        'EXIF width 4000 px, decoded 2000 px (resized after capture)',
        'time from the camera clock, in UTC by the zone its GPS time implies: no OffsetTimeOriginal',
        f'camera clock is UTC-05:00 {clock_s:+d} s by GPS time',
    )

    intr, reason = intrinsics_from_metadata(meta)
    assert reason == 'focal length 4.5 mm over a 6.20 mm sensor (focal plane resolution)'
    assert intr.fx == pytest.approx(CANON_FX_2000, rel=1e-12)
    assert intr.fx == pytest.approx(1452.175, abs=1e-3)
    assert intr.fy == intr.fx
    assert (intr.width, intr.height, intr.cx, intr.cy) == (2000, 1500, 999.5, 749.5)


def test_caliterra_full_size_original_has_no_resize_and_double_fx():
    meta = read_still_metadata(CALITERRA_FULL)
    assert (meta.width_px, meta.height_px, meta.exif_width_px) == (4000, 3000, 4000)
    assert meta.stamp_ns == utc_ns(2014, 10, 19, 18, 21, 4)
    assert meta.latitude_deg == pytest.approx(dms(30, 10, 15.336), abs=1e-12)
    assert meta.longitude_deg == pytest.approx(-dms(98, 5, 22.176), abs=1e-12)
    assert meta.altitude_m == pytest.approx(327.1, abs=1e-9)
    # its XMP holds only xmp:Rating: read, no angles
    assert 'no XMP' not in meta.notes and 'no gimbal angles in the XMP' in meta.notes
    assert not any('resized' in n for n in meta.notes)
    intr, _ = intrinsics_from_metadata(meta)
    assert intr.fx == pytest.approx(2 * CANON_FX_2000, rel=1e-12)
    assert (intr.cx, intr.cy) == (1999.5, 1499.5)


def test_stale_gps_fix_pair_shares_position_not_time():
    a = read_still_metadata(FIXTURES / 'IMG_9370.jpg')
    b = read_still_metadata(FIXTURES / 'IMG_9371.jpg')
    assert b.stamp_ns - a.stamp_ns == 2 * 10**9  # the camera clock moved on; the GPS tags did not
    assert (a.latitude_deg, a.longitude_deg, a.altitude_m) == (b.latitude_deg, b.longitude_deg, b.altitude_m)


def test_dji_phantom3_xmp_and_table_intrinsics():
    meta = read_still_metadata(BRIGHTON)
    assert (meta.width_px, meta.height_px, meta.exif_width_px) == (4000, 2250, 4000)
    assert (meta.make, meta.model) == ('DJI', 'FC300S')  # EXIF pads both with NULs
    assert meta.relative_altitude_m == 40.0
    # drone-dji:GimbalYawDegree="-132.00" GimbalPitchDegree="-89.90" GimbalRollDegree="+0.00"
    assert meta.gimbal_ypr_deg == (-132.0, -89.9, 0.0)
    # drone-dji:FlightYawDegree="-129.90" FlightPitchDegree="-1.60" FlightRollDegree="+0.90"
    assert meta.flight_ypr_deg == (-129.9, -1.6, 0.9)
    assert meta.latitude_deg == pytest.approx(dms(46, 50, 33.9859), abs=1e-12)
    assert meta.longitude_deg == pytest.approx(-dms(91, 59, 37.7734), abs=1e-12)
    assert meta.altitude_m == pytest.approx(198.509, abs=1e-9)
    assert meta.focal_length_mm == 3.61 and meta.focal_length_35mm_mm == 20.0
    assert meta.focal_plane_x_res_px_per_mm is None and meta.calibrated_focal_length_px is None
    # no OffsetTimeOriginal and no GPS time: the naive 16:32:50 is taken as UTC
    assert meta.stamp_ns == utc_ns(2016, 6, 23, 16, 32, 50)
    assert meta.notes == ('no time offset nor GPS time: local time treated as UTC',)

    intr, reason = intrinsics_from_metadata(meta)
    assert reason == 'focal length 3.61 mm over a 6.17 mm sensor (camera table: DJI FC300S)'
    assert intr.fx == pytest.approx(3.61 / 6.17 * 4000, rel=1e-12)
    assert (intr.cx, intr.cy) == (1999.5, 1124.5)

    # without the table entry the 35 mm equivalent is the last resort, over the diagonal
    unknown = dataclasses.replace(meta, make='Nobody', model='X1')
    intr35, reason35 = intrinsics_from_metadata(unknown)
    assert reason35 == '35 mm equivalent 20 mm'
    assert intr35.fx == pytest.approx(20 / FULL_FRAME_DIAGONAL_MM * math.hypot(4000, 2250), rel=1e-12)
    assert FULL_FRAME_DIAGONAL_MM == pytest.approx(43.2666, abs=1e-4)
    no_f35 = dataclasses.replace(unknown, focal_length_35mm_mm=None)
    assert intrinsics_from_metadata(no_f35)[0] is None


def test_truncated_jpeg_reads_the_same_metadata(tmp_path):
    """Only the header is read: a still cut off inside its compressed pixels gives the same answer."""
    src = FIXTURES / 'IMG_9354.jpg'
    cut = tmp_path / 'cut.jpg'
    cut.write_bytes(src.read_bytes()[:60_000])
    with pytest.raises(OSError):
        Image.open(cut).load()  # decoding it fails
    full, part = read_still_metadata(src), read_still_metadata(cut)
    assert dataclasses.replace(part, path=src) == full


def test_png_without_exif(tmp_path):
    path = tmp_path / 'plain.png'
    Image.new('RGB', (40, 30), (10, 20, 30)).save(path)
    meta = read_still_metadata(path)
    assert (meta.width_px, meta.height_px) == (40, 30)
    assert all(math.isnan(v) for v in (meta.latitude_deg, meta.longitude_deg, meta.altitude_m,
                                       meta.relative_altitude_m))
    assert None is meta.stamp_ns is meta.exif_width_px is meta.focal_length_mm is meta.focal_length_35mm_mm
    assert None is meta.focal_plane_x_res_px_per_mm is meta.gimbal_ypr_deg is meta.flight_ypr_deg
    assert (meta.make, meta.model, meta.exif_orientation) == ('', '', 1)
    assert meta.notes == ('no EXIF', 'no XMP', 'no camera make/model', 'no capture time', 'no focal length')
    assert intrinsics_from_metadata(meta) == (None, 'no focal length in the EXIF')


def test_png_with_exif_in_its_header(tmp_path):
    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = 'DJI', 'FC6310'
    exif.get_ifd(0x8769)[0x920A] = IFDRational(88, 10)
    path = tmp_path / 'p4p.png'
    Image.new('RGB', (547, 365)).save(path, exif=exif)
    meta = read_still_metadata(path)
    assert (meta.make, meta.model, meta.focal_length_mm) == ('DJI', 'FC6310', 8.8)
    assert meta.notes == ('no GPS in the EXIF', 'no XMP', 'no capture time')
    intr, reason = intrinsics_from_metadata(meta)
    assert reason == 'focal length 8.8 mm over a 13.20 mm sensor (camera table: DJI FC6310)'
    assert intr.fx == pytest.approx(8.8 / 13.2 * 547, rel=1e-12)


def test_text_file_named_jpg_is_a_metadata_error(tmp_path):
    path = tmp_path / 'notes.jpg'
    path.write_text('lat,lon\n30.1,-98.0\n')
    with pytest.raises(MetadataError, match='notes.jpg is not an image') as info:
        read_still_metadata(path)
    assert isinstance(info.value, InputError)
    with pytest.raises(MetadataError, match='does not exist'):
        read_still_metadata(tmp_path / 'missing.jpg')


def test_broken_gps_rationals_and_missing_refs(tmp_path):
    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = 'Canon', 'Canon PowerShot SX260 HS'
    gps = exif.get_ifd(0x8825)
    gps[1] = 'N'
    gps[2] = (IFDRational(30, 0), IFDRational(10, 1), IFDRational(15, 1))  # 30/0 degrees
    gps[4] = (IFDRational(98, 1), IFDRational(5, 1), IFDRational(22, 1))  # no GPSLongitudeRef
    gps[6] = IFDRational(100, 0)
    gps[7] = (IFDRational(18, 1), IFDRational(0, 0), IFDRational(5, 1))
    gps[29] = '2014:10:19'
    sub = exif.get_ifd(0x8769)
    sub[0x9003] = '2014:10:19 13:00:05'
    sub[0x920A] = IFDRational(45, 10)
    path = tmp_path / 'badgps.jpg'
    Image.new('RGB', (64, 48), (90, 120, 60)).save(path, exif=exif)

    meta = read_still_metadata(path)
    assert math.isnan(meta.latitude_deg) and math.isnan(meta.longitude_deg) and math.isnan(meta.altitude_m)
    assert not meta.has_position
    assert 'GPS latitude unreadable (zero denominator?)' in meta.notes
    assert 'GPS longitude ref missing or unknown' in meta.notes
    assert 'GPS altitude unreadable (zero denominator?)' in meta.notes
    # GPS time with a 0/0 minute is unusable: the naive camera time is used instead
    assert meta.stamp_ns == utc_ns(2014, 10, 19, 13, 0, 5)
    assert 'no time offset nor GPS time: local time treated as UTC' in meta.notes
    # table fallback (no focal plane resolution in this EXIF)
    intr, reason = intrinsics_from_metadata(meta)
    assert reason == 'focal length 4.5 mm over a 6.20 mm sensor (camera table: Canon PowerShot SX260 HS)'
    assert intr.fx == pytest.approx(4.5 / 6.198 * 64, rel=1e-12)


def test_offset_and_subseconds_give_utc(tmp_path):
    exif = Image.Exif()
    sub = exif.get_ifd(0x8769)
    sub[0x9003] = '2023:05:01 14:30:00'
    sub[0x9291] = '25'  # SubSecTimeOriginal: 0.25 s
    sub[0x9011] = '+02:00'
    gps = exif.get_ifd(0x8825)  # a GPS time that must NOT win over the explicit offset
    gps[7] = (IFDRational(9, 1), IFDRational(0, 1), IFDRational(0, 1))
    gps[29] = '2023:05:01'
    path = tmp_path / 'offset.jpg'
    Image.new('RGB', (32, 24)).save(path, exif=exif)
    meta = read_still_metadata(path)
    assert meta.stamp_ns == utc_ns(2023, 5, 1, 12, 30, 0) + 250_000_000
    assert not any('UTC' in n for n in meta.notes)


DJI_ELEMENT_XMP = b"""<?xpacket begin="\xef\xbb\xbf" id="W5M0MpCehiHzreSzNTczkc9d"?>
<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
 <rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/">
  <drone-dji:RelativeAltitude>+100.10</drone-dji:RelativeAltitude>
  <drone-dji:GimbalRollDegree>+0.00</drone-dji:GimbalRollDegree>
  <drone-dji:GimbalYawDegree>-1.30</drone-dji:GimbalYawDegree>
  <drone-dji:GimbalPitchDegree>-90.00</drone-dji:GimbalPitchDegree>
  <drone-dji:FlightRollDegree>-6.00</drone-dji:FlightRollDegree>
  <drone-dji:FlightYawDegree>+2.50</drone-dji:FlightYawDegree>
  <drone-dji:FlightPitchDegree>-15.00</drone-dji:FlightPitchDegree>
  <drone-dji:CalibratedFocalLength>3666.666504</drone-dji:CalibratedFocalLength>
  <drone-dji:CalibratedOpticalCenterX>2736.000000</drone-dji:CalibratedOpticalCenterX>
  <drone-dji:CalibratedOpticalCenterY>1824.000000</drone-dji:CalibratedOpticalCenterY>
 </rdf:Description></rdf:RDF></x:xmpmeta>
<?xpacket end="w"?>"""

PIX4D_XMP = b"""<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
 <rdf:Description rdf:about="" xmlns:Camera="http://pix4d.com/camera/1.0"
   xmlns:drone-parrot="http://www.parrot.com/drone-parrot/1.0/" drone-parrot:DroneYawDegree="44.0"
   drone-parrot:DronePitchDegree="3/2" drone-parrot:DroneRollDegree="-0.5">
  <Camera:Yaw>45.5</Camera:Yaw><Camera:Pitch>2.0</Camera:Pitch><Camera:Roll>-1.25</Camera:Roll>
  <Camera:BandName><rdf:Seq><rdf:li>Red</rdf:li></rdf:Seq></Camera:BandName>
 </rdf:Description></rdf:RDF></x:xmpmeta>"""


def _jpeg_with_xmp(path: Path, xmp: bytes, size: tuple[int, int], exif_width: int | None = None) -> Path:
    exif = Image.Exif()
    if exif_width:
        exif.get_ifd(0x8769)[0xA002] = exif_width
        exif.get_ifd(0x8769)[0xA003] = round(exif_width * size[1] / size[0])
    Image.new('RGB', size, (50, 60, 70)).save(path, exif=exif, xmp=xmp)
    return path


def test_dji_xmp_in_element_form_with_calibration_scaled(tmp_path):
    # a Phantom 4 RTK packet (5472x3648 native) on a still resized to a quarter
    path = _jpeg_with_xmp(tmp_path / 'p4rtk.jpg', DJI_ELEMENT_XMP, (1368, 912), exif_width=5472)
    meta = read_still_metadata(path)
    assert meta.relative_altitude_m == pytest.approx(100.1)
    assert meta.gimbal_ypr_deg == (-1.3, -90.0, 0.0)
    assert meta.flight_ypr_deg == (2.5, -15.0, -6.0)
    assert meta.calibrated_focal_length_px == pytest.approx(3666.666504 / 4, rel=1e-12)
    # DJI's 2736 = 5472 / 2 is the image centre: (1368 - 1) / 2 with centres at integers
    assert meta.calibrated_optical_center_px == (683.5, 455.5)
    intr, reason = intrinsics_from_metadata(meta)
    assert reason == 'calibrated focal length (XMP)'
    assert (intr.fx, intr.cx, intr.cy) == (pytest.approx(916.666626), 683.5, 455.5)


def test_pix4d_camera_angles_are_turned_to_nadir_minus_90(tmp_path):
    meta = read_still_metadata(_jpeg_with_xmp(tmp_path / 'seq.jpg', PIX4D_XMP, (64, 48)))
    assert meta.gimbal_ypr_deg == (45.5, 2.0 - 90.0, -1.25)  # Pix4D pitch 0 = nadir
    assert meta.flight_ypr_deg == (44.0, 1.5, -0.5)  # Parrot DroneYaw/Pitch/RollDegree, a rational pitch


def test_xmp_parser_structs_arrays_and_broken_packets():
    skydio = b"""<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
     <rdf:Description xmlns:drone-skydio="https://www.skydio.com/drone-skydio/1.0/">
      <drone-skydio:CameraOrientationNED rdf:parseType="Resource"><drone-skydio:Yaw>10</drone-skydio:Yaw>
       <drone-skydio:Pitch>-80</drone-skydio:Pitch><drone-skydio:Roll>0.5</drone-skydio:Roll>
      </drone-skydio:CameraOrientationNED>
      <drone-skydio:Other><rdf:Description drone-skydio:Yaw="11"/></drone-skydio:Other>
     </rdf:Description></rdf:RDF></x:xmpmeta>"""
    flat = parse_xmp(skydio)
    ns = 'skydio.com/drone-skydio/1.0'
    assert flat == {(ns, 'CameraOrientationNED/Yaw'): '10', (ns, 'CameraOrientationNED/Pitch'): '-80',
                    (ns, 'CameraOrientationNED/Roll'): '0.5', (ns, 'Other/Yaw'): '11'}
    assert parse_xmp(PIX4D_XMP)[('pix4d.com/camera/1.0', 'BandName')] == 'Red'
    # undeclared prefixes make the packet unparsable XML: known prefixes are still read
    notes: list[str] = []
    broken = b'<x:xmpmeta><rdf:RDF><rdf:Description drone-dji:GimbalYawDegree="+12.30">' \
             b'<drone-dji:GimbalPitchDegree>-90.0</drone-dji:GimbalPitchDegree></rdf:Description></rdf:RDF></x:xmpmeta>'
    assert parse_xmp(broken, notes) == {('dji.com/drone-dji/1.0', 'GimbalYawDegree'): '+12.30',
                                        ('dji.com/drone-dji/1.0', 'GimbalPitchDegree'): '-90.0'}
    assert notes == ['XMP is not well-formed XML: read by pattern']


REQUIRED_MODELS = ['FC300S', 'FC300X', 'FC330', 'FC6310', 'FC6310S', 'FC6310R', 'FC220', 'FC2103', 'L1D-20c',
                   'FC2204', 'FC3170', 'FC7303', 'FC3411', 'L2D-20c', 'ZenmuseP1', 'XT2', 'ZH20T',
                   'MAVIC2-ENTERPRISE-ADVANCED', 'M30T', 'ANAFI', 'Sequoia', 'RedEdge', 'S.O.D.A.',
                   'PowerShot SX260 HS']


@pytest.mark.parametrize('model', REQUIRED_MODELS)
def test_camera_table_covers_the_common_uas_cameras(model):
    spec = lookup_sensor('', model)
    assert spec is not None
    assert spec.height_mm == pytest.approx(spec.width_mm * spec.native_height_px / spec.native_width_px, rel=5e-3)
    assert 0.5 < spec.pixel_pitch_um < 20


def test_camera_lookup_is_case_space_and_make_insensitive():
    p3 = lookup_sensor('DJI', 'FC300S')
    assert (p3.width_mm, p3.native_width_px, p3.native_height_px) == (6.17, 4000, 3000)
    for make, model in (('', 'fc300s'), ('', 'DJI FC300S'), ('dji', ' FC 300S '), ('DJI', 'DJI FC300S')):
        assert lookup_sensor(make, model) is p3
    assert lookup_sensor('Canon', 'Canon PowerShot SX260 HS').width_mm == 6.198
    assert lookup_sensor('senseFly', 'SODA') is lookup_sensor('', 'S.O.D.A.')
    assert lookup_sensor('MicaSense', 'RedEdge-MX').pixel_pitch_um == pytest.approx(3.75)
    assert lookup_sensor('DJI', 'FC9999') is None and lookup_sensor('', '') is None
    assert len({(s.model, s.native_width_px) for s in CAMERAS}) == len(CAMERAS)  # no duplicate rows


def test_camera_lookup_picks_the_sensor_that_fits_the_image():
    assert lookup_sensor('DJI', 'XT2', width_px=640, height_px=512).pixel_pitch_um == pytest.approx(17.0)
    assert lookup_sensor('DJI', 'XT2', width_px=4000, height_px=3000).width_mm == 7.6
    assert lookup_sensor('DJI', 'ZH20T', width_px=640, height_px=512).pixel_pitch_um == pytest.approx(12.0)
    assert lookup_sensor('DJI', 'ZH20T', width_px=5184, height_px=3888).width_mm == 7.6
    # a halved thermal image keeps the 5:4 aspect
    assert lookup_sensor('DJI', 'M30T', width_px=320, height_px=256).native_width_px == 640
    assert lookup_sensor('DJI', 'M30T', width_px=4000, height_px=3000).native_width_px == 8000
