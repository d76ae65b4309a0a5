"""MISB KLV metadata in MPEG-TS video: the ST0601 UAS Datalink Local Set and the legacy EG0104 set.

This module demultiplexes and times the KLV of a file; klv_framing.py splits KLV items,
klv_st0601.py and klv_eg0104.py decode the two sets (their public names are re-exported here).

Demultiplexing (PyAV): the KLV data stream is the first data stream FFmpeg labels ``klv`` (its PMT
entry carries the ``KLVA`` registration descriptor), else the first data stream whose first
packet starts with the SMPTE ST 336 key prefix ``06 0E 2B 34``. A stream is called synchronous
when its PES packets carry a PTS, asynchronous otherwise (ST1402); asynchronous KLV has no
container time, so its records have ``pts_ns=None`` and are timed by ``precision_time_us`` alone.
One PES packet may hold several concatenated KLV items (16-byte universal key + BER length, short
or long form); an item cut across two PES packets of a stream is joined again.

Time: ``KlvRecord.pts_ns`` is the data packet's PTS on the container clock minus the PTS of the
first decoded video frame, in ns, with the same rounding as ``VideoReader`` stamps, so a record and
the frame it was muxed with have equal stamps. It is negative for metadata sent before frame 0.

Field names and units (``KlvRecord.fields``; floats in degrees and metres, NaN where the standard's
reserved "error"/"out of range"/"off-earth" value was sent, absent when the item was not sent):
``precision_time_us`` (int, UNIX epoch microseconds, UTC without leap seconds),
``mission_id``, ``platform_designation``, ``image_source_sensor`` (str), ``ls_version`` (int, ST0601
tag 65), ``platform_heading_deg`` (clockwise from true north, [0, 360)), ``platform_pitch_deg`` (nose
up positive), ``platform_roll_deg`` (right wing down positive), ``sensor_latitude_deg``,
``sensor_longitude_deg`` (WGS84), ``sensor_altitude_m`` (true altitude, above mean sea level),
``sensor_hfov_deg``, ``sensor_vfov_deg``, ``slant_range_m``, ``target_width_m``,
``frame_center_latitude_deg``, ``frame_center_longitude_deg``, ``frame_center_elevation_m`` (MSL),
``corner_latitude_deg`` and ``corner_longitude_deg`` (tuples of 4: upper left, upper right, lower
right, lower left of the image), and the sensor pointing angles below. Items the decoders do not
decode are kept raw in ``fields['raw']`` (ST0601: int tag -> bytes; EG0104: hex key -> bytes) and
counted in ``KlvTrack.unknown_keys``.

Angle conventions, per standard:

- ST0601 (UAS Datalink LS) carries the platform attitude (tag 5 heading clockwise from true north,
  tag 6/90 pitch positive nose up, tag 7/91 roll positive right wing down) and the sensor angles
  RELATIVE to the platform: tag 18 ``sensor_rel_azimuth_deg`` clockwise from the platform's nose
  seen from above, [0, 360); tag 19 ``sensor_rel_elevation_deg`` from the platform's
  longitudinal-transverse plane, negative down; tag 20 ``sensor_rel_roll_deg`` about the line of
  sight, clockwise seen from behind the camera, [0, 360). The sensor pointing is the platform
  attitude (Z-Y-X: heading, pitch, roll) followed by azimuth, elevation, roll. Pitch and roll come
  from the full-range tags 90/91 when sent, else from the short-range tags 6/7. The corners come
  from the full corner tags 82-89 when all eight were sent, else from the offset tags 26-33 added
  to the frame centre.
- EG0104 (Predator UAV Basic Universal Metadata Set) carries the platform attitude as IEEE floats
  in the same sense (heading wrapped here into [0, 360)) and the sensor pointing as ABSOLUTE,
  earth-referenced angles: "Angle to North" -> ``sensor_azimuth_deg`` (clockwise from true north,
  [0, 360)), "Obliquity Angle" -> ``sensor_elevation_deg`` (from the local horizontal, negative
  below it, as the real files carry it: docs/results.md, "KLV"), "Sensor Roll Angle" ->
  ``sensor_roll_deg``. When the attitude and both pointing angles are present,
  ``sensor_rel_azimuth_deg`` and ``sensor_rel_elevation_deg`` are DERIVED from them in the ST0601
  sense (the line of sight rotated into the platform frame), and ``fields['derived']`` names them;
  no relative roll is derived.

The checksum (ST0601 tag 1, the last item) is the 16-bit running sum of the whole packet, key and
length included, up to and including the checksum's own tag and length bytes, each even-offset
byte weighted 256. Packets failing it are counted in ``KlvTrack.bad_checksum`` and left out of
``records``. EG0104 has no checksum (``checksum_ok=None``).

Written by hand from the public definitions (ST0601 tags and their integer mappings, checked in
the tests against kwiver's decoded values; EG0104.5 keys as listed in Kitware kwiver
arrows/klv/klv_0104.cxx and in OSSIM's ossimPredatorKlvTable.cxx); the
``klvdata`` package (0.0.3) is not used because it cannot decode these files (its tag-73 parser
raises on every kwiver ST0601 packet, it reads only one-byte tags, does not verify the checksum,
raises on the reserved error values and has no EG0104).
"""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

from ..errors import MetadataError
from .klv_eg0104 import EG0104_KEY, _eg0104_fields, _eg0104_item, decode_eg0104
from .klv_framing import _UL_PREFIX, _same_ul, _split_items, split_klv
from .klv_st0601 import ST0601_KEY, decode_st0601

__all__ = [
    'EG0104_KEY',
    'ST0601_KEY',
    'KlvRecord',
    'KlvTrack',
    'decode_eg0104',
    'decode_st0601',
    'read_klv',
    'split_klv',
]

_SNIFF_PACKETS = 200  # data packets inspected to find KLV in a stream FFmpeg did not label


@dataclass(frozen=True)
class KlvRecord:
    """One decoded KLV set (a ST0601 local set, or an EG0104 universal set).

    pts_ns: presentation time of its data packet in ns from the first video frame (None for an
    asynchronous stream); standard: 'ST0601' or 'EG0104'; fields: see the module docstring;
    checksum_ok: True for a verified ST0601 checksum, None when the standard has none.
    """

    pts_ns: int | None
    standard: str
    fields: dict[str, object]
    checksum_ok: bool | None


@dataclass
class KlvTrack:
    """All KLV of a file: good records in pts order (demux order when asynchronous) and counts.

    packets: top-level KLV items seen; bad_checksum: ST0601 packets that failed their checksum
    (not in records); unknown_keys: hex key (or 'ST0601 tag N') -> count of items not decoded;
    standards: 'ST0601'/'EG0104' -> sets seen, bad checksums included; stream: which stream
    was read, '' when the file has none; malformed: items cut short or bytes that are not KLV;
    error: why demultiplexing stopped early ('' when it read to the end).
    """

    records: list[KlvRecord]
    packets: int
    bad_checksum: int
    unknown_keys: dict[str, int]
    standards: dict[str, int]
    stream: str
    malformed: int = 0
    error: str = ''



# ---------------------------------------------------------------------------------------------
# Demultiplexing


def _find_klv_stream(container):
    """The KLV data stream and whether FFmpeg labelled it, or (None, False)."""
    data_streams = list(container.streams.data)
    for stream in data_streams:
        if getattr(stream, 'name', None) == 'klv':
            return stream, True
    if not data_streams:
        return None, False
    # some muxers omit the KLVA descriptor: look for universal keys in the first packets
    seen = 0
    for packet in container.demux(*data_streams):
        payload = bytes(packet)
        if payload:
            if payload.startswith(_UL_PREFIX):
                return packet.stream, False
            seen += 1
            if seen >= _SNIFF_PACKETS:
                break
    return None, False


def _first_frame_seconds(path: Path) -> Fraction | None:
    """PTS of the first decoded video frame in seconds (the VideoReader origin), None without video."""
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                return None
            stream = container.streams.video[0]
            time_base = stream.time_base or Fraction(1, 90000)
            try:
                for frame in container.decode(stream):
                    if frame.pts is not None:
                        return frame.pts * time_base
                    break
            except av.error.FFmpegError:  # undecodable video: fall back to the declared start
                pass
            if stream.start_time is not None:
                return stream.start_time * time_base
    except (av.error.FFmpegError, OSError):  # opened once already; timing then counts from the KLV
        return None
    return None


class _Joiner:
    """Splits successive PES payloads into KLV items, joining an item cut across two of them.

    A payload that does not start with a key prefix continues the previous payload's unfinished
    item; one that does means that item was lost (counted in ``malformed`` with non-KLV runs).
    """

    def __init__(self) -> None:
        self.carry = b''
        self.malformed = 0

    def feed(self, payload: bytes) -> list[tuple[bytes, bytes, bytes]]:
        if self.carry and not payload.startswith(_UL_PREFIX):
            payload = self.carry + payload
        elif self.carry:
            self.malformed += 1
        items, junk, self.carry = _split_items(payload)
        self.malformed += junk
        return items


class _TrackBuilder:
    """Accumulates decoded items of one stream into a KlvTrack."""

    def __init__(self) -> None:
        self.track = KlvTrack([], 0, 0, {}, {}, '')

    def _unknown(self, key: str) -> None:
        self.track.unknown_keys[key] = self.track.unknown_keys.get(key, 0) + 1

    def _standard(self, name: str) -> None:
        self.track.standards[name] = self.track.standards.get(name, 0) + 1

    def add_packet(self, items: list[tuple[bytes, bytes, bytes]], pts_ns: int | None) -> None:
        loose: list[tuple[bytes, bytes]] = []  # EG0104 elements sent without their set
        for key, value, whole in items:
            self.track.packets += 1
            if _same_ul(key, ST0601_KEY):
                self._standard('ST0601')
                fields, ok = decode_st0601(value, packet=whole)
                for tag in fields.get('raw', {}):
                    self._unknown(f'ST0601 tag {tag}')
                if ok:
                    self.track.records.append(KlvRecord(pts_ns, 'ST0601', fields, True))
                else:
                    self.track.bad_checksum += 1
            elif _same_ul(key, EG0104_KEY):
                self._standard('EG0104')
                self._add_eg0104(split_klv(value), pts_ns)
            elif _eg0104_item(key) is not None:
                loose.append((key, value))
            else:
                self._unknown(key.hex())
        if loose:
            self._standard('EG0104')
            self._add_eg0104(loose, pts_ns)

    def _add_eg0104(self, items: list[tuple[bytes, bytes]], pts_ns: int | None) -> None:
        fields = _eg0104_fields(items)
        for key in fields.get('raw', {}):
            self._unknown(key)
        self.track.records.append(KlvRecord(pts_ns, 'EG0104', fields, None))


def _open(path: Path):
    import av

    try:
        return av.open(str(path))
    except (av.error.FFmpegError, OSError) as exc:  # not a media file, a damaged header, no access
        msg = (f'KLV: {str(path)!r} cannot be opened as a video container ({exc}); MISB KLV is read '
               'from MPEG transport streams (.ts): check that this is one and that the copy is complete.')
        raise MetadataError(msg) from None


def _read_stream(path: Path, container, stream, builder: _TrackBuilder) -> int:
    """Demultiplex the KLV stream into the builder; returns how many packets carried a PTS."""
    import av

    track = builder.track
    time_base: Fraction = stream.time_base or Fraction(1, 90000)
    origin: Fraction | None = None
    joiner = _Joiner()
    with_pts = 0
    try:
        for packet in container.demux(stream):
            payload = bytes(packet)
            if not payload:
                continue  # the demuxer's flush packet
            pts = packet.pts if packet.pts is not None else packet.dts
            pts_ns = None
            if pts is not None:
                with_pts += 1
                if origin is None:
                    origin = _first_frame_seconds(path)
                    if origin is None:  # no video: count from the first KLV packet instead
                        origin = pts * time_base
                pts_ns = round(float(pts * time_base - origin) * 1e9)
            builder.add_packet(joiner.feed(payload), pts_ns)
    except av.error.FFmpegError as exc:  # damage mid-file: keep what was read
        track.error = f'demultiplexing stopped after {track.packets} KLV items: {exc}'
    track.malformed += joiner.malformed + bool(joiner.carry)
    return with_pts


def read_klv(path: str | Path) -> KlvTrack:
    """Every KLV set of a video file (MPEG-TS), decoded; an empty track when it carries none.

    Raises MetadataError when the file is missing or cannot be opened as a media container.
    A packet failing its checksum or cut short is counted and skipped, never raised.
    """
    path = Path(path)
    if not path.is_file():
        msg = f'KLV: {str(path)!r} does not exist; check the path.'
        raise MetadataError(msg)
    builder = _TrackBuilder()
    track = builder.track
    with _open(path) as container:
        stream, labelled = _find_klv_stream(container)
        if stream is None:
            return track
        index = stream.index
        if labelled:
            with_pts = _read_stream(path, container, stream, builder)
    if not labelled:  # sniffing consumed packets: demultiplex again from the start
        with _open(path) as container:
            with_pts = _read_stream(path, container, container.streams[index], builder)
    timing = 'synchronous' if with_pts else 'asynchronous'
    kind = 'KLVA' if labelled else 'data, KLV keys found'
    track.stream = f'stream #{index} ({kind}, {timing})'
    if track.records and all(r.pts_ns is not None for r in track.records):
        track.records.sort(key=lambda r: r.pts_ns)  # type: ignore[arg-type, return-value]
    return track
