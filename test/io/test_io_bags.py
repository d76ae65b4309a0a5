"""srmosaic_ros.io.bags: real bags written into tmp_path, every storage and encoding."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import msg_adapters as ma
from msg_adapters.image import _ENCODINGS
from srmosaic_ros.core.types import CameraIntrinsics, Frame, GeoFix, ImuSample
from srmosaic_ros.errors import BagError
from srmosaic_ros.io.bags import BagWriter, TopicConfig, inspect_bag, read_flight
from cli_runner import run_cli

STORAGES = ['sqlite3', 'mcap']
T0 = 1_700_000_000_000_000_000
DT = 100_000_000  # 10 Hz frames
INTR = CameraIntrinsics(16, 12, 20.0, 21.0, 7.5, 5.5, 'plumb_bob', (0.01, 0.0, 0.0, 0.0, 0.0))
INTR2 = CameraIntrinsics(16, 12, 30.0, 31.0, 7.5, 5.5, 'plumb_bob', (0.0, 0.0, 0.0, 0.0, 0.0))


def pixels_for(encoding: str, index: int) -> np.ndarray:
    enc = _ENCODINGS[encoding]
    rng = np.random.default_rng(index)
    dtype = np.uint8 if enc.itemsize == 1 else np.uint16
    shape = (12, 16) if enc.channels == 1 else (12, 16, enc.channels)
    return rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True).astype(dtype)


def rgb_or_mono(pixels: np.ndarray, encoding: str) -> np.ndarray:
    order = _ENCODINGS[encoding].order
    return {'mono': pixels, 'rgb': pixels, 'rgba': pixels[..., :3], 'bgr': pixels[..., ::-1],
            'bgra': pixels[..., 2::-1]}[order]


def fix_at(i: int) -> GeoFix:
    return GeoFix(T0 + i * DT + 5, 47.0 + i * 1e-5, 8.0 - i * 1e-5, 500.0 + i, 0, np.eye(3) * 2.0, 2, 'gps')


def imu_at(i: int) -> ImuSample:
    quat = np.array([0.0, 0.0, np.sin(0.05 * i), np.cos(0.05 * i)])
    return ImuSample(T0 + i * DT + 7, quat, np.array([0.0, 0.0, 0.1]), np.array([0.0, 0.0, 9.81]),
                     np.eye(3) * 0.01, 'imu')


def write_flight(
    path: Path,
    storage: str,
    *,
    encoding: str = 'rgb8',
    frames: int = 4,
    image_topic: str = '/camera/image_raw',
    compressed: str = '',
    info_from: int = 0,
    with_telemetry: bool = True,
) -> list[np.ndarray]:
    """Frames every DT, camera info with each frame from ``info_from`` on, fix and imu between."""
    sent = []
    with BagWriter(path, storage=storage) as writer:
        for i in range(frames):
            t = T0 + i * DT
            if i >= info_from:
                writer.write('/camera/camera_info', ma.intrinsics_to_camera_info(
                    INTR, stamp_ns=t, frame_id='cam', flavor='rosbags'), t)
            if compressed:
                pixels = np.full((12, 16, 3), 40 * i, np.uint8)
                msg = ma.numpy_to_compressed(pixels, fmt=compressed, stamp_ns=t, frame_id='cam',
                                             flavor='rosbags')
            else:
                pixels = pixels_for(encoding, i)
                msg = ma.numpy_to_image(pixels, encoding, stamp_ns=t, frame_id='cam',
                                        flavor='rosbags', step=None if i % 2 else pixels[0].nbytes + 3)
            writer.write(image_topic, msg, t)
            sent.append(pixels)
            if with_telemetry:
                writer.write('/fix', ma.fix_to_navsat(fix_at(i), flavor='rosbags'), t + 5)
                writer.write('/imu/data', ma.sample_to_imu(imu_at(i), flavor='rosbags'), t + 7)
    return sent


def consume(path: Path, **kwargs: Any) -> list[Frame | GeoFix | ImuSample]:
    return list(read_flight(path, **kwargs))


# ----------------------------------------------------------------------------------- round trips


@pytest.mark.parametrize('storage', STORAGES)
@pytest.mark.parametrize('encoding', list(ma.SUPPORTED_ENCODINGS))
def test_flight_round_trip(tmp_path: Path, storage: str, encoding: str) -> None:
    bag = tmp_path / 'flight'
    sent = write_flight(bag, storage, encoding=encoding)
    reader = read_flight(bag)
    assert reader.frame_count == 4
    assert reader.image_topic == '/camera/image_raw'
    items = list(reader)
    assert reader.skipped == {}
    assert [type(x).__name__ for x in items] == ['Frame', 'GeoFix', 'ImuSample'] * 4
    stamps = [x.stamp_ns for x in items]
    assert stamps == sorted(stamps)
    frames = [x for x in items if isinstance(x, Frame)]
    for i, frame in enumerate(frames):
        assert frame.stamp_ns == T0 + i * DT
        assert frame.frame_id == 'cam'
        assert frame.camera == INTR
        assert frame.image.dtype == sent[i].dtype
        np.testing.assert_array_equal(frame.image, rgb_or_mono(sent[i], encoding))
    fixes = [x for x in items if isinstance(x, GeoFix)]
    imus = [x for x in items if isinstance(x, ImuSample)]
    for i, (fix, imu) in enumerate(zip(fixes, imus, strict=True)):
        want = fix_at(i)
        assert (fix.stamp_ns, fix.latitude_deg, fix.longitude_deg, fix.altitude_m) == (
            want.stamp_ns, want.latitude_deg, want.longitude_deg, want.altitude_m)
        np.testing.assert_array_equal(fix.position_covariance_m2, want.position_covariance_m2)
        assert imu.stamp_ns == imu_at(i).stamp_ns
        np.testing.assert_allclose(imu.orientation_xyzw, imu_at(i).orientation_xyzw, atol=1e-15)


@pytest.mark.parametrize('storage', STORAGES)
def test_inspect_bag(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    write_flight(bag, storage, frames=3)
    info = inspect_bag(bag)
    assert info.storage == storage
    assert info.message_count == 12
    assert info.start_ns == T0
    assert info.end_ns == T0 + 2 * DT + 7
    assert info.duration_ns == 2 * DT + 7
    assert info.topics['/camera/image_raw'].msgtype == 'sensor_msgs/msg/Image'
    assert {name: t.count for name, t in info.topics.items()} == {
        '/camera/camera_info': 3, '/camera/image_raw': 3, '/fix': 3, '/imu/data': 3}
    bare = next(p for p in bag.iterdir() if p.suffix in {'.db3', '.mcap'})
    assert inspect_bag(bare).storage == storage  # a bare storage file reads too
    assert len(consume(bare)) == 9


@pytest.mark.parametrize('storage', STORAGES)
def test_camera_info_look_ahead_and_update(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    with BagWriter(bag, storage=storage) as writer:
        for i in range(4):
            t = T0 + i * DT
            writer.write('/camera/image_raw', ma.numpy_to_image(
                np.zeros((12, 16), np.uint8), 'mono8', stamp_ns=t, flavor='rosbags'), t)
            if i in {1, 2}:  # first info after the first frame; a new one at frame 2
                intr = INTR if i == 1 else INTR2
                writer.write('/camera/camera_info',
                             ma.intrinsics_to_camera_info(intr, stamp_ns=t, flavor='rosbags'), t)
    frames = consume(bag)
    assert [f.camera for f in frames] == [INTR, INTR, INTR2, INTR2]  # type: ignore[union-attr]


@pytest.mark.parametrize('storage', STORAGES)
def test_no_camera_info_no_telemetry(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    with BagWriter(bag, storage=storage) as writer:
        writer.write('/camera/image_raw', ma.numpy_to_image(
            np.zeros((12, 16), np.uint8), 'mono8', stamp_ns=0, flavor='rosbags'), T0)
    (frame,) = consume(bag)
    assert isinstance(frame, Frame)
    assert frame.camera is None
    assert frame.stamp_ns == T0  # header stamp 0: the log time stands in


@pytest.mark.parametrize('storage', STORAGES)
@pytest.mark.parametrize('fmt', ['jpeg', 'png'])
def test_compressed_topic_fallback(tmp_path: Path, storage: str, fmt: str) -> None:
    bag = tmp_path / 'flight'
    sent = write_flight(bag, storage, image_topic='/camera/image_raw/compressed', compressed=fmt)
    reader = read_flight(bag)
    assert reader.image_topic == '/camera/image_raw/compressed'
    assert reader.image_msgtype == 'sensor_msgs/msg/CompressedImage'
    assert reader.frame_count == 4
    frames = [x for x in reader if isinstance(x, Frame)]
    assert len(frames) == 4
    for frame, pixels in zip(frames, sent, strict=True):
        assert frame.camera == INTR
        assert frame.image.shape == (12, 16, 3)
        np.testing.assert_allclose(frame.image, pixels, atol=0 if fmt == 'png' else 3)


def test_ros1_bag(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    types = store.types

    def header(t: int) -> Any:
        return types['std_msgs/msg/Header'](
            seq=0, stamp=types['builtin_interfaces/msg/Time'](sec=t // 10**9, nanosec=t % 10**9),
            frame_id='cam')

    bag = tmp_path / 'flight.bag'
    sent = [pixels_for('bgr8', i) for i in range(3)]
    k = np.array([INTR.fx, 0, INTR.cx, 0, INTR.fy, INTR.cy, 0, 0, 1.0])
    with Writer(bag) as writer:
        conns = {
            topic: writer.add_connection(topic, msgtype, typestore=store)
            for topic, msgtype in [('/camera/image_raw', 'sensor_msgs/msg/Image'),
                                   ('/camera/camera_info', 'sensor_msgs/msg/CameraInfo'),
                                   ('/fix', 'sensor_msgs/msg/NavSatFix')]
        }
        for i, pixels in enumerate(sent):
            t = T0 + i * DT
            info = types['sensor_msgs/msg/CameraInfo'](
                header=header(t), height=12, width=16, distortion_model='plumb_bob',
                D=np.array(INTR.distortion), K=k, R=np.eye(3).ravel(), P=np.zeros(12),
                binning_x=0, binning_y=0,
                roi=types['sensor_msgs/msg/RegionOfInterest'](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
            image = types['sensor_msgs/msg/Image'](
                header=header(t), height=12, width=16, encoding='bgr8', is_bigendian=0, step=48,
                data=pixels.reshape(-1).copy())
            fix = types['sensor_msgs/msg/NavSatFix'](
                header=header(t + 1), status=types['sensor_msgs/msg/NavSatStatus'](status=0, service=1),
                latitude=47.0, longitude=8.0, altitude=400.0 + i, position_covariance=np.zeros(9),
                position_covariance_type=0)
            for topic, msg in [('/camera/camera_info', info), ('/camera/image_raw', image),
                               ('/fix', fix)]:
                writer.write(conns[topic], t + (topic == '/fix'),
                             store.serialize_ros1(msg, msg.__msgtype__))
    assert inspect_bag(bag).storage == 'rosbag1'
    reader = read_flight(bag)
    assert reader.frame_count == 3
    items = list(reader)
    assert [type(x).__name__ for x in items] == ['Frame', 'GeoFix'] * 3
    for i, frame in enumerate(items[::2]):
        assert isinstance(frame, Frame)
        assert frame.camera == INTR
        assert frame.stamp_ns == T0 + i * DT
        np.testing.assert_array_equal(frame.image, sent[i][..., ::-1])
    assert [x.altitude_m for x in items[1::2]] == [400.0, 401.0, 402.0]  # type: ignore[union-attr]


@pytest.mark.parametrize('storage', STORAGES)
def test_bad_messages_are_skipped_and_counted(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    with BagWriter(bag, storage=storage) as writer:
        for i in range(5):
            t = T0 + i * DT
            image = ma.numpy_to_image(np.zeros((12, 16), np.uint8), 'mono8', stamp_ns=t, flavor='rosbags')
            if i in {1, 3}:
                image.encoding = 'yuv422'
            writer.write('/camera/image_raw', image, t)
            fix = ma.fix_to_navsat(fix_at(i), flavor='rosbags')
            if i == 2:
                fix.latitude = float('nan')
            writer.write('/fix', fix, t + 1)
    reader = read_flight(bag)
    assert reader.frame_count == 5
    items = list(reader)
    assert sum(isinstance(x, Frame) for x in items) == 3
    assert sum(isinstance(x, GeoFix) for x in items) == 4
    assert sum(reader.skipped.values()) == 3
    (image_key,) = [k for k in reader.skipped if k.startswith('/camera/image_raw: ')]
    assert "Image.encoding 'yuv422'" in image_key
    assert reader.skipped[image_key] == 2
    assert any(k.startswith('/fix: NavSatFix.latitude is NaN') for k in reader.skipped)


def test_custom_topics_and_rclpy_messages(tmp_path: Path) -> None:
    bag = tmp_path / 'flight'
    with BagWriter(bag, storage='mcap') as writer:
        writer.write('/cam/img', ma.numpy_to_image(np.full((2, 3), 7, np.uint8), 'mono8',
                                                   flavor='rclpy', stamp_ns=T0), T0)
        writer.write('/gps', ma.fix_to_navsat(fix_at(0), flavor='rclpy'), T0 + 1)
    assert writer.counts == {'/cam/img': 1, '/gps': 1}
    items = consume(bag, topics=TopicConfig(image='/cam/img', fix='/gps', camera_info='', imu=''))
    assert isinstance(items[0], Frame)
    np.testing.assert_array_equal(items[0].image, np.full((2, 3), 7, np.uint8))
    assert isinstance(items[1], GeoFix)
    assert items[1].latitude_deg == fix_at(0).latitude_deg


# --------------------------------------------------------------------------------------- errors


@pytest.mark.parametrize('storage', STORAGES)
def test_missing_image_topic(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    write_flight(bag, storage, image_topic='/down/image')
    with pytest.raises(BagError, match=r"no image topic '/camera/image_raw'") as info:
        read_flight(bag)
    text = str(info.value)
    assert '--image-topic' in text
    assert 'image topics present: /down/image' in text
    assert '/fix (sensor_msgs/msg/NavSatFix, 4 msgs)' in text
    reader = read_flight(bag, require_image=False)
    assert reader.frame_count == 0
    assert {type(x).__name__ for x in reader} == {'GeoFix', 'ImuSample'}
    assert len(consume(bag, topics=TopicConfig(image='/down/image'))) == 12


@pytest.mark.parametrize('storage', STORAGES)
def test_wrong_msgtype(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    with BagWriter(bag, storage=storage) as writer:
        writer.write('/camera/image_raw', ma.fix_to_navsat(fix_at(0), flavor='rosbags'), T0)
        writer.write('/fix', ma.sample_to_imu(imu_at(0), flavor='rosbags'), T0)
    pattern = (r"Topic '/camera/image_raw' .* has type 'sensor_msgs/msg/NavSatFix', but the image "
               r'topic must be sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage')
    with pytest.raises(BagError, match=pattern):
        read_flight(bag)
    with pytest.raises(BagError, match=r"Topic '/fix' .* type 'sensor_msgs/msg/Imu', but the fix topic must be sensor_msgs/msg/NavSatFix"):
        read_flight(bag, require_image=False, topics=TopicConfig(image=''))


def _storage_file(bag: Path) -> Path:
    return next(p for p in bag.iterdir() if p.suffix in {'.db3', '.mcap'})


@pytest.mark.parametrize('storage', STORAGES)
def test_truncated_bag(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    write_flight(bag, storage, frames=20)
    data = _storage_file(bag).read_bytes()
    _storage_file(bag).write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=r"flight'.*(truncated|corrupt|damaged)") as info:
        consume(bag)
    assert info.value.__cause__ is not None
    with pytest.raises(BagError):
        inspect_bag(bag)


def test_damage_found_while_iterating(tmp_path: Path) -> None:
    bag = tmp_path / 'flight'
    write_flight(bag, 'mcap', frames=20)
    path = _storage_file(bag)
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 2000] = b'\xff' * 2000  # chunk damaged, summary at the end intact
    path.write_bytes(bytes(data))
    reader = read_flight(bag)  # the index still reads
    assert reader.frame_count == 20
    with pytest.raises(BagError, match=r'is damaged: reading .* stopped after \d+ messages'):
        list(reader)


def test_damage_in_the_tail_keeps_the_frames_before_it(tmp_path: Path) -> None:
    """The demo flight as a chunked mcap, damaged at 85 %: the CameraInfo pre-read meets the damage
    first, and used to end the run before any frame (the frames before it are now read)."""
    from demo_bags import rewrite_demo

    bag = rewrite_demo(tmp_path / 'flight')
    path = _storage_file(bag)
    data = bytearray(path.read_bytes())
    at = len(data) * 85 // 100
    data[at:at + 4000] = b'\xff' * 4000
    path.write_bytes(bytes(data))
    frames = []
    with pytest.raises(BagError, match=r'is damaged: reading the flight stopped after \d+ messages'):
        frames.extend(item for item in read_flight(bag) if isinstance(item, Frame))
    assert 20 <= len(frames) < 60 and all(f.camera is not None for f in frames)


def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"Bag '.*nowhere' does not exist"):
        read_flight(tmp_path / 'nowhere')
    with pytest.raises(BagError, match='does not exist'):
        inspect_bag(tmp_path / 'nowhere.bag')


def test_not_a_bag(tmp_path: Path) -> None:
    text = tmp_path / 'notes.txt'
    text.write_text('hello')
    with pytest.raises(BagError, match=r"'.*notes.txt' is not a bag"):
        read_flight(text)
    for name in ('garbage.bag', 'garbage.mcap', 'garbage.db3'):
        (tmp_path / name).write_bytes(b'\x00garbage' * 100)
        with pytest.raises(BagError, match=rf"Cannot open bag '.*{name}'"):
            read_flight(tmp_path / name)
    with pytest.raises(BagError, match='folder without metadata.yaml'):
        read_flight(tmp_path)


@pytest.mark.parametrize('storage', STORAGES)
def test_metadata_missing_or_garbled(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    write_flight(bag, storage, frames=2)
    meta = bag / 'metadata.yaml'
    text = meta.read_text()
    meta.write_text(text.replace('rosbag2_bagfile_information', 'something_else'))
    with pytest.raises(BagError, match=r"Cannot open bag '.*flight'.*metadata key is missing"):
        read_flight(bag)
    meta.write_text('rosbag2_bagfile_information: [unclosed')
    with pytest.raises(BagError, match=r"Cannot open bag '.*flight'"):
        read_flight(bag)
    meta.unlink()
    with pytest.raises(BagError, match=r"folder without metadata.yaml.*pass that file itself"):
        read_flight(bag)
    assert len(consume(_storage_file(bag))) == 6  # as it says: the bare file reads


# --------------------------------------------------------------------------------------- writer


@pytest.mark.parametrize('storage', STORAGES)
def test_writer_refuses_existing_path(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'flight'
    write_flight(bag, storage, frames=2)
    with pytest.raises(BagError, match=r"'.*flight' exists already.*overwrite"):
        BagWriter(bag, storage=storage)
    with BagWriter(bag, storage=storage, overwrite=True) as writer:
        writer.write('/camera/image_raw', ma.numpy_to_image(
            np.zeros((3, 3), np.uint8), 'mono8', flavor='rosbags'), T0)
    assert inspect_bag(bag).message_count == 1


def test_writer_errors(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="storage 'zip' is not supported"):
        BagWriter(tmp_path / 'a', storage='zip')
    with BagWriter(tmp_path / 'b') as writer:
        writer.write('/fix', ma.fix_to_navsat(fix_at(0), flavor='rosbags'), T0)
        with pytest.raises(BagError, match=r"Topic '/fix' .* already carries 'sensor_msgs/msg/NavSatFix'"):
            writer.write('/fix', ma.sample_to_imu(imu_at(0), flavor='rosbags'), T0)
        with pytest.raises(BagError, match='neither a rosbags message'):
            writer.write('/x', object(), T0)
    with pytest.raises(BagError, match='not open'):
        writer.write('/fix', ma.fix_to_navsat(fix_at(0), flavor='rosbags'), T0)
    assert inspect_bag(tmp_path / 'b').message_count == 1


def test_bad_messages_are_counted_per_kind_not_per_message(tmp_path: Path) -> None:
    """Imu samples NaN at every stamp: one key with its count (it was one key per message)."""
    bag = tmp_path / 'flight'
    with BagWriter(bag, storage='mcap') as writer:
        for i in range(6):
            t = T0 + i * DT
            writer.write('/camera/image_raw', ma.numpy_to_image(np.zeros((12, 16), np.uint8), 'mono8', stamp_ns=t,
                                                                flavor='rosbags'), t)
            imu = ma.sample_to_imu(imu_at(i), flavor='rosbags')
            imu.linear_acceleration.x = float('nan')
            writer.write('/imu/data', imu, t + 7)
    reader = read_flight(bag)
    list(reader)
    imu_keys = [k for k in reader.skipped if k.startswith('/imu/data')]
    assert len(imu_keys) == 1 and reader.skipped[imu_keys[0]] == 6, reader.skipped


def test_a_bag_of_unusable_images_is_refused_with_the_reason(tmp_path: Path) -> None:
    """Every image in an unsupported encoding: exit 2 and the reason with its count (it was
    '0/0 frames in mosaic.png', exit 0, nothing said); no output written."""

    bag = tmp_path / 'flight'
    with BagWriter(bag, storage='mcap') as writer:
        for i in range(4):
            t = T0 + i * DT
            image = ma.numpy_to_image(np.zeros((12, 16), np.uint8), 'mono8', stamp_ns=t, flavor='rosbags')
            image.encoding = 'yuv422'
            writer.write('/camera/image_raw', image, t)
    out = tmp_path / 'out'
    run = run_cli('process', str(bag), '--out', str(out), '--no-progress')
    assert run.returncode == 2, (run.stdout, run.stderr)
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith('srmosaic process: error: no usable image in ') and "4 x /camera/image_raw: " in last
    assert 'yuv422' in last and 'Traceback' not in run.stderr
    assert not (out / 'mosaic.png').exists() and not (out / 'report.json').exists()


def test_camera_info_of_another_image_size(tmp_path: Path) -> None:
    """Images that change size mid-bag under one CameraInfo: those of the same aspect ratio get it
    scaled (said once, counted in ``adjusted``), those of another aspect ratio are skipped with the
    reason (they were used with the wrong intrinsics, the second half placed ~40 m off)."""
    camera = CameraIntrinsics(32, 24, 40.0, 40.0, 15.5, 11.5)
    bag = tmp_path / 'flight'
    with BagWriter(bag, storage='mcap') as writer:
        writer.write('/camera/camera_info', ma.intrinsics_to_camera_info(camera, stamp_ns=T0, flavor='rosbags'), T0)
        for i, (h, w) in enumerate([(24, 32), (24, 32), (48, 64), (48, 64), (24, 40)]):
            t = T0 + (i + 1) * DT
            writer.write('/camera/image_raw', ma.numpy_to_image(np.zeros((h, w), np.uint8), 'mono8', stamp_ns=t,
                                                                flavor='rosbags'), t)
    reader = read_flight(bag)
    frames = list(reader)
    assert [f.image.shape[1] for f in frames] == [32, 32, 64, 64]
    assert frames[0].camera == camera
    big = frames[2].camera
    assert (big.width, big.height, big.fx, big.cx, big.cy) == (64, 48, 80.0, 31.5, 23.5)
    assert list(reader.adjusted.values()) == [2]
    assert len(reader.skipped) == 1 and 'another aspect ratio' in next(iter(reader.skipped)), reader.skipped
