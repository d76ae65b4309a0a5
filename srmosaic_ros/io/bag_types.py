"""Names, constants and the plain records of the bag layer (io/bags.py is the way in)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = ['BagInfo', 'BagSummary', 'TopicConfig', 'TopicCount', 'TopicSummary', 'STORAGES', 'IMAGE_MSGTYPE',
           'COMPRESSED_IMAGE_MSGTYPE', 'CAMERA_INFO_MSGTYPE', 'NAVSAT_MSGTYPE', 'IMU_MSGTYPE']

IMAGE_MSGTYPE = 'sensor_msgs/msg/Image'
COMPRESSED_IMAGE_MSGTYPE = 'sensor_msgs/msg/CompressedImage'
CAMERA_INFO_MSGTYPE = 'sensor_msgs/msg/CameraInfo'
NAVSAT_MSGTYPE = 'sensor_msgs/msg/NavSatFix'
IMU_MSGTYPE = 'sensor_msgs/msg/Imu'
STORAGES: tuple[str, ...] = ('sqlite3', 'mcap')

_SUFFIX_STORAGE = {'.bag': 'rosbag1', '.db3': 'sqlite3', '.mcap': 'mcap'}
_ROSBAG2_VERSION = 9  # what ROS 2 Jazzy writes
_NEWEST_READABLE_VERSION = 9  # metadata.yaml versions 1..9 share the fields read here
_CDR = 'cdr'
_ROS1 = 'ros1'
_EXPECTED = {
    'image': (IMAGE_MSGTYPE, COMPRESSED_IMAGE_MSGTYPE),
    'camera_info': (CAMERA_INFO_MSGTYPE,),
    'fix': (NAVSAT_MSGTYPE,),
    'imu': (IMU_MSGTYPE,),
}
_OPTION = {
    'image': '--image-topic',
    'camera_info': '--camera-info-topic',
    'fix': '--fix-topic',
    'imu': '--imu-topic',
}
_ROLES = ('image', 'camera_info', 'fix', 'imu')
_MAX_LISTED = 4  # topics or files named in one message before '...'
_ZSTD_MAGIC = b'\x28\xb5\x2f\xfd'  # a zstd frame; CDR starts with its 0x00 encapsulation byte


@dataclass(frozen=True)
class TopicConfig:
    """Topics of a flight. An empty string switches a topic off.

    If ``image`` is absent but ``<image>/compressed`` carries sensor_msgs/CompressedImage, that is
    used. ``camera_info``, ``fix`` and ``imu`` are optional in the bag.
    """

    image: str = '/camera/image_raw'
    camera_info: str = '/camera/camera_info'
    fix: str = '/fix'
    imu: str = '/imu/data'


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: its message type (None if several) and message count in the storage files."""

    msgtype: str | None
    count: int


@dataclass(frozen=True)
class BagInfo:
    """What :func:`inspect_bag` finds: storage ('sqlite3', 'mcap', 'rosbag1' or None), times, topics.

    Times and counts are those of the storage files (their index), which are what a reader yields.
    ``warnings`` are one-line notes on the bag as a whole (metadata.yaml disagreeing with the files,
    messages missing); ``missing`` maps a topic to the messages metadata.yaml counts on it that the
    storage files do not hold.
    """

    path: Path
    storage: str | None
    start_ns: int
    end_ns: int
    message_count: int
    topics: Mapping[str, TopicSummary] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    missing: Mapping[str, int] = field(default_factory=dict)

    @property
    def duration_ns(self) -> int:
        """Nanoseconds from the first to the last message (0 for an empty bag)."""
        return max(0, self.end_ns - self.start_ns) if self.message_count else 0

    @property
    def duration_s(self) -> float:
        return self.duration_ns * 1e-9


@dataclass(frozen=True)
class TopicCount:
    """One topic of a :class:`BagSummary`.

    Attributes:
        msgtype: message type in the storage files (metadata.yaml's when the files lack the topic;
            None if several).
        serialization_format: as declared: metadata.yaml's for a rosbag2 folder, else the storage
            file's ('cdr'); 'ros1' for a ROS 1 bag.
        count_metadata: messages metadata.yaml counts on it; for a bare storage file or a ROS 1 bag,
            the file's own index. None when metadata.yaml does not list the topic.
        count_read: messages actually read from the storage files (None if the summary was made
            without reading messages).
        note: why the package cannot deserialise the topic or how it worked around the bag ('' when
            all is well).
    """

    msgtype: str | None
    serialization_format: str
    count_metadata: int | None
    count_read: int | None
    note: str = ''


@dataclass(frozen=True)
class BagSummary:
    """What :func:`bag_summary` finds in a bag, for ``srmosaic inspect`` and tests.

    Attributes:
        path: the bag.
        storage: 'sqlite3', 'mcap' or 'rosbag1'.
        metadata_version: metadata.yaml's ``version`` (1..9); None for a bare storage file or a ROS 1
            bag.
        files: names of the storage files (as metadata.yaml lists them, or the file itself).
        compression: rosbag2 compression as '<format> <mode>' ('zstd file', 'zstd message'), ''
            when none (ROS 1 chunk compression is handled but not reported).
        start_ns: first message, nanoseconds since the epoch, as metadata.yaml (or the index) says;
            0 for an empty bag.
        duration_ns: nanoseconds from the first to the last message, as metadata.yaml (or the
            index) says; 0 for an empty bag.
        message_count: messages as metadata.yaml (or the index) counts.
        messages_read: messages actually read (None if not read).
        topics: per topic, sorted by name.
        warnings: one-line warnings on the bag as a whole.
        missing: per topic, messages metadata.yaml counts that the storage files do not hold.
        flight_topics: role ('image', 'camera_info', 'fix', 'imu') -> the topic :func:`read_flight`
            reads for it with the given TopicConfig (roles it would not read are absent).
        refusal: the one-line BagError message of :func:`read_flight` on this bag with that
            TopicConfig, '' when it reads the bag.
    """

    path: Path
    storage: str
    metadata_version: int | None
    files: tuple[str, ...]
    compression: str
    start_ns: int
    duration_ns: int
    message_count: int
    messages_read: int | None
    topics: Mapping[str, TopicCount]
    warnings: tuple[str, ...]
    missing: Mapping[str, int]
    flight_topics: Mapping[str, str]
    refusal: str
