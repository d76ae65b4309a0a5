"""srmosaic_ros.io.bags on real bags: rosbag2's own test bags (crystal to jazzy) and ROS 1 bags.

Every bag under test/data/real/bags is listed in BAGS with what reading it must give: the messages
of every topic, counted and equal to what its metadata.yaml (or the file's own index) says, or the
one-line BagError that refuses it. None has an image topic, so read_flight (what ``srmosaic
process`` opens a bag with) refuses each with its one-line 'no image topic' message. Where the
files come from and what was left out: test/data/real/bags/README.md.
"""
from __future__ import annotations

import hashlib
import logging
import re
import shutil
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from rosbags.typesys import Stores, get_typestore

from srmosaic_ros.errors import BagError
from srmosaic_ros.io.bags import TopicConfig, bag_summary, iter_raw, read_flight
from repo_paths import TEST_DATA

FIXTURES = TEST_DATA / 'real' / 'bags'
R2 = FIXTURES / 'rosbag2'
REINDEX_G = R2 / 'galactic/rosbag2_tests/resources/reindex_test_bags'
REINDEX_H = R2 / 'humble/rosbag2_tests/resources/reindex_test_bags'
STORE = get_typestore(Stores.ROS2_JAZZY)  # ROS 2 Jazzy's own message definitions
NO_IMAGE = (r"has no image topic '/camera/image_raw' \(nor '/camera/image_raw/compressed'\)\. "
            r'Choose the image topic with --image-topic TOPIC \(')


@dataclass(frozen=True)
class Read:
    """The bag reads: ``counts`` messages per topic (topics without messages left out), each equal
    to its metadata count; ``warning`` a regex one warning must match ('' for none at all)."""

    counts: dict[str, int]
    warning: str = ''


@dataclass(frozen=True)
class Refused:
    """iter_raw refuses the bag with one line matching ``pattern``; with ``summary_opens`` the
    bag still opens (bag_summary reports it), else opening it is refused with the same line."""

    pattern: str
    summary_opens: bool = False


TURTLES = {'/rosout': 10, '/tf': 2688, '/tf_static': 1, '/turtle1/cmd_vel': 357,
           '/turtle1/color_sensor': 1351, '/turtle1/pose': 1344, '/turtle2/cmd_vel': 208,
           '/turtle2/color_sensor': 1344, '/turtle2/pose': 1344}
CDR_TEST = {'/array_topic': 4, '/test_topic': 3}
TALKER = {'/rosout': 10, '/topic': 10}
SERVICE_EVENTS = {'/test_service1/_service_event': 4, '/test_service2/_service_event': 4,
                  '/test_topic1': 1, '/test_topic2': 1}
QOS = (r"metadata\.yaml's QoS profiles \(or type hashes\) of {} differ from those in {}, so the "
       r'rosbags reader would yield none of their {} messages; they are read by topic name from '
       r'the storage files instead\.')
NOT_CDR = r"cannot be read: /array_topic, .*/test_topic: serialisation format 'wrong_format' is not CDR"
CONVERT = r'; only CDR \(and ROS 1\) messages are read; re-record or convert those topics to CDR'
SPLIT = (r'is a folder without metadata\.yaml, so not a readable rosbag2 bag: it holds the 3 files of '
         r'a split bag \(multiple_files_0\.{0}, multiple_files_1\.{0}, multiple_files_2\.{0}\); '
         r'reindex it with `ros2 bag reindex .*multiple_files -s {1}`')
NO_FILES = (r"Cannot open bag '.*target_metadata/{}': storage files listed in its metadata\.yaml "
            r'are not in the folder \({}\); copy the whole bag folder')
THREE_DB3 = r'multiple_files_0\.db3, multiple_files_1\.db3, multiple_files_2\.db3'
ZSTD_FRAMES = r'its messages are zstd frames, so it is one file of a bag compressed in zstd message mode'
CRYSTAL, DASHING, FOXY = 'rosbag2/crystal/', 'rosbag2/dashing/', 'rosbag2/foxy/'
GALACTIC, HUMBLE, IRON, JAZZY = 'rosbag2/galactic/', 'rosbag2/humble/', 'rosbag2/iron/', 'rosbag2/jazzy/'
G_REINDEX = GALACTIC + 'rosbag2_tests/resources/reindex_test_bags/'
H_REINDEX = HUMBLE + 'rosbag2_tests/resources/reindex_test_bags/'
I_PY = IRON + 'rosbag2_py/test/resources/'
J_CPP = JAZZY + 'rosbag2_cpp/test/rosbag2_cpp/bags'
MESSAGE_COMPRESSION_FILES = [{'/rosout': 260, '/topic': 120}, {'/rosout': 240, '/topic': 120},
                             {'/rosout': 240, '/topic': 120}, {'/rosout': 18, '/topic': 9}]

BAGS: dict[str, Read | Refused] = {
    # ROS 1 (cruise-automation/rosbag.js fixtures): bz2 and lz4 chunks, unsorted chunks, no messages
    'rosbag1/example-bz2.bag': Read(TURTLES),
    'rosbag1/example-lz4.bag': Read(TURTLES),
    'rosbag1/example-unsorted-chunks.bag': Read({'foo': 3}),
    'rosbag1/no-messages.bag': Read({}),
    # crystal: ROS 1 bags (uncompressed; a topic over two connections), sqlite3 schema 1, metadata v1
    CRYSTAL + 'rosbag2_bag_v2_plugins/resources/test_bag.bag': Read(
        {'/rosout': 3, '/test_topic': 1, '/test_topic2': 1}),
    CRYSTAL + 'rosbag2_bag_v2_plugins/resources/test_bag_multiple_connections.bag': Read(
        {'/int_test_topic': 2, '/rosout': 2, '/test_topic': 2}),
    CRYSTAL + 'rosbag2_tests/resources/test_bag.bag': Read({'int_topic': 3, 'rosout': 5, 'string_topic': 3}),
    CRYSTAL + 'rosbag2_tests/resources/cdr_test': Read(CDR_TEST),
    CRYSTAL + 'rosbag2_tests/resources/wrong_rmw_test': Refused(NOT_CDR + CONVERT, summary_opens=True),
    # dashing: metadata.yaml names other types than the database holds (known wrong)
    DASHING + 'rosbag2_tests/resources/cdr_test': Read(
        CDR_TEST, r'disagree on the message type of /array_topic \(test_msgs/Arrays in metadata\.yaml, '
                  r'test_msgs/StaticArrayPrimitives in cdr_test\.db3\), /test_topic'),
    # foxy: metadata v4 with QoS strings equal to the database's; wrong_format only in metadata.yaml
    FOXY + 'ros2bag/test/resources/empty_bag': Read({}),
    FOXY + 'rosbag2_tests/resources/cdr_test': Read(CDR_TEST),
    FOXY + 'rosbag2_tests/resources/wrong_rmw_test': Refused(
        NOT_CDR + r" \(metadata\.yaml declares 'wrong_format', the storage file 'cdr'\); .*the storage "
                  r'files say cdr: if they are right, regenerate metadata\.yaml with `ros2 bag reindex`',
        summary_opens=True),
    # galactic: QoS strings differ from the database's; reindex test bags (no metadata.yaml)
    GALACTIC + 'rosbag2_py/resources/talker': Read(TALKER, QOS.format('/rosout, /topic', r'talker\.db3', 20)),
    GALACTIC + 'rosbag2_tests/resources/cdr_test': Read(
        CDR_TEST, QOS.format('/array_topic, /test_topic', r'cdr_test_0\.db3', 7)),
    G_REINDEX + 'file_compression': Refused(
        r'is a folder without metadata\.yaml, so not a readable rosbag2 bag: it holds 4 zstd-compressed '
        r'storage files \(file_compression_0\.db3\.zstd, .* whose compression only metadata\.yaml '
        r'records; reindex it with `ros2 bag reindex`'),
    G_REINDEX + 'message_compression': Refused(
        r'it holds the 4 files of a split bag \(message_compression_0\.db3, .*\); reindex it with '
        r'`ros2 bag reindex .*message_compression -s sqlite3`'),
    **{G_REINDEX + f'message_compression/message_compression_{i}.db3': Read(counts, ZSTD_FRAMES)
       for i, counts in enumerate(MESSAGE_COMPRESSION_FILES)},
    G_REINDEX + 'target_metadata/file_compression': Refused(NO_FILES.format(
        'file_compression', r'file_compression_0\.db3\.zstd, file_compression_1\.db3\.zstd, '
                            r'file_compression_2\.db3\.zstd, file_compression_3\.db3\.zstd')),
    G_REINDEX + 'target_metadata/message_compression': Refused(NO_FILES.format(
        'message_compression', r'message_compression_0\.db3, .*message_compression_3\.db3')),
    G_REINDEX + 'target_metadata/multiple_files': Refused(NO_FILES.format('multiple_files', THREE_DB3)),
    # humble: metadata v5 with QoS strings, a database without; a split bag without metadata.yaml
    HUMBLE + 'rosbag2_py/test/resources/convert_a': Read(
        {'a_empty': 100, 'b_basictypes': 50}, QOS.format('a_empty, b_basictypes', r'rewriter_a_0\.db3', 150)),
    HUMBLE + 'rosbag2_py/test/resources/convert_b': Read(
        {'a_empty': 25, 'c_strings': 50}, QOS.format('a_empty, c_strings', r'rewriter_b_0\.db3', 75)),
    H_REINDEX + 'multiple_files': Refused(SPLIT.format('db3', 'sqlite3')),
    **{H_REINDEX + f'multiple_files/multiple_files_{i}.db3': Read({'/topic': n})
       for i, n in enumerate([20, 20, 12])},
    H_REINDEX + 'target_metadata/multiple_files': Refused(NO_FILES.format('multiple_files', THREE_DB3)),
    HUMBLE + 'rosbag2_transport/test/resources/test_bag_for_seek': Read({'topic1': 5}),
    # iron: mcap (some written by the Go mcap tool, without QoS), metadata v4 to v7
    I_PY + 'mcap/convert_a': Read(
        {'a_empty': 100, 'b_basictypes': 50},
        QOS.format('a_empty, b_basictypes', r'rewriter_a_0\.mcap', 150)),
    I_PY + 'mcap/convert_b': Read({'a_empty': 25, 'c_strings': 50}),
    I_PY + 'mcap/reindex_test_bags/multiple_files': Refused(SPLIT.format('mcap', 'mcap')),
    **{I_PY + f'mcap/reindex_test_bags/multiple_files/multiple_files_{i}.mcap': Read({'/chatter': n})
       for i, n in enumerate([1324, 1324, 529])},
    I_PY + 'mcap/talker': Read(TALKER, QOS.format('/rosout, /topic', r'talker\.mcap', 20)),
    I_PY + 'sqlite3/talker': Read(TALKER, QOS.format('/rosout, /topic', r'talker\.db3', 20)),
    IRON + 'rosbag2_tests/resources/mcap/cdr_test': Read(CDR_TEST),
    IRON + 'rosbag2_tests/resources/mcap/wrong_rmw_test': Refused(NOT_CDR + CONVERT, summary_opens=True),
    IRON + 'rosbag2_tests/resources/sqlite3/cdr_test': Read(CDR_TEST),
    IRON + 'rosbag2_transport/test/resources/mcap/test_bag_for_seek': Read({'topic1': 5}),
    # jazzy: metadata v8, service event topics (mcap schemas that are .srv texts), bare files
    J_CPP: Refused(r'it holds 4 storage files that are not the parts of one split bag '
                   r'\(only_services\.mcap, only_topics\.mcap, topics_and_services\.db3, '
                   r'topics_and_services\.mcap\); pass one of them'),
    J_CPP + '/only_services.mcap': Read({'/add_two_ints/_service_event': 12}),
    J_CPP + '/only_topics.mcap': Read({'/parameter_events': 7}),
    J_CPP + '/topics_and_services.db3': Read({'/add_two_ints/_service_event': 6, '/parameter_events': 7}),
    J_CPP + '/topics_and_services.mcap': Read({'/add_two_ints/_service_event': 6, '/parameter_events': 7}),
    JAZZY + 'rosbag2_tests/resources/mcap/bag_with_topics_and_service_events': Read(SERVICE_EVENTS),
    JAZZY + 'rosbag2_tests/resources/sqlite3/bag_with_topics_and_service_events': Read(SERVICE_EVENTS),
}


def fixture_bags() -> set[str]:
    """Every bag under FIXTURES: folders with metadata.yaml or storage files, ROS 1 bags, and bare
    storage files that are not part of a folder with metadata.yaml."""
    found = set()
    for path in FIXTURES.rglob('*'):
        if path.is_dir():
            storage = any(p.suffix in {'.db3', '.mcap', '.zstd'} for p in path.iterdir())
            if (path / 'metadata.yaml').is_file() or storage:
                found.add(path)
        elif path.suffix == '.bag':
            found.add(path)
        elif path.suffix in {'.db3', '.mcap'} and not (path.parent / 'metadata.yaml').exists():
            found.add(path)
    return {p.relative_to(FIXTURES).as_posix() for p in found}


def read_counts(path: Path, topics: list[str] | None = None) -> Counter[str]:
    return Counter(topic for topic, _msgtype, _log_ns, _raw in iter_raw(path, topics=topics))


def one_line(exc: pytest.ExceptionInfo[BagError]) -> str:
    text = str(exc.value)
    assert '\n' not in text, text
    assert 'Could not parse' not in text and 'MSG:' not in text, text  # never a schema dump
    return text


def test_every_fixture_bag_is_listed() -> None:
    assert fixture_bags() == set(BAGS)


@pytest.mark.parametrize('name', sorted(BAGS))
def test_bag_is_read_or_refused(name: str) -> None:
    path = FIXTURES / name
    expect = BAGS[name]
    if isinstance(expect, Read):
        assert dict(read_counts(path)) == expect.counts
        summary = bag_summary(path)
        assert {t: c.count_read for t, c in summary.topics.items() if c.count_read} == expect.counts
        assert {t: c.count_metadata for t, c in summary.topics.items() if c.count_metadata} == expect.counts
        assert summary.messages_read == summary.message_count == sum(expect.counts.values())
        assert summary.missing == {}
        for warning in summary.warnings:
            assert '\n' not in warning
            assert str(path) in warning
        if expect.warning:
            assert len(summary.warnings) == 1
            assert re.search(expect.warning, summary.warnings[0]), summary.warnings[0]
        else:
            assert summary.warnings == ()
        return
    with pytest.raises(BagError) as info:
        list(iter_raw(path))
    text = one_line(info)
    assert repr(str(path)) in text
    assert re.search(expect.pattern, text), text
    if expect.summary_opens:
        summary = bag_summary(path)
        noted = "serialisation format 'wrong_format' is not CDR"
        assert {t for t, c in summary.topics.items() if noted in c.note} >= {'/array_topic', '/test_topic'}
        read = {t: c.count_read for t, c in summary.topics.items() if c.count_read}
        assert read == CDR_TEST  # the bytes are there, only their format is refused
    else:
        with pytest.raises(BagError) as again:
            bag_summary(path)
        assert str(again.value) == text


@pytest.mark.parametrize('name', sorted(BAGS))
def test_read_flight_refuses_in_one_line(name: str) -> None:
    """What `srmosaic process` opens a bag with: none of these has an image topic."""
    path = FIXTURES / name
    expect = BAGS[name]
    with pytest.raises(BagError) as info:
        read_flight(path, topics=TopicConfig())
    text = one_line(info)
    if isinstance(expect, Read) or expect.summary_opens:
        assert text.startswith(f'Bag {str(path)!r} has no image topic')
        assert re.search(NO_IMAGE, text), text
        summary = bag_summary(path, read_messages=False)
        assert (summary.refusal, summary.flight_topics, summary.messages_read) == (text, {}, None)
    else:
        assert re.search(expect.pattern, text), text


# ------------------------------------------------------------------------------------- the issue


def test_service_event_mcap_opens_and_reads_its_topics() -> None:
    """Jazzy's mcap schema of a service event topic is the .srv text; it must stop nothing."""
    path = R2 / 'jazzy/rosbag2_tests/resources/mcap/bag_with_topics_and_service_events'
    reader = read_flight(path, topics=TopicConfig(image=''), require_image=False)
    assert reader.warnings == ()
    assert reader.frame_count == 0
    assert list(reader) == []
    summary = bag_summary(path)
    for topic in ('/test_service1/_service_event', '/test_service2/_service_event'):
        assert summary.topics[topic].note == (
            'its definition of test_msgs/srv/BasicTypes_Event in the bag is a service/action text '
            "with '---', not a message definition")
    assert summary.topics['/test_topic1'].note == ''
    assert (summary.storage, summary.metadata_version, summary.files, summary.compression) == (
        'mcap', 8, ('bag_with_topics_and_service_events.mcap',), '')
    assert (summary.start_ns, summary.duration_ns, summary.message_count) == (
        1699345836270074454, 70653944, 10)


@pytest.mark.parametrize('name', ['galactic/rosbag2_py/resources/talker',
                                  'iron/rosbag2_py/test/resources/sqlite3/talker',
                                  'iron/rosbag2_py/test/resources/mcap/talker'])
def test_qos_mismatch_reads_every_message(name: str, caplog: pytest.LogCaptureFixture) -> None:
    from rosbags.highlevel import AnyReader

    path = R2 / name
    with AnyReader([path], default_typestore=STORE) as plain:  # the premise: rosbags alone yields none
        assert sum(1 for _ in plain.messages()) == 0
    with caplog.at_level(logging.WARNING, logger='srmosaic_ros.io.bags'):
        reader = read_flight(path, topics=TopicConfig(image=''), require_image=False)
    (warning,) = reader.warnings
    assert re.search(r'QoS profiles .* of /rosout, /topic differ .* none of their 20 messages', warning)
    logged = [r.getMessage() for r in caplog.records if r.name == 'srmosaic_ros.io.bags']
    assert logged == [warning]  # logged once, one line
    texts: dict[str, list[str]] = {'/topic': [], '/rosout': []}
    for topic, msgtype, _log_ns, raw in iter_raw(path):
        msg = STORE.deserialize_cdr(raw, msgtype)
        texts[topic].append(msg.data if topic == '/topic' else msg.msg)
    assert texts['/topic'] == [f'Hello, world! {i}' for i in range(10)]
    assert texts['/rosout'] == [f"Publishing: 'Hello, world! {i}'" for i in range(10)]
    summary = bag_summary(path)
    assert (summary.start_ns, summary.duration_ns) == (1585866235112411371, 4531096768)


def test_missing_messages_are_counted_and_said(tmp_path: Path) -> None:
    """metadata.yaml counting more than the database holds (a recording cut short)."""
    bag = tmp_path / 'talker'
    shutil.copytree(R2 / 'iron/rosbag2_py/test/resources/sqlite3/talker', bag)
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    info['message_count'] = 22
    (topic,) = [t for t in info['topics_with_message_count'] if t['topic_metadata']['name'] == '/topic']
    topic['message_count'] = 12
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(meta))
    reader = read_flight(bag, topics=TopicConfig(image=''), require_image=False)
    assert reader.missing == {'/topic': 2}
    assert any('the storage files hold 2 messages fewer than metadata.yaml counts (/topic 12 -> 10)' in w
               for w in reader.warnings)
    summary = bag_summary(bag)
    assert summary.missing == {'/topic': 2}
    assert (summary.message_count, summary.messages_read) == (22, 20)
    assert summary.topics['/topic'].count_metadata == 12
    assert summary.topics['/topic'].count_read == 10
    assert summary.topics['/topic'].note == '2 messages counted in metadata.yaml are not in the files'
    assert read_counts(bag) == TALKER


def test_metadata_with_wrong_types_uses_the_database() -> None:
    summary = bag_summary(R2 / 'dashing/rosbag2_tests/resources/cdr_test')
    assert summary.topics['/test_topic'].msgtype == 'test_msgs/Primitives'
    assert summary.topics['/array_topic'].msgtype == 'test_msgs/StaticArrayPrimitives'
    assert summary.metadata_version == 1


@pytest.mark.parametrize('name', ['crystal/rosbag2_tests/resources/wrong_rmw_test',
                                  'foxy/rosbag2_tests/resources/wrong_rmw_test',
                                  'iron/rosbag2_tests/resources/mcap/wrong_rmw_test'])
def test_unneeded_topics_in_another_format_stop_nothing(name: str) -> None:
    reader = read_flight(R2 / name, topics=TopicConfig(image=''), require_image=False)
    assert list(reader) == []
    assert read_counts(R2 / name, topics=['/no/such/topic']) == Counter()
    with pytest.raises(BagError, match=r"/test_topic: serialisation format 'wrong_format' is not") as info:
        list(iter_raw(R2 / name, topics=['/test_topic']))
    one_line(info)


# ----------------------------------------------------------------------------- decoded contents


def stream_digest(path: Path) -> str:
    digest = hashlib.sha256()
    for topic, msgtype, log_ns, raw in iter_raw(path):
        digest.update(f'{topic}|{msgtype}|{log_ns}|'.encode() + raw)
    return digest.hexdigest()


def test_ros1_bags_convert_to_cdr_that_ros2_decodes() -> None:
    lz4, bz2 = FIXTURES / 'rosbag1/example-lz4.bag', FIXTURES / 'rosbag1/example-bz2.bag'
    assert stream_digest(lz4) == stream_digest(bz2)  # one recording, two chunk compressions
    ((topic, msgtype, log_ns, raw),) = list(iter_raw(lz4, topics=['/tf_static']))
    assert (topic, msgtype, log_ns) == ('/tf_static', 'tf2_msgs/msg/TFMessage', 1396293888046138414)
    (transform,) = STORE.deserialize_cdr(raw, msgtype).transforms  # ROS 2's definition: no Header.seq
    assert (transform.header.stamp.sec, transform.header.stamp.nanosec) == (1396293887, 807552910)
    assert (transform.header.frame_id, transform.child_frame_id) == ('turtle1', 'carrot')
    t, q = transform.transform.translation, transform.transform.rotation
    assert (t.x, t.y, t.z, q.x, q.y, q.z, q.w) == (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    summary = bag_summary(FIXTURES / 'rosbag1/example-unsorted-chunks.bag')
    assert (summary.storage, summary.metadata_version, summary.start_ns, summary.duration_ns) == (
        'rosbag1', None, 1_000_000_000, 2_000_000_000)


@dataclass(frozen=True)
class Reindexed:
    """A reindex test bag with rosbag2's own target metadata.yaml beside it (what `ros2 bag
    reindex` writes): its /topic carries 'Hello, world! N' for consecutive N."""

    data: Path
    target: Path
    compression: str
    version: int
    counts: dict[str, int]
    first: int


REINDEXED = [
    Reindexed(REINDEX_G / 'file_compression', REINDEX_G / 'target_metadata/file_compression', 'zstd file', 4,
              {'/rosout': 392, '/topic': 383}, 11721),
    Reindexed(REINDEX_G / 'message_compression', REINDEX_G / 'target_metadata/message_compression',
              'zstd message', 4, {'/rosout': 758, '/topic': 369}, 4084),
    Reindexed(REINDEX_H / 'multiple_files', REINDEX_H / 'target_metadata/multiple_files', '', 5,
              {'/topic': 52}, 10),
]


@pytest.mark.parametrize('case', REINDEXED, ids=lambda c: c.data.name)
def test_reindexed_split_and_compressed_bags(tmp_path: Path, case: Reindexed) -> None:
    bag = tmp_path / case.data.name
    shutil.copytree(case.data, bag)
    shutil.copy(case.target / 'metadata.yaml', bag / 'metadata.yaml')
    summary = bag_summary(bag)
    assert (summary.compression, summary.metadata_version) == (case.compression, case.version)
    assert summary.warnings == ()
    assert len(summary.files) == len(list(case.data.iterdir()))
    assert {t: c.count_read for t, c in summary.topics.items() if c.count_read} == case.counts
    assert {t: c.count_metadata for t, c in summary.topics.items() if c.count_metadata} == case.counts
    texts = [STORE.deserialize_cdr(raw, msgtype).data
             for _topic, msgtype, _log_ns, raw in iter_raw(bag, topics=['/topic'])]
    assert texts == [f'Hello, world! {case.first + i}' for i in range(case.counts['/topic'])]


def test_bare_file_of_a_message_compressed_bag_is_decompressed() -> None:
    path = REINDEX_G / 'message_compression/message_compression_0.db3'
    topic, msgtype, log_ns, raw = next(iter_raw(path))
    assert (topic, log_ns) == ('/rosout', 1604581357697556242)
    assert STORE.deserialize_cdr(raw, msgtype).msg == "I heard: 'Hello, world! 4074'"
