"""msg_adapters: numpy/dataclasses <-> rclpy and rosbags messages, the same functions for both."""
from __future__ import annotations

import math
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

import msg_adapters as ma
from msg_adapters.image import _ENCODINGS
from srmosaic_ros.core.types import CameraIntrinsics, GeoFix, ImuSample
from srmosaic_ros.errors import ConfigError, MessageError

FLAVORS = ['rclpy', 'rosbags']
ENCODINGS = list(ma.SUPPORTED_ENCODINGS)


def sample_pixels(encoding: str, height: int = 7, width: int = 5, seed: int = 0) -> np.ndarray:
    """Seeded pixels shaped and typed as ``encoding`` needs."""
    enc = _ENCODINGS[encoding]
    rng = np.random.default_rng(seed)
    dtype = np.uint8 if enc.itemsize == 1 else np.uint16
    shape = (height, width) if enc.channels == 1 else (height, width, enc.channels)
    return rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True).astype(dtype)


def expected_rgb_or_mono(pixels: np.ndarray, encoding: str) -> np.ndarray:
    order = _ENCODINGS[encoding].order
    return {
        'mono': pixels,
        'rgb': pixels,
        'rgba': pixels[..., :3],
        'bgr': pixels[..., ::-1],
        'bgra': pixels[..., 2::-1],
    }[order]


# -------------------------------------------------------------------------------------- images


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('pad', [0, 5])
@pytest.mark.parametrize('encoding', ENCODINGS)
def test_image_round_trip(encoding: str, pad: int, flavor: str) -> None:
    pixels = sample_pixels(encoding)
    row_bytes = pixels.shape[1] * _ENCODINGS[encoding].channels * _ENCODINGS[encoding].itemsize
    msg = ma.numpy_to_image(
        pixels, encoding, stamp_ns=1_700_000_000_123_456_789, frame_id='cam', flavor=flavor,
        step=row_bytes + pad,
    )
    assert msg.step == row_bytes + pad
    assert len(msg.data) == msg.height * msg.step
    assert ma.header_to_ns_frame(msg) == (1_700_000_000_123_456_789, 'cam')
    back = ma.image_to_numpy(msg)
    assert back.dtype == pixels.dtype
    assert back.dtype.isnative
    np.testing.assert_array_equal(back, pixels)
    rgb = ma.image_to_rgb_or_mono(msg)
    np.testing.assert_array_equal(rgb, expected_rgb_or_mono(pixels, encoding))
    assert rgb.ndim == 2 or rgb.shape[2] == 3
    assert rgb.flags.c_contiguous


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('encoding', ['mono16', '16UC1', 'rgb16', 'bgra16'])
@pytest.mark.parametrize('pad', [0, 3])
def test_image_big_endian(encoding: str, pad: int, flavor: str) -> None:
    pixels = sample_pixels(encoding, seed=3)
    pixels.reshape(-1)[0] = 0x0102
    row_bytes = pixels.shape[1] * _ENCODINGS[encoding].channels * 2
    msg = ma.numpy_to_image(pixels, encoding, flavor=flavor, is_bigendian=True, step=row_bytes + pad)
    assert bool(msg.is_bigendian)
    assert list(msg.data[:2]) == [0x01, 0x02]  # most significant byte first
    np.testing.assert_array_equal(ma.image_to_numpy(msg), pixels)
    little = ma.numpy_to_image(pixels, encoding, flavor=flavor)
    assert list(little.data[:2]) == [0x02, 0x01]


@pytest.mark.parametrize('flavor', FLAVORS)
def test_image_to_numpy_returns_a_copy(flavor: str) -> None:
    pixels = sample_pixels('rgb8')
    msg = ma.numpy_to_image(pixels, 'rgb8', flavor=flavor)
    out = ma.image_to_numpy(msg)
    out[...] = 0
    np.testing.assert_array_equal(ma.image_to_numpy(msg), pixels)
    data = msg.data if flavor == 'rosbags' else np.frombuffer(msg.data, np.uint8)
    assert not np.shares_memory(ma.image_to_numpy(msg), data)
    assert not np.shares_memory(ma.image_to_rgb_or_mono(msg), data)


def test_image_accepts_plain_bytes_data() -> None:
    pixels = sample_pixels('bgr8')
    msg = SimpleNamespace(
        height=7, width=5, encoding='bgr8', is_bigendian=0, step=15, data=pixels.tobytes(),
    )
    np.testing.assert_array_equal(ma.image_to_numpy(msg), pixels)
    np.testing.assert_array_equal(ma.image_to_rgb_or_mono(msg), pixels[..., ::-1])


def _valid_image(flavor: str):
    return ma.numpy_to_image(sample_pixels('rgb8'), 'rgb8', flavor=flavor)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_image_unsupported_encoding(flavor: str) -> None:
    msg = _valid_image(flavor)
    msg.encoding = 'yuv422'
    for func in (ma.image_to_numpy, ma.image_to_rgb_or_mono):
        with pytest.raises(MessageError, match=r"Image\.encoding 'yuv422' is not supported.*mono8"):
            func(msg)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_image_wrong_data_length(flavor: str) -> None:
    msg = _valid_image(flavor)
    msg.data = msg.data[:-3]
    with pytest.raises(MessageError, match=r'Image\.data has 102 bytes but height\*step = 7\*15 = 105'):
        ma.image_to_numpy(msg)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_image_step_too_small(flavor: str) -> None:
    msg = _valid_image(flavor)
    msg.step = 14
    with pytest.raises(MessageError, match=r'Image\.step 14 is smaller than .* = 15'):
        ma.image_to_numpy(msg)


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('field', ['width', 'height'])
def test_image_zero_size(flavor: str, field: str) -> None:
    msg = _valid_image(flavor)
    setattr(msg, field, 0)
    with pytest.raises(MessageError, match=rf'Image\.{field} is 0'):
        ma.image_to_numpy(msg)


def test_numpy_to_image_refuses_bad_arrays() -> None:
    with pytest.raises(MessageError, match='needs a uint16 array'):
        ma.numpy_to_image(np.zeros((2, 2), np.uint8), 'mono16')
    with pytest.raises(MessageError, match=r'shape \(H, W, 3\)'):
        ma.numpy_to_image(np.zeros((2, 2), np.uint8), 'rgb8')
    with pytest.raises(MessageError, match='step 5 is smaller'):
        ma.numpy_to_image(np.zeros((2, 2, 3), np.uint8), 'rgb8', step=5)
    with pytest.raises(MessageError, match="encoding 'nv12' is not supported"):
        ma.numpy_to_image(np.zeros((2, 2), np.uint8), 'nv12')
    with pytest.raises(ConfigError, match="flavor 'ros1'"):
        ma.numpy_to_image(np.zeros((2, 2), np.uint8), 'mono8', flavor='ros1')


# ------------------------------------------------------------------------------ compressed images


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('fmt', ['jpeg', 'png'])
@pytest.mark.parametrize('channels', [1, 3])
def test_compressed_round_trip(flavor: str, fmt: str, channels: int) -> None:
    yy, xx = np.mgrid[0:32, 0:48]
    mono = ((xx * 5 + yy * 3) % 256).astype(np.uint8)
    pixels = mono if channels == 1 else np.stack([mono, 255 - mono, np.full_like(mono, 90)], axis=2)
    msg = ma.numpy_to_compressed(pixels, fmt=fmt, quality=95, stamp_ns=42, frame_id='c', flavor=flavor)
    expected_format = f'mono8; {fmt} compressed mono8' if channels == 1 else f'rgb8; {fmt} compressed bgr8'
    assert msg.format == expected_format
    assert ma.is_compressed_image(msg)
    assert ma.header_to_ns_frame(msg) == (42, 'c')
    back = ma.image_to_rgb_or_mono(msg)
    assert back.shape == pixels.shape
    assert back.dtype == np.uint8
    if fmt == 'png':
        np.testing.assert_array_equal(back, pixels)
    else:
        error = np.abs(back.astype(int) - pixels).mean()
        assert error < 8.0  # lossy values ...
        if channels == 3:  # ... but the channel order is right
            assert np.abs(back[..., ::-1].astype(int) - pixels).mean() > 10 * error


@pytest.mark.parametrize('flavor', FLAVORS)
def test_compressed_png_16bit(flavor: str) -> None:
    pixels = sample_pixels('mono16', 9, 11)
    msg = ma.numpy_to_compressed(pixels, fmt='png', flavor=flavor)
    assert msg.format == 'mono16; png compressed mono16'
    np.testing.assert_array_equal(ma.image_to_rgb_or_mono(msg), pixels)
    with pytest.raises(MessageError, match='jpeg cannot hold a uint16'):
        ma.numpy_to_compressed(pixels, fmt='jpeg', flavor=flavor)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_compressed_undecodable(flavor: str) -> None:
    msg = ma.numpy_to_compressed(np.zeros((8, 8, 3), np.uint8), flavor=flavor)
    msg.data = msg.data[: len(msg.data) // 4]
    with pytest.raises(MessageError, match=r'CompressedImage\.data .* cannot be decoded'):
        ma.image_to_rgb_or_mono(msg)
    msg.data = msg.data[:0]
    with pytest.raises(MessageError, match=r'CompressedImage\.data is empty'):
        ma.image_to_rgb_or_mono(msg)


def test_compressed_bad_fmt() -> None:
    with pytest.raises(MessageError, match="fmt 'webp' is not supported"):
        ma.numpy_to_compressed(np.zeros((4, 4), np.uint8), fmt='webp')


# --------------------------------------------------------------------------------- camera info

INTRINSICS = CameraIntrinsics(640, 480, 500.5, 501.25, 319.5, 239.75, 'plumb_bob', (-0.1, 0.01, 0.001, 0.0, 0.0))


@pytest.mark.parametrize('flavor', FLAVORS)
def test_camera_info_round_trip(flavor: str) -> None:
    msg = ma.intrinsics_to_camera_info(INTRINSICS, stamp_ns=5, frame_id='cam', flavor=flavor)
    assert list(msg.k) == [500.5, 0.0, 319.5, 0.0, 501.25, 239.75, 0.0, 0.0, 1.0]
    assert list(msg.r) == [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    assert list(msg.p) == [500.5, 0.0, 319.5, 0.0, 0.0, 501.25, 239.75, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert ma.camera_info_to_intrinsics(msg) == INTRINSICS
    np.testing.assert_array_equal(ma.camera_info_to_intrinsics(msg).K, INTRINSICS.K)


def test_camera_info_ros1_field_names() -> None:
    ros1 = SimpleNamespace(
        width=640, height=480, distortion_model='plumb_bob', D=np.array(INTRINSICS.distortion),
        K=np.array([500.5, 0, 319.5, 0, 501.25, 239.75, 0, 0, 1.0]),
    )
    assert ma.camera_info_to_intrinsics(ros1) == INTRINSICS


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize(('index', 'value'), [(0, 0.0), (4, 0.0), (0, math.nan), (4, -3.0)])
def test_camera_info_bad_focal(flavor: str, index: int, value: float) -> None:
    msg = ma.intrinsics_to_camera_info(INTRINSICS, flavor=flavor)
    k = [float(x) for x in msg.k]
    k[index] = value
    msg.k = k if flavor == 'rclpy' else np.array(k)
    with pytest.raises(MessageError, match=r'CameraInfo\.k has focal length f[xy]=.*uncalibrated'):
        ma.camera_info_to_intrinsics(msg)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_camera_info_zero_size(flavor: str) -> None:
    msg = ma.intrinsics_to_camera_info(INTRINSICS, flavor=flavor)
    msg.width = 0
    with pytest.raises(MessageError, match=r'CameraInfo\.width is 0'):
        ma.camera_info_to_intrinsics(msg)


# ------------------------------------------------------------------------------------- navsat

FIX = GeoFix(
    stamp_ns=1_700_000_000_000_000_001, latitude_deg=47.3977, longitude_deg=8.5456, altitude_m=488.5,
    status=0, position_covariance_m2=np.diag([1.0, 2.0, 4.0]), covariance_type=2, frame_id='gps',
)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_navsat_round_trip(flavor: str) -> None:
    back = ma.navsat_to_fix(ma.fix_to_navsat(FIX, flavor=flavor))
    assert (back.stamp_ns, back.latitude_deg, back.longitude_deg, back.altitude_m) == (
        FIX.stamp_ns, FIX.latitude_deg, FIX.longitude_deg, FIX.altitude_m,
    )
    assert (back.status, back.covariance_type, back.frame_id) == (0, 2, 'gps')
    np.testing.assert_array_equal(back.position_covariance_m2, FIX.position_covariance_m2)


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('field', ['latitude', 'longitude', 'altitude'])
def test_navsat_nan_field(flavor: str, field: str) -> None:
    msg = ma.fix_to_navsat(FIX, flavor=flavor)
    setattr(msg, field, math.nan)
    with pytest.raises(MessageError, match=rf'NavSatFix\.{field} is NaN'):
        ma.navsat_to_fix(msg)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_navsat_out_of_range(flavor: str) -> None:
    msg = ma.fix_to_navsat(FIX, flavor=flavor)
    msg.latitude = 91.0
    with pytest.raises(MessageError, match=r'NavSatFix\.latitude 91\.0 is outside'):
        ma.navsat_to_fix(msg)


# ---------------------------------------------------------------------------------------- imu


def _imu(orientation: np.ndarray | None) -> ImuSample:
    return ImuSample(
        stamp_ns=123_456_789_012, orientation_xyzw=orientation,
        angular_velocity_rad_s=np.array([0.1, -0.2, 0.3]),
        linear_acceleration_m_s2=np.array([0.0, 0.5, 9.81]),
        orientation_covariance=np.diag([0.01, 0.02, 0.03]), frame_id='imu',
    )


@pytest.mark.parametrize('flavor', FLAVORS)
def test_imu_round_trip(flavor: str) -> None:
    quat = np.array([0.1, -0.2, 0.3, 0.9])
    quat /= np.linalg.norm(quat)
    sample = _imu(quat)
    back = ma.imu_to_sample(ma.sample_to_imu(sample, flavor=flavor))
    assert back.stamp_ns == sample.stamp_ns
    assert back.frame_id == 'imu'
    assert back.orientation_xyzw is not None
    np.testing.assert_allclose(back.orientation_xyzw, quat, atol=1e-15)
    np.testing.assert_array_equal(back.angular_velocity_rad_s, sample.angular_velocity_rad_s)
    np.testing.assert_array_equal(back.linear_acceleration_m_s2, sample.linear_acceleration_m_s2)
    np.testing.assert_array_equal(back.orientation_covariance, sample.orientation_covariance)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_imu_without_orientation(flavor: str) -> None:
    msg = ma.sample_to_imu(_imu(None), flavor=flavor)
    assert msg.orientation_covariance[0] == -1.0
    msg.orientation.x = math.nan  # ignored: the message says there is no orientation
    assert ma.imu_to_sample(msg).orientation_xyzw is None


@pytest.mark.parametrize('flavor', FLAVORS)
def test_imu_rates_marked_missing_become_nan(flavor: str) -> None:
    """An Imu that gives orientation only (angular_velocity_covariance[0] = -1, zeros sent): the
    zeros must not reach the filter as a gyro measuring no rotation; NaN round-trips to -1."""
    msg = ma.sample_to_imu(_imu(np.array([0.0, 0.0, 0.0, 1.0])), flavor=flavor)
    msg.angular_velocity_covariance[0] = -1.0
    sample = ma.imu_to_sample(msg)
    assert np.all(np.isnan(sample.angular_velocity_rad_s))
    np.testing.assert_array_equal(sample.linear_acceleration_m_s2, [0.0, 0.5, 9.81])
    again = ma.sample_to_imu(sample, flavor=flavor)
    assert again.angular_velocity_covariance[0] == -1.0
    assert (again.angular_velocity.x, again.angular_velocity.y, again.angular_velocity.z) == (0.0, 0.0, 0.0)
    assert again.linear_acceleration_covariance[0] == 0.0


@pytest.mark.parametrize('flavor', FLAVORS)
def test_imu_normalises_quaternion(flavor: str) -> None:
    msg = ma.sample_to_imu(_imu(np.array([0.0, 0.0, 0.0, 2.0])), flavor=flavor)
    np.testing.assert_array_equal(ma.imu_to_sample(msg).orientation_xyzw, [0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize('flavor', FLAVORS)
def test_imu_nan_and_zero_quaternion(flavor: str) -> None:
    msg = ma.sample_to_imu(_imu(np.array([0.0, 0.0, 0.0, 1.0])), flavor=flavor)
    msg.orientation.w = math.nan
    with pytest.raises(MessageError, match=r'Imu\.orientation .* is not finite'):
        ma.imu_to_sample(msg)
    msg.orientation.w = 0.0
    with pytest.raises(MessageError, match=r'Imu\.orientation is the zero quaternion'):
        ma.imu_to_sample(msg)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_imu_nan_angular_velocity(flavor: str) -> None:
    msg = ma.sample_to_imu(_imu(None), flavor=flavor)
    msg.angular_velocity.y = math.nan
    with pytest.raises(MessageError, match=r'Imu\.angular_velocity .* is not finite'):
        ma.imu_to_sample(msg)


# ------------------------------------------------------------------------------------- stamps


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('ns', [0, 1, 999_999_999, 1_000_000_000, 1_700_000_000_123_456_789, -1])
def test_stamp_round_trip(flavor: str, ns: int) -> None:
    stamp = ma.ns_to_stamp(ns, flavor)
    assert 0 <= stamp.nanosec < 1_000_000_000
    assert ma.stamp_to_ns(stamp) == ns


def test_stamp_out_of_range() -> None:
    with pytest.raises(MessageError, match='outside the int32 range'):
        ma.ns_to_stamp(2**31 * 1_000_000_000)
    with pytest.raises(MessageError, match='has no sec/nanosec'):
        ma.stamp_to_ns(object())


def test_import_needs_no_rclpy() -> None:
    code = (
        'import sys, msg_adapters, numpy as np\n'
        "m = msg_adapters.numpy_to_image(np.zeros((2, 2), np.uint8), 'mono8', flavor='rosbags')\n"
        'msg_adapters.image_to_numpy(m)\n'
        "assert not any(n.split('.')[0] in {'rclpy', 'sensor_msgs', 'std_msgs'} for n in sys.modules)\n"
    )
    subprocess.run([sys.executable, '-c', code], check=True)
