"""GoPro GPMF telemetry in an MP4/MOV -> GPS fixes, accelerometer, gyroscope and orientation samples
(and a Karma drone's attitude and gimbal angles).

GPMF (GoPro's public spec, github.com/gopro/gpmf-parser) is a big-endian KLV stream: a 4-character
key, a 1-byte type, a 1-byte structure size and a 2-byte repeat count, the value padded to 32 bits.
Type 0 nests more KLV (``DEVC`` per device, ``STRM`` per sensor stream); in a stream, sticky
properties (``SCAL`` divisors, ``TYPE`` for ``?`` complex structures, ``SIUN``/``UNIT``, ``STNM``,
``TIMO``) modify the data KLV that follows them. The MP4 carries one GPMF payload per track sample
(about 1 s) in the ``gpmd`` track ("GoPro MET"); PyAV demuxes it as a data stream.

Read here:
- ``GPS5`` (HERO5..HERO11 camera GPS: lat, lon, alt, 2D speed, 3D speed, scaled by SCAL) with the
  payload's ``GPSU`` (UTC ``yymmddhhmmss.sss``), ``GPSF`` (fix) and ``GPSP`` (DOP x100);
- ``GPS9`` (HERO11 on: the same plus days since 2000, seconds since midnight, DOP and fix per
  sample);
- ``GPRI`` ("GPS RAW") of a GoPro Karma drone's own device (a MAVLink GPS_RAW_INT in a ``TYPE``
  struct: time, lat, lon, alt, eph, epv, vel, cog, fix type, satellites), with its ``SYST``
  (boot time, UNIX time) pairs for UTC. Used only when the file has no camera GPS (karma.mp4: a
  HERO5 with its GPS off, GPS from the drone);
- ``ACCL`` (m/s²) and ``GYRO`` (rad/s), 3 axes in the order the camera stores them: GPMF defines the
  axes per model (HERO5: Z,X,Y; Fusion: -Y,X,Z; HERO6: Y,-X,Z; the stream's ``STNM`` names them);
- ``CORI`` (HERO8 on): camera orientation quaternions (w, x, y, z), scaled by SCAL;
- ``ATTD`` ("Attitude") of a Karma drone's device: MAVLink ATTITUDE in a ``TYPE`` struct (boot ms,
  roll, pitch, yaw in rad, their rates): the drone's body attitude, NED axes, yaw clockwise from
  north;
- ``GLPI`` ("Position") of a Karma drone: MAVLink GLOBAL_POSITION_INT, of which the altitude (m above
  mean sea level) and the height above the take-off point are read (their difference is the
  take-off point's altitude, the ground prior; metadata.gpmf_items);
- ``CYTS`` ("Coyote Status", the Karma's gimbal): a ``TYPE`` struct whose three ``rad`` fields are
  the gimbal's angles. Their meaning is not published; on karma.mp4 the first two are 0 and the third
  is the camera's tilt from the horizon (-2.3 to +0.1 deg where the picture has the sea's horizon
  just above its middle, while the drone pitches 5 to 22 deg nose down): the gimbal levels the
  camera and follows the drone's heading (metadata.gpmf_items composes them).

Time stamps (``stamp_ns``) are on the video's clock, ns from its first frame (the Karma's streams
too: their own time fields are two boot clocks, the drone's and the gimbal's, 3 s apart on
karma.mp4): the payload's track time plus, for its n samples, ``j/n`` of its duration (samples
spread evenly over the payload). The last payload is the exception: the camera closes it when
recording stops, short, while the MP4 still gives it a full period; its samples are spread at the
rate the stream had in the payloads before. ``TIMO`` (a stream's declared delay) is subtracted.

Altitude datum depends on the source (``GpmfTrack.gps_source``), and nothing is converted here:
- ``GPS5``/``GPS9``: metres above the WGS 84 ellipsoid (GoPro's spec; its maintainer confirmed in
  gopro/gpmf-parser issue #4 that the HERO5's u-blox height above the ellipsoid is stored, not the
  receiver's mean-sea-level altitude);
- ``GPRI``: metres above mean sea level, as MAVLink defines GPS_RAW_INT.alt.

Errors: a missing file raises InputError, a file PyAV cannot open as a container MetadataError, a
file without a ``gpmd`` stream gives an empty track. A payload or KLV that is cut or inconsistent is
skipped and counted in ``GpmfTrack.skipped``.
"""
from __future__ import annotations

import calendar
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from ..errors import InputError, MetadataError

__all__ = ['GpmfTrack', 'GpsSample', 'read_gpmf']


@dataclass(frozen=True)
class GpsSample:
    """One GPS fix: WGS 84 degrees, altitude in metres (datum: see GpmfTrack.gps_source), 2D ground
    speed in m/s, fix 0 none / 2 2D / 3 3D, dop unitless (GPSP/100; Karma: GPRI eph, which MAVLink
    calls HDOP x100), utc_ns since 1970 (GPSU plus the offset within the payload; GPS9's own time;
    Karma: its boot clock through SYST) or None.
    """

    stamp_ns: int
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    speed_2d_m_s: float
    fix: int
    dop: float
    utc_ns: int | None


@dataclass
class GpmfTrack:
    """A file's GPMF telemetry; each sensor list is (stamp_ns, values) in time order.

    ``gps_source`` names the KLV the fixes come from, which fixes their altitude datum (see the
    module docstring). ``device`` joins the DVNM of every device in order of appearance (karma.mp4: 'Camera, GoPro
    Karma v1.0'); ``payloads`` counts the gpmd track's samples; ``skipped`` counts, by reason,
    what was dropped: 'payload_truncated' (a KLV runs past its payload: the rest of it),
    'bad_klv' (a size or TYPE that does not fit), 'gps_zero_position' (0/0 before a lock),
    'gps_out_of_range'.
    """

    gps: list[GpsSample] = field(default_factory=list)
    accel: list[tuple[int, tuple[float, float, float]]] = field(default_factory=list)
    gyro: list[tuple[int, tuple[float, float, float]]] = field(default_factory=list)
    orientation: list[tuple[int, tuple[float, float, float, float]]] = field(default_factory=list)
    platform_attitude: list[tuple[int, tuple[float, float, float]]] = field(default_factory=list)  # ATTD (rad)
    gimbal_angles: list[tuple[int, tuple[float, float, float]]] = field(default_factory=list)  # CYTS (rad)
    heights: list[tuple[int, tuple[float, float]]] = field(default_factory=list)  # GLPI (m MSL, m above take-off)
    device: str = ''
    payloads: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    gps_source: str = ''  # 'GPS5' | 'GPS9' (ellipsoid heights) | 'GPRI' (MSL) | '' (no GPS)


# Size in bytes and big-endian numpy dtype of GPMF's basic types (spec, "Type Char" table).
_SIZES = {'b': 1, 'B': 1, 'c': 1, 'd': 8, 'f': 4, 'F': 4, 'G': 16, 'j': 8, 'J': 8, 'l': 4, 'L': 4,
          'q': 4, 'Q': 8, 's': 2, 'S': 2, 'U': 16}
_DTYPES = {'b': '>i1', 'B': '>u1', 'd': '>f8', 'f': '>f4', 'j': '>i8', 'J': '>u8', 'l': '>i4', 'L': '>u4',
           'q': '>i4', 'Q': '>i8', 's': '>i2', 'S': '>u2'}
_FIXED_POINT = {'q': 65536.0, 'Q': 4294967296.0}  # Q15.16 and Q31.32
_SENSORS = ('GPS5', 'GPS9', 'GPRI', 'SYST', 'ACCL', 'GYRO', 'CORI', 'ATTD', 'CYTS', 'GLPI')
#: The Karma's MAVLink-like structs: columns of (roll, pitch, yaw) in ATTD, of the angles in CYTS,
#: of (altitude, relative altitude) in GLPI.
_KARMA_COLUMNS = {'ATTD': slice(1, 4), 'CYTS': slice(5, 8), 'GLPI': slice(3, 5)}
_DAYS_2000_NS = calendar.timegm((2000, 1, 1, 0, 0, 0, 0, 0, 0)) * 1_000_000_000


class _Truncated(Exception):
    """A KLV runs past the end of its parent: the rest of that parent is unusable."""


def read_gpmf(path: str | Path) -> GpmfTrack:
    """Read the GPMF track of a GoPro MP4/MOV (an empty GpmfTrack when it has none)."""
    path = Path(path)
    if not path.is_file():
        msg = f'GoPro video {path} does not exist.'
        raise InputError(msg)
    try:
        container = av.open(str(path))
    except av.FFmpegError as exc:
        msg = f'GoPro video {path} cannot be opened as a video container ({exc}); check that the file is complete.'
        raise MetadataError(msg) from None
    with container:
        payloads, origin_ns = _demux_gpmd(container, path)
    track = GpmfTrack(payloads=len(payloads))
    if not payloads:
        return track
    streams = _decode_payloads(payloads, track)
    _assemble(streams, payloads, origin_ns, track)
    return track


def _demux_gpmd(container: av.container.InputContainer, path: Path) -> tuple[list[tuple[int, int, bytes]], int]:
    """[(start_ns, duration_ns, payload)] of the gpmd stream, and the first video frame's time in ns."""
    data = [s for s in container.streams if s.type == 'data']
    video = next((s for s in container.streams if s.type == 'video'), None)
    origin_ns = 0
    if video is not None and video.start_time is not None:
        origin_ns = _to_ns(video.start_time, video.time_base)
    if not data:
        return [], origin_ns
    discard = getattr(getattr(av, 'stream', None), 'Discard', None)
    for s in container.streams:
        if s.type != 'data' and discard is not None:
            s.discard = discard.all  # only the data tracks are read: no video bytes pulled through
    packets: dict[int, list[tuple[int, int, bytes]]] = {s.index: [] for s in data}
    try:
        for packet in container.demux(*data):
            if packet.size == 0 or packet.pts is None:
                continue
            tb = packet.time_base or packet.stream.time_base
            packets[packet.stream.index].append(
                (_to_ns(packet.pts, tb), _to_ns(packet.duration or 0, tb), bytes(packet)))
    except av.FFmpegError as exc:
        msg = f'GoPro video {path}: its data tracks cannot be read ({exc}); the file is probably cut short.'
        raise MetadataError(msg) from None
    # GoPro's "GoPro MET" track holds GPMF; the SOS (fdsc) and TCD (timecode) tracks do not. A GPMF
    # payload always opens with a DEVC, so the first payload decides, whatever the handler name says.
    for s in data:
        got = packets[s.index]
        if got and got[0][2][:4] == b'DEVC':
            got.sort(key=lambda p: p[0])
            return _fill_durations(got), origin_ns
    return [], origin_ns


def _fill_durations(payloads: list[tuple[int, int, bytes]]) -> list[tuple[int, int, bytes]]:
    """A payload without a duration lasts until the next one starts (the last: as long as the one before)."""
    out = []
    for i, (start, duration, data) in enumerate(payloads):
        if duration <= 0:
            if i + 1 < len(payloads):
                duration = payloads[i + 1][0] - start
            elif out:
                duration = out[-1][1]
        out.append((start, max(duration, 0), data))
    return out


def _to_ns(value: int, time_base: Fraction | None) -> int:
    return round(Fraction(value) * Fraction(time_base or 0) * 1_000_000_000)


@dataclass
class _Block:
    """One data KLV of one payload, decoded: rows of scaled values and what the stream said about it."""

    payload: int
    rows: np.ndarray  # (n, elements) float64
    timo_s: float
    extras: dict[str, object]


def _decode_payloads(payloads: list[tuple[int, int, bytes]], track: GpmfTrack) -> dict[str, list[_Block]]:
    streams: dict[str, list[_Block]] = {key: [] for key in _SENSORS}
    devices: list[str] = []
    for i, (_, _, payload) in enumerate(payloads):
        try:
            for key, _t, _ss, _rep, body in _klv(payload):
                if key != 'DEVC':
                    continue
                for dkey, dtype, _dss, _drep, dbody in _klv(body):
                    if dkey == 'DVNM' and dtype == ord('c'):
                        name = _text(dbody)
                        if name and name not in devices:
                            devices.append(name)
                    elif dkey == 'STRM' and dtype == 0:
                        _decode_stream(i, dbody, streams, track)
        except _Truncated:
            _count(track, 'payload_truncated')
    track.device = ', '.join(devices)
    return streams


def _decode_stream(i: int, body: bytes, streams: dict[str, list[_Block]], track: GpmfTrack) -> None:
    scal: np.ndarray | None = None
    types: str | None = None
    timo = 0.0
    extras: dict[str, object] = {}
    for key, t, ss, rep, value in _klv(body):
        ch = chr(t) if t else ''
        try:
            if key == 'SCAL':
                scal = _numbers(ch, ss, rep, value).reshape(-1)
            elif key == 'TYPE' and ch == 'c':
                types = _expand_type(_text(value))
            elif key == 'TIMO':
                timo = float(_numbers(ch, ss, rep, value).reshape(-1)[0])
            elif key == 'GPSU' and ch in 'Uc':
                extras['gpsu_ns'] = _gpsu_ns(value)
            elif key == 'GPSF':
                extras['fix'] = int(_numbers(ch, ss, rep, value).reshape(-1)[0])
            elif key == 'GPSP':
                extras['dop'] = float(_numbers(ch, ss, rep, value).reshape(-1)[0]) / 100.0
            elif key in _SENSORS:
                if ch == '?':
                    if types is None:
                        _count(track, 'bad_klv')
                        continue
                    rows = _structs(types, ss, rep, value)
                else:
                    rows = _numbers(ch, ss, rep, value)
                streams[key].append(_Block(i, _scaled(rows, scal), timo, dict(extras)))
        except (ValueError, struct.error, IndexError):
            _count(track, 'bad_klv')  # a size that does not fit its type, an unknown type...


def _klv(buf: bytes) -> Iterator[tuple[str, int, int, int, bytes]]:
    """(key, type, struct size, repeat, value bytes) of each KLV in buf; _Truncated when one is cut."""
    off = 0
    end = len(buf)
    while off + 8 <= end:
        key = buf[off:off + 4]
        if key == b'\x00\x00\x00\x00':
            return  # zero padding after the last KLV
        t, ss, rep = buf[off + 4], buf[off + 5], struct.unpack_from('>H', buf, off + 6)[0]
        n = ss * rep
        if off + 8 + n > end:
            raise _Truncated
        yield key.decode('latin-1'), t, ss, rep, buf[off + 8:off + 8 + n]
        off += 8 + ((n + 3) & ~3)


def _numbers(ch: str, ss: int, rep: int, value: bytes) -> np.ndarray:
    """A basic-typed KLV as a (rep, ss/size) float64 array."""
    if ch not in _DTYPES:
        raise ValueError(ch)
    size = _SIZES[ch]
    if ss % size or ss == 0:
        raise ValueError(ss)
    if rep == 0:
        return np.zeros((0, ss // size))
    out = np.frombuffer(value, dtype=_DTYPES[ch], count=rep * ss // size).astype(np.float64)
    if ch in _FIXED_POINT:
        out /= _FIXED_POINT[ch]
    return out.reshape(rep, ss // size)


def _expand_type(text: str) -> str:
    """'f[8]L' -> 'ffffffffL' (the spec's array notation in TYPE strings)."""
    out: list[str] = []
    i = 0
    while i < len(text):
        ch = text[i]
        if i + 1 < len(text) and text[i + 1] == '[':
            close = text.index(']', i)
            out.append(ch * int(text[i + 2:close]))
            i = close + 1
        else:
            out.append(ch)
            i += 1
    return ''.join(out)


def _structs(types: str, ss: int, rep: int, value: bytes) -> np.ndarray:
    """A '?' KLV whose TYPE is ``types``: (rep, len(types)) float64 (strings and ids as NaN)."""
    layout = []
    offset = 0
    for ch in types:
        layout.append((ch, offset))
        offset += _SIZES[ch]
    if offset != ss:
        raise ValueError(types)
    out = np.full((rep, len(types)), math.nan)
    if rep == 0:
        return out  # an empty KLV keeps the stream's timing: no samples in this payload
    for k, (ch, off) in enumerate(layout):
        if ch not in _DTYPES:
            continue
        column = np.ndarray((rep,), dtype=_DTYPES[ch], buffer=value, offset=off, strides=(ss,))
        out[:, k] = column.astype(np.float64) / _FIXED_POINT.get(ch, 1.0)
    return out


def _scaled(rows: np.ndarray, scal: np.ndarray | None) -> np.ndarray:
    """SCAL is a divisor: one for all elements, or one per element."""
    if scal is None or scal.size == 0:
        return rows
    if scal.size == 1 or scal.size == rows.shape[1]:
        with np.errstate(divide='ignore', invalid='ignore'):
            return rows / (scal if scal.size > 1 else scal[0])
    raise ValueError(scal.size)


def _text(value: bytes) -> str:
    return value.split(b'\x00', 1)[0].decode('latin-1').strip()


def _gpsu_ns(value: bytes) -> int | None:
    """GPSU 'yymmddhhmmss.sss' (UTC, years 20xx) -> ns since 1970, or None when malformed."""
    text = _text(value)
    try:
        yy, mo, dd, hh, mi = (int(text[k:k + 2]) for k in range(0, 10, 2))
        seconds = float(text[10:])
        whole = calendar.timegm((2000 + yy, mo, dd, hh, mi, 0, 0, 0, 0))
    except (ValueError, OverflowError):
        return None
    if not (1 <= mo <= 12 and 1 <= dd <= 31 and hh < 24 and mi < 60 and 0.0 <= seconds < 61.0):
        return None
    return whole * 1_000_000_000 + round(seconds * 1e9)


def _count(track: GpmfTrack, reason: str, n: int = 1) -> None:
    track.skipped[reason] = track.skipped.get(reason, 0) + n


def _stamps(blocks: list[_Block], payloads: list[tuple[int, int, bytes]], origin_ns: int) -> list[np.ndarray]:
    """Stamps (ns, video clock) of each block's rows: spread over the payload, see the module docstring."""
    last = len(payloads) - 1
    full = [b for b in blocks if b.payload != last and len(b.rows)]
    rate_hz = (sum(len(b.rows) for b in full) * 1e9 / sum(payloads[b.payload][1] for b in full)
               if full and sum(payloads[b.payload][1] for b in full) > 0 else 0.0)
    out = []
    for b in blocks:
        start_ns, duration_ns, _ = payloads[b.payload]
        n = len(b.rows)
        period_ns = duration_ns / n if n else 0.0
        if b.payload == last and rate_hz > 0.0:
            period_ns = 1e9 / rate_hz  # the closing payload is short though the MP4 gives it a full period
        out.append(np.rint(start_ns - origin_ns - b.timo_s * 1e9 + period_ns * np.arange(n)).astype(np.int64))
    return out


def _assemble(streams: dict[str, list[_Block]], payloads: list[tuple[int, int, bytes]], origin_ns: int,
              track: GpmfTrack) -> None:
    for key, target in (('ACCL', track.accel), ('GYRO', track.gyro)):
        blocks = streams[key]
        for b, stamps in zip(blocks, _stamps(blocks, payloads, origin_ns)):
            if b.rows.shape[1] != 3:
                _count(track, 'bad_klv')
                continue
            target.extend((int(s), (float(r[0]), float(r[1]), float(r[2]))) for s, r in zip(stamps, b.rows))
    blocks = streams['CORI']
    for b, stamps in zip(blocks, _stamps(blocks, payloads, origin_ns)):
        if b.rows.shape[1] != 4:
            _count(track, 'bad_klv')
            continue
        track.orientation.extend((int(s), (float(r[0]), float(r[1]), float(r[2]), float(r[3])))
                                 for s, r in zip(stamps, b.rows))
    for key, target in (('ATTD', track.platform_attitude), ('CYTS', track.gimbal_angles), ('GLPI', track.heights)):
        blocks, cols = streams[key], _KARMA_COLUMNS[key]
        for b, stamps in zip(blocks, _stamps(blocks, payloads, origin_ns)):
            if b.rows.shape[1] < cols.stop:
                _count(track, 'bad_klv')
                continue
            target.extend((int(s), tuple(float(v) for v in r)) for s, r in zip(stamps, b.rows[:, cols])
                          if np.all(np.isfinite(r)))
    # One receiver only: the camera's when it has one, else the Karma drone's.
    for key in ('GPS9', 'GPS5', 'GPRI'):
        if any(len(b.rows) for b in streams[key]):
            _gps(key, streams[key], _stamps(streams[key], payloads, origin_ns), streams['SYST'], track)
            track.gps_source = key
            break
    for seq in (track.accel, track.gyro, track.orientation, track.platform_attitude, track.gimbal_angles,
                track.heights):
        seq.sort(key=lambda item: item[0])
    track.gps.sort(key=lambda g: g.stamp_ns)


def _gps(key: str, blocks: list[_Block], stamps: list[np.ndarray], syst_blocks: list[_Block],
         track: GpmfTrack) -> None:
    need = {'GPS5': 5, 'GPS9': 9, 'GPRI': 10}[key]
    for b, st in zip(blocks, stamps):
        if b.rows.shape[1] < need:
            _count(track, 'bad_klv')
            continue
        # Karma: the latest (boot s, UNIX s) pair written up to this payload maps its boot clock to UTC
        syst = next((s.rows[-1] for s in reversed(syst_blocks)
                     if s.payload <= b.payload and len(s.rows) and s.rows.shape[1] == 2), None)
        for stamp, r in zip(st, b.rows):
            lat, lon = (float(r[1]), float(r[2])) if key == 'GPRI' else (float(r[0]), float(r[1]))
            if not (math.isfinite(lat) and math.isfinite(lon)) or (lat == 0.0 and lon == 0.0):
                _count(track, 'gps_zero_position')
                continue
            if abs(lat) > 90.0 or abs(lon) > 180.0:
                _count(track, 'gps_out_of_range')
                continue
            if key == 'GPS5':
                gpsu = b.extras.get('gpsu_ns')
                utc = None if gpsu is None else int(gpsu) + int(stamp - st[0])  # GPSU dates the payload's first fix
                sample = GpsSample(int(stamp), lat, lon, float(r[2]), float(r[3]), int(b.extras.get('fix', 0)),
                                   float(b.extras.get('dop', math.nan)), utc)
            elif key == 'GPS9':
                utc = _DAYS_2000_NS + round(float(r[5]) * 86400e9 + float(r[6]) * 1e9)
                sample = GpsSample(int(stamp), lat, lon, float(r[2]), float(r[3]), _fix(r[8]), float(r[7]), utc)
            else:
                utc = None if syst is None else round(float(syst[1]) * 1e9) + round((float(r[0]) - float(syst[0])) * 1e9)
                sample = GpsSample(int(stamp), lat, lon, float(r[3]), float(r[6]), _fix(r[8]), float(r[4]), utc)
            track.gps.append(sample)


def _fix(value: float) -> int:
    """MAVLink/GPS9 fix type -> 0 none, 2 2D, 3 3D (DGPS and RTK fixes are 3D fixes)."""
    if not math.isfinite(value) or value < 2:
        return 0
    return 2 if value < 3 else 3
