"""DJI subtitle telemetry (.SRT beside a video) -> time-ordered position and attitude samples.

Each subtitle block is ``index``, ``HH:MM:SS,mmm --> HH:MM:SS,mmm`` (the span of video it
covers) and one or more lines of telemetry whose layout depends on the aircraft and firmware.
The generations read here (``SrtTrack.format``):

- ``old_gps_lon_lat`` (early Mavic Pro): ``HOME(lon,lat) 2017.8.5 14:11:51`` /
  ``GPS(lon,lat,sats) Hb:1.9 Hs:1.9`` / ``ISO:100 TV:60 EV: 0 IR:F2.8``;
- ``mavic_pro_2017``: the same with ``BAROMETER:1.9`` and ``Shutter:60 Fnum:2.2``;
- ``m300`` (Matrice 300): a date line, ``GPS(lat,lon,0.0M) BAROMETER:0.3M``: latitude FIRST here,
  and the third value is an altitude in metres (its ``M``), not a satellite count;
- ``p4p_mini`` (Phantom 4 Pro, Mavic Mini): one line ``F/2.8, SS 30.15, ISO 260, EV -1.7,
  GPS (lon, lat, sats), D 221.21m, H 200.70m, H.S n/a, V.S n/a``;
- ``p4rtk`` (Phantom 4 RTK): that line plus ``HOME (lon, lat, alt m)``,
  ``F.PRY (pitch°, roll°, yaw°)`` (aircraft) and ``G.PRY (pitch°, roll°, yaw°)`` (gimbal);
- ``mavic2`` (Mavic 2 Pro/Zoom, Mavic Air): ``<font>FrameCnt : 1, DiffTime : 40ms``, a date
  ``2020-04-02 15:19:58,720,764`` (ms,µs), ``[iso : 120] [shutter : 1/2500.0] [fnum : 280]
  [ev : 0] [ct : 5003] [color_md : default] [focal_len : 240] [latitude : ..]
  [longtitude : ..] [altitude: ..]`` (sic "longtitude");
- ``air2`` (Air 2, Air 2S): ``SrtCnt : 1`` and ``[latitude: ..] [longitude: ..] [altitude: ..]``;
- ``mavic3`` (Mavic 3 and later): ``FrameCnt: 1``, a date ``2021-12-25 12:27:52.373``,
  ``[focal_len: 24.00] [latitude: ..] [longitude: ..] [rel_alt: -2.400 abs_alt: 0.401]``, and on
  some models ``[gb_yaw: .. gb_pitch: .. gb_roll: ..]`` or ``[Drone: Yaw:.., Pitch:.., Roll:..]``.
A file mixing generations (clips joined by an editor) is read block by block; its ``format`` joins
the names with ``+`` in order of appearance.

Conventions:
- ``GPS(a,b,c)`` without a unit on ``c`` is (longitude, latitude, satellites): ``c`` is an
  integer 3..19 that never follows the barometer (DJI_SRT_Parser reads it as SATELLITES too); it
  goes to ``extra['satellites']``, never into an altitude;
- ``altitude_m`` is the best absolute altitude the block has, in metres: ``abs_alt``, else
  ``[altitude: ..]``, else the ``m300`` GPS altitude. DJI documents no datum for any of them
  (read them as height above mean sea level, not WGS84 ellipsoid, at your own risk). The ``m300``
  GPS altitude is exactly ``0.0M`` in every block while its barometer climbs: a placeholder,
  read as absent (NaN), its raw text kept in ``extra['gps_altitude']``;
- ``relative_altitude_m``: height above the take-off point: ``rel_alt``, ``H``, ``BAROMETER`` or
  ``Hb`` (barometric height; ``Hs`` stays in extra);
- angles are degrees as written: yaw clockwise from north in -180..180, pitch -90 = nadir;
  ``gimbal_ypr_deg`` / ``flight_ypr_deg`` are reordered to (yaw, pitch, roll) from ``G.PRY`` /
  ``F.PRY`` (pitch, roll, yaw), ``gb_yaw/gb_pitch/gb_roll`` and ``[Gimbal: ..]`` /
  ``[Drone: ..]`` brackets;
- ``focal_length_mm`` is the 35 mm-equivalent focal length DJI writes: ``[focal_len : 240]``
  (integer, no decimal point: tenths of a millimetre) is 24.0 mm, ``[focal_len: 24.00]`` is
  24.0 mm;
- the date-time line is the aircraft's local wall clock WITHOUT a time zone; ``utc_ns`` is that
  reading taken as if it were UTC (naive): add the zone offset yourself when you know it.
Everything else a block says (iso, shutter, fnum, ev, ct, color_md, satellites, home, distance,
speeds, frame_cnt, diff_time...) is kept raw, as text, in ``SrtSample.extra`` under lower-case
keys (aliases folded: ``TV``/``SS`` -> shutter, ``IR``/``F/`` -> fnum, ``longtitude`` -> longitude).

Records: a block without a position, with a malformed time, at (0, 0) (GPS not locked yet), out of
range, at the same start time as the one before (duplicate) or earlier than it (out of order) is
skipped and counted in ``SrtTrack.skipped`` by reason; so is a chunk of text between blank lines
that starts no block (``no_timing``: garbage where a block was, never glued to the block before), so
that ``blocks`` = len(samples) + sum(skipped). A file with no usable block at all raises
:class:`MetadataError`. :func:`time_mismatch` says when a track does not cover the video it sits
beside (an .SRT of another video).
"""
from __future__ import annotations

import calendar
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError, MetadataError

__all__ = ['SrtSample', 'SrtTrack', 'find_srt', 'read_srt', 'time_mismatch']


@dataclass(frozen=True)
class SrtSample:
    """One subtitle block's telemetry (units in the field names; NaN/None when the block lacks it)."""

    index: int
    start_ns: int
    end_ns: int
    utc_ns: int | None
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    relative_altitude_m: float
    gimbal_ypr_deg: tuple[float, float, float] | None
    flight_ypr_deg: tuple[float, float, float] | None
    focal_length_mm: float | None
    extra: dict[str, str] = field(default_factory=dict)


@dataclass
class SrtTrack:
    """A parsed .SRT: good samples in time order and what was skipped (reason -> count)."""

    path: Path
    samples: list[SrtSample]
    blocks: int
    skipped: dict[str, int]
    format: str


# Subtitle timing; some firmware writes more than three digits of milliseconds (read as an integer).
_TIMING = re.compile(r'^\s*(\d+):(\d{1,2}):(\d{1,2})[,.](\d{1,4})\s*-->\s*(\d+):(\d{1,2}):(\d{1,2})[,.](\d{1,4})\s*$')
_DATETIME = re.compile(
    r'(?<!\d)(\d{4})[-./](\d{1,2})[-./](\d{1,2})[ T]+(\d{1,2}):(\d{2}):(\d{2})(?:[.,](\d{1,3})(?:,(\d{1,3}))?)?(?![\d])')
_COUNTERS = re.compile(r'\b(FrameCnt|SrtCnt)\s*:\s*(\d+)\s*,?\s*(?:DiffTime\s*:\s*([\d.]+\s*ms))?', re.IGNORECASE)
_TAG = re.compile(r'<[^<>]*>')
_PAREN = re.compile(r'\b([A-Za-z][A-Za-z.]*)\s*\(([^()]*)\)')
_BRACKET = re.compile(r'\[([^\[\]]*)\]')
_BRACKET_GROUP = re.compile(r'^\s*([A-Za-z]\w*)\s*:\s*(?=[A-Za-z]\w*\s*:)')  # "[Drone: Yaw:1, ...]"
_PAIR = re.compile(r'([A-Za-z_][\w.]*)\s*:\s*([^\s,:\[\]]*)(?=[\s,\]]|$)')
_INLINE = re.compile(r'^([A-Za-z][A-Za-z.]*)\s+(\S+)$')
_NUMBER = re.compile(r'^[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?')

# Key spellings of the generations -> one lower-case name.
_ALIASES = {
    'longtitude': 'longitude', 'tv': 'shutter', 'ss': 'shutter', 'ir': 'fnum', 'f': 'fnum',
    'framecnt': 'frame_cnt', 'srtcnt': 'frame_cnt', 'difftime': 'diff_time', 'd': 'distance',
    'h.s': 'h_speed', 'v.s': 'v_speed',
}
_SRT_SUFFIX = '.srt'


def read_srt(path: str | Path) -> SrtTrack:
    """Parse a DJI .SRT (any generation above) into an SrtTrack.

    Raises InputError when the file is missing or unreadable and MetadataError when nothing
    usable is in it: empty, no subtitle timing lines, or no block with a position.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        msg = f'DJI SRT {path} does not exist.'
        raise InputError(msg) from None
    except OSError as exc:
        msg = f'DJI SRT {path} cannot be read ({exc.strerror}).'
        raise InputError(msg) from None
    # utf-8-sig drops the BOM some firmware writes; a stray byte must not sink the whole file.
    text = raw.decode('utf-8-sig', errors='replace')
    lines = text.replace('\r\n', '\n').replace('\r', '\n').split('\n')
    if not text.strip():
        msg = (f'DJI SRT {path} is empty ({len(raw)} bytes): it holds no telemetry. Copy it again from the '
               "aircraft's card, or georeference the video from another source such as a flight-log CSV (--telemetry).")
        raise MetadataError(msg)

    blocks, stray = _split_blocks(lines)
    if not blocks:
        msg = (f'DJI SRT {path} has no subtitle timing lines ("00:00:01,000 --> 00:00:02,000") in its {len(lines)} '
               'lines, so no sample can be placed on the video clock: it is not a subtitle file as the aircraft '
               'writes it (edited or converted?). Use the .SRT the drone recorded beside the video.')
        raise MetadataError(msg)

    skipped: dict[str, int] = {'no_timing': stray} if stray else {}
    formats: list[str] = []
    samples: list[SrtSample] = []
    for index, timing, body in blocks:
        sample, generation, reason = _parse_block(index, timing, body)
        if generation not in formats and generation != 'unknown':
            formats.append(generation)
        if reason is None and samples:
            if sample.start_ns == samples[-1].start_ns:
                reason = 'duplicate'
            elif sample.start_ns < samples[-1].start_ns:
                reason = 'out_of_order'
        if reason is not None:
            skipped[reason] = skipped.get(reason, 0) + 1
            continue
        samples.append(sample)

    if not samples:
        why = ', '.join(f'{k}: {v}' for k, v in sorted(skipped.items()))
        msg = (f'DJI SRT {path}: none of its {len(blocks) + stray} subtitle blocks has a usable position ({why}; format '
               f'{"+".join(formats) or "unknown"}). The aircraft wrote no GPS (not locked, or a model/setting that omits it): '
               'georeference this video from another source such as a flight-log CSV (--telemetry).')
        raise MetadataError(msg)
    return SrtTrack(path=path, samples=samples, blocks=len(blocks) + stray, skipped=skipped,
                    format='+'.join(formats) or 'unknown')


#: A track covering less than this fraction of its video's duration is said to (used all the same).
SRT_MIN_COVERAGE = 0.5


def time_mismatch(track: SrtTrack, duration_s: float) -> tuple[bool, str]:
    """(whether the track is of no use to the video, a sentence naming the file; '' when it fits) for
    a track beside a video of ``duration_s`` seconds: subtitle times count from the video's start, so
    a track that starts after the video ends belongs to another video; one that covers less than
    SRT_MIN_COVERAGE of it is said (its positions are used where it has them)."""
    if not track.samples or not math.isfinite(duration_s) or duration_s <= 0.0:
        return False, ''
    first = track.samples[0].start_ns / 1e9
    last = max(max(s.start_ns, s.end_ns) for s in track.samples) / 1e9
    span = f'{first:.1f} to {last:.1f} s'
    if first >= duration_s:
        return True, (f'DJI SRT {track.path.name} covers {span} of the video clock, but the video lasts {duration_s:.1f} s: '
                      'the two do not overlap in time (an .SRT of another video?), so it is not used. Put the .SRT '
                      'recorded with this video beside it, or give a flight log with --telemetry.')
    covered = min(last, duration_s) - max(first, 0.0)
    if covered < SRT_MIN_COVERAGE * duration_s:
        return False, (f'DJI SRT {track.path.name} covers {span} of the video clock, {max(covered, 0.0):.1f} of the '
                       f'video\'s {duration_s:.1f} s: the frames outside it have no telemetry.')
    return False, ''


def find_srt(video_path: str | Path) -> Path | None:
    """The .SRT/.srt beside ``video_path`` with the same stem (extension in any case), or None.

    An exact stem wins over one that differs only in case (DJI_0001.SRT beside dji_0001.mp4 after a
    copy through a case-folding file system); among equals, the sorted first.
    """
    video = Path(video_path)
    try:
        candidates = sorted(p for p in video.parent.iterdir() if p.suffix.lower() == _SRT_SUFFIX and p.is_file())
    except OSError:
        return None
    for same in (lambda p: p.stem == video.stem, lambda p: p.stem.lower() == video.stem.lower()):
        hits = [p for p in candidates if same(p)]
        if hits:
            return hits[0]
    return None


def _split_blocks(lines: list[str]) -> tuple[list[tuple[int, str, list[str]]], int]:
    """((index, timing line, body lines) per block, chunks that start no block).

    A block starts at a timing line ('-->'), after its integer index line when it has one. After the
    first block, a chunk of lines between blank lines that starts no block is garbage where a block
    was (DJI writes no blank line inside a block): counted, and not glued to the block before.
    """
    blocks: list[tuple[int, str, list[str]]] = []
    stray = 0
    in_stray = after_blank = False  # in_stray: in a chunk that has started no block (yet)
    for i, raw in enumerate(lines):
        line = raw.strip()
        if not line:
            stray += in_stray
            in_stray, after_blank = False, True
            continue
        if '-->' in line:  # a block; its index line, the one before, is read when it is an integer
            before = lines[i - 1].strip() if i else ''
            index = int(before) if before.isdigit() else (blocks[-1][0] + 1 if blocks else 1)
            blocks.append((index, raw, []))
            in_stray = after_blank = False
            continue
        if blocks and after_blank:
            in_stray = True
        if blocks and not in_stray and not (line.isdigit() and i + 1 < len(lines) and '-->' in lines[i + 1]):
            blocks[-1][2].append(line)
        after_blank = False
    stray += in_stray
    return blocks, stray


def _parse_block(index: int, timing: str, body: list[str]) -> tuple[SrtSample, str, str | None]:
    """One block -> (sample, generation name, skip reason or None)."""
    fields = _fields(body)
    generation = _generation(fields)
    nan = math.nan
    t = _TIMING.match(timing)
    start_ns = end_ns = 0
    reason: str | None = None
    if t is None:
        reason = 'malformed_time'
    else:
        g = [int(x) for x in t.groups()]
        start_ns = ((g[0] * 3600 + g[1] * 60 + g[2]) * 1000 + g[3]) * 1_000_000
        end_ns = ((g[4] * 3600 + g[5] * 60 + g[6]) * 1000 + g[7]) * 1_000_000
        # Matrice 300 firmware ends each minute's block at "00:00:60,000": the carry it means, so
        # 60 is accepted; anything past it is not a time.
        if max(g[1], g[5]) > 59 or max(g[2], g[6]) > 60 or end_ns < start_ns:
            reason = 'malformed_time'

    extra = dict(fields.extra)
    lat, lon, alt_gps = fields.latitude, fields.longitude, nan
    gps = fields.paren.get('gps')
    if gps is not None and not (math.isfinite(lat) and math.isfinite(lon)):
        lat, lon, alt_gps = _gps_triple(gps, extra)
    if reason is None:
        if not (math.isfinite(lat) and math.isfinite(lon)):
            reason = 'no_gps'
        elif lat == 0.0 and lon == 0.0:
            reason = 'zero_position'
        elif abs(lat) > 90.0 or abs(lon) > 180.0:
            reason = 'out_of_range'

    altitude = _first_finite(fields.number('abs_alt'), fields.number('altitude'), alt_gps)
    relative = _first_finite(fields.number('rel_alt'), fields.number('h'), fields.number('barometer'),
                             fields.number('hb'))
    sample = SrtSample(
        index=index, start_ns=start_ns, end_ns=end_ns, utc_ns=fields.utc_ns,
        latitude_deg=lat, longitude_deg=lon, altitude_m=altitude, relative_altitude_m=relative,
        gimbal_ypr_deg=_ypr(fields, 'g.pry', ('gb_yaw', 'gb_pitch', 'gb_roll'), 'gimbal'),
        flight_ypr_deg=_ypr(fields, 'f.pry', ('drone_yaw', 'drone_pitch', 'drone_roll'), 'drone'),
        focal_length_mm=_focal_mm(fields.values.get('focal_len')),
        extra=extra)
    return sample, generation, reason


@dataclass
class _Fields:
    """What a block says, before interpretation: raw values by canonical key."""

    values: dict[str, str]
    paren: dict[str, list[str]]
    utc_ns: int | None
    extra: dict[str, str]
    has_brackets: bool
    spellings: set[str]
    latitude: float = math.nan
    longitude: float = math.nan

    def number(self, key: str) -> float:
        return _to_float(self.values.get(key))


# Keys that become typed SrtSample fields (everything else read goes to extra, raw).
_TYPED = {'latitude', 'longitude', 'abs_alt', 'altitude', 'rel_alt', 'h', 'barometer', 'hb',
          'gb_yaw', 'gb_pitch', 'gb_roll', 'drone_yaw', 'drone_pitch', 'drone_roll',
          'gimbal_yaw', 'gimbal_pitch', 'gimbal_roll'}


def _fields(body: list[str]) -> _Fields:
    text = ' '.join(_TAG.sub(' ', line) for line in body)
    values: dict[str, str] = {}
    utc_ns = None
    m = _DATETIME.search(text)
    if m is not None:
        utc_ns = _naive_ns(m)
        values['datetime'] = m.group(0)
        text = text[:m.start()] + ' ' + text[m.end():]  # its HH:MM:SS must not read as key:value pairs
    for m in _COUNTERS.finditer(text):
        values['frame_cnt'] = m.group(2)
        if m.group(3):
            values['diff_time'] = m.group(3).replace(' ', '')
    text = _COUNTERS.sub(' ', text)

    paren: dict[str, list[str]] = {}
    for m in _PAREN.finditer(text):
        paren[m.group(1).lower()] = [v.strip() for v in m.group(2).split(',')]
    text = _PAREN.sub(' ', text)

    has_brackets = False
    spellings: set[str] = set()
    for m in _BRACKET.finditer(text):
        has_brackets = True
        inner = m.group(1)
        prefix = ''
        g = _BRACKET_GROUP.match(inner)
        if g is not None:
            prefix = g.group(1).lower() + '_'
            inner = inner[g.end():]
        for key, value in _PAIR.findall(inner):
            spellings.add(key.lower())
            values[_canonical(prefix + key)] = value
    text = _BRACKET.sub(' ', text)

    # What is left: "ISO:100 Shutter:60 EV: Fnum:2.2" pairs or "F/2.8, SS 30.15, ISO 260" items.
    for item in text.split(','):
        item = item.strip()
        if not item:
            continue
        pairs = _PAIR.findall(item)
        if pairs:
            for key, value in pairs:
                values[_canonical(key)] = value
            continue
        if item.startswith('F/'):
            values['fnum'] = item[2:].strip()
            continue
        m = _INLINE.match(item)
        if m is not None:
            values[_canonical(m.group(1))] = m.group(2)

    extra = {k: v for k, v in values.items() if k not in _TYPED}
    for key in ('home', 'f.pry', 'g.pry'):
        if key in paren:
            extra[key] = ', '.join(paren[key])
    out = _Fields(values=values, paren=paren, utc_ns=utc_ns, extra=extra, has_brackets=has_brackets,
                  spellings=spellings)
    out.latitude = _to_float(values.get('latitude'))
    out.longitude = _to_float(values.get('longitude'))
    return out


def _canonical(key: str) -> str:
    key = key.strip().lower().replace(' ', '')
    return _ALIASES.get(key, key)


def _generation(f: _Fields) -> str:
    """Name of the format generation a block is written in (see the module docstring)."""
    v, p = f.values, f.paren
    if 'f.pry' in p or 'g.pry' in p:
        return 'p4rtk'
    if 'gps' in p:
        third = p['gps'][2] if len(p['gps']) > 2 else ''
        if third[-1:] in ('M', 'm'):
            return 'm300'
        if 'hb' in v or 'hs' in v:
            return 'old_gps_lon_lat'
        if 'barometer' in v or 'home' in p:
            return 'mavic_pro_2017'
        return 'p4p_mini'
    if 'home' in p:
        return 'mavic_pro_2017'  # a block cut after its first line
    if 'rel_alt' in v or 'abs_alt' in v or 'gb_yaw' in v:
        return 'mavic3'
    if f.has_brackets:
        # Mavic 2 firmware spells "longtitude"; the Air 2 generation fixed it
        if 'longitude' in f.spellings and 'altitude' in v:
            return 'air2'
        return 'mavic2'
    return 'unknown'


def _gps_triple(values: list[str], extra: dict[str, str]) -> tuple[float, float, float]:
    """GPS(...) -> (lat, lon, alt): (lat, lon, alt M) when the third value has a metre unit, else (lon, lat, sats)."""
    nan = math.nan
    if len(values) < 2:
        return nan, nan, nan
    a, b = _to_float(values[0]), _to_float(values[1])
    third = values[2] if len(values) > 2 else ''
    if third[-1:] in ('M', 'm'):
        extra['gps_altitude'] = third
        alt = _to_float(third)
        # M300 writes 0.0M in every block while flying: a placeholder, not sea level.
        return a, b, (nan if alt == 0.0 else alt)
    if third:
        extra['satellites'] = third
    return b, a, nan


def _ypr(f: _Fields, pry_key: str, keys: tuple[str, str, str], group: str) -> tuple[float, float, float] | None:
    """(yaw, pitch, roll) in degrees from 'X.PRY (p, r, y)', 'gb_yaw..' or '[Group: Yaw:.., Pitch:.., Roll:..]'."""
    pry = f.paren.get(pry_key)
    if pry is not None and len(pry) == 3:
        p, r, y = (_to_float(v) for v in pry)
        out = (y, p, r)
    else:
        yaw = f.number(keys[0])
        if not math.isfinite(yaw):
            keys = (f'{group}_yaw', f'{group}_pitch', f'{group}_roll')
            yaw = f.number(keys[0])
        out = (yaw, f.number(keys[1]), f.number(keys[2]))
    return out if all(math.isfinite(v) for v in out) else None


def _focal_mm(text: str | None) -> float | None:
    value = _to_float(text)
    if not math.isfinite(value):
        return None
    # Mavic 2/Air 2 write tenths of a millimetre as an integer (240 = 24 mm); Mavic 3 writes 24.00.
    if text is not None and '.' not in text and value >= 100.0:
        value /= 10.0
    return value


def _naive_ns(m: re.Match[str]) -> int | None:
    year, month, day, hour, minute, second = (int(m.group(i)) for i in range(1, 7))
    if not (1 <= month <= 12 and 1 <= day <= 31 and hour < 24 and minute < 60 and second < 61):
        return None
    try:
        seconds = calendar.timegm((year, month, day, hour, minute, second, 0, 0, 0))
    except (OverflowError, ValueError):
        return None
    frac = m.group(7) or ''
    ns = int(frac.ljust(3, '0')) * 1_000_000 if frac else 0  # "52.37" is 370 ms, ",774" is 774 ms
    if m.group(8):
        ns += int(m.group(8)) * 1_000  # ",774,808": the second group is microseconds
    return seconds * 1_000_000_000 + ns


def _to_float(text: str | None) -> float:
    if not text:
        return math.nan
    m = _NUMBER.match(text.strip())
    if m is None:
        return math.nan
    try:
        return float(m.group(0))
    except ValueError:
        return math.nan


def _first_finite(*values: float) -> float:
    for v in values:
        if math.isfinite(v):
            return v
    return math.nan
