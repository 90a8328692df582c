"""Tests of the compressed depth codec (no rclpy.init, no ROS graph)."""

from __future__ import annotations

import struct
from collections.abc import Callable

import cv2
import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CompressedImage

from message_helpers import (array_to_compressed_depth, depth_message_to_array,
                             quantisation_constants, quantisation_error_bound_m)
from obstacle_detection.ros.compressed_depth import (
    CONFIG_HEADER_SIZE,
    compressed_depth_to_array,
    parse_format,
    raw_topic,
)
from obstacle_detection.ros import RosInputError
from obstacle_detection.ros.conversions import array_to_image, image_to_array

STAMP = Time(sec=1700000000, nanosec=123456789)
RNG_SEED = 20261201
SHAPE = (424, 512)


def _depth_mm(shape: tuple[int, int] = SHAPE, high_mm: int = 10000) -> np.ndarray:
    """Millimetres 0..high_mm with holes, and a byte-asymmetric corner (0x0102)."""
    rng = np.random.default_rng(RNG_SEED)
    depth = rng.integers(500, high_mm, size=shape, endpoint=True).astype(np.uint16)
    depth[rng.random(shape) < 0.1] = 0
    depth[0, 0] = 0x0102
    return depth


def _depth_m(shape: tuple[int, int] = SHAPE) -> np.ndarray:
    """Metres 0.2-9.9 m with NaN, 0, inf, negative and beyond-depth_max pixels."""
    rng = np.random.default_rng(RNG_SEED)
    depth = rng.uniform(0.2, 9.9, size=shape).astype(np.float32)
    depth[0, :5] = [np.nan, 0.0, np.inf, -1.0, 12.0]
    return depth


def _png(array: np.ndarray) -> bytes:
    return cv2.imencode('.png', array)[1].tobytes()


def _tiff(array: np.ndarray) -> bytes:
    return cv2.imencode('.tif', array)[1].tobytes()


def _message(fmt: str, data: bytes) -> CompressedImage:
    return CompressedImage(format=fmt, data=data)


def _garbage_header() -> bytes:
    """Return a ConfigHeader as iai_kinect2 and the ROS 2 16-bit encoder leave it (junk quant)."""
    return struct.pack('<iff', 0, float('nan'), -3.0e38)


# --------------------------------------------------------------------------------------------
# 16UC1: lossless


@pytest.mark.parametrize('encoding', ['16UC1', 'mono16'])
def test_16bit_round_trip_is_bit_identical(encoding: str) -> None:
    depth = _depth_mm()

    msg = array_to_compressed_depth(depth, STAMP, 'kinect2_ir_optical_frame', encoding=encoding)

    assert msg.format == f'{encoding}; compressedDepth png'
    assert (msg.header.stamp, msg.header.frame_id) == (STAMP, 'kinect2_ir_optical_frame')
    decoded = compressed_depth_to_array(msg)
    assert decoded.dtype == np.uint16 and decoded.shape == SHAPE
    np.testing.assert_array_equal(decoded, depth)


def test_16bit_equals_what_image_to_array_gives_for_the_raw_image() -> None:
    depth = _depth_mm()
    raw = array_to_image(depth, stamp=STAMP, frame_id='f', encoding='16UC1')
    compressed = array_to_compressed_depth(depth, STAMP, 'f')

    from_raw = depth_message_to_array(raw)
    from_compressed = depth_message_to_array(compressed)
    assert from_compressed.shape == SHAPE

    np.testing.assert_array_equal(from_compressed, image_to_array(raw))
    np.testing.assert_array_equal(from_compressed, from_raw)


def test_16bit_values_beyond_depth_max_are_zeroed_as_the_encoder_does() -> None:
    depth = np.array([[0, 1000, 3999, 4000, 4001, 65535]], dtype=np.uint16)

    decoded = compressed_depth_to_array(
        array_to_compressed_depth(depth, STAMP, 'f', depth_max_m=4.0))

    np.testing.assert_array_equal(decoded, [[0, 1000, 3999, 4000, 0, 0]])


def test_16bit_header_names_inv_depth_and_holds_a_png() -> None:
    data = bytes(array_to_compressed_depth(_depth_mm((4, 6)), STAMP, 'f').data)

    assert struct.unpack('<iff', data[:CONFIG_HEADER_SIZE]) == (0, 0.0, 0.0)
    assert data[CONFIG_HEADER_SIZE:CONFIG_HEADER_SIZE + 8] == b'\x89PNG\r\n\x1a\n'


@pytest.mark.parametrize(('fmt', 'build'), [
    ('16UC1; compressedDepth', lambda a: _garbage_header() + _png(a)),   # iai_kinect2, use_png
    ('16UC1; compressedDepth', lambda a: _garbage_header() + _tiff(a)),  # iai_kinect2 default
    ('16UC1', lambda a: _garbage_header() + _png(a)),                    # oldest compressedDepth
    ('16UC1; png compressed ', _png),                                    # no header
    ('16UC1; tiff compressed', _tiff),                                   # no header
    ('mono16; png compressed mono16', _png),                             # compressed transport
], ids=['iai-png', 'iai-tiff', 'legacy', 'png', 'tiff', 'mono16'])
def test_iai_kinect2_and_headerless_variants_decode_bit_identical(
        fmt: str, build: Callable[[np.ndarray], bytes]) -> None:
    depth = _depth_mm((60, 80))

    decoded = compressed_depth_to_array(_message(fmt, build(depth)))

    np.testing.assert_array_equal(decoded, depth)


# --------------------------------------------------------------------------------------------
# 32FC1: inverse depth quantisation


def test_32bit_constants_and_header_are_the_publishers_defaults() -> None:
    quant_a, quant_b = quantisation_constants()  # depth_max 10 m, depth_quantization 100
    msg = array_to_compressed_depth(np.ones((2, 3), np.float32), STAMP, 'f')

    assert (quant_a, quant_b) == (100.0 * 101.0, 1.0 - 10100.0 / 10.0)
    assert msg.format == '32FC1; compressedDepth png'
    assert struct.unpack('<iff', bytes(msg.data)[:CONFIG_HEADER_SIZE]) == (0, 10100.0, -1009.0)


def test_32bit_quantised_values_follow_the_inverse_depth_formula() -> None:
    # q = trunc(10100 / d - 1009): 1 m -> 9091, 2 m -> 4041, 3 m -> 2357 (3366.67 - 1009).
    depth = np.array([[1.0, 2.0, 3.0, np.nan, 10.0, 0.0]], dtype=np.float32)
    data = bytes(array_to_compressed_depth(depth, STAMP, 'f').data)

    quantised = cv2.imdecode(np.frombuffer(data[CONFIG_HEADER_SIZE:], np.uint8),
                             cv2.IMREAD_UNCHANGED)

    np.testing.assert_array_equal(quantised, [[9091, 4041, 2357, 0, 0, 0]])


def test_32bit_round_trip_is_within_the_quantisation_error() -> None:
    depth = _depth_m()
    decoded = compressed_depth_to_array(array_to_compressed_depth(depth, STAMP, 'f'))

    valid = np.isfinite(depth) & (depth > 0) & (depth < 10.0)
    error = decoded[valid].astype(np.float64) - depth[valid]
    bound = quantisation_error_bound_m(depth[valid].astype(np.float64))
    ulp = 4 * np.spacing(depth[valid]).astype(np.float64)  # float32 rounding of A/d + B, A/(q-B)
    assert decoded.dtype == np.float32
    assert np.all(error >= -ulp) and np.all(error <= bound + ulp)
    assert error.max() > 0.5 * bound.max()  # the bound is reached, not loose by far
    assert np.isnan(decoded[~valid]).all()  # NaN, 0, inf, -1, beyond depth_max: no return


def test_32bit_error_bound_is_two_millimetres_at_kinect_range() -> None:
    assert quantisation_error_bound_m(4.5) == pytest.approx(4.5 ** 2 / (10100 - 4.5))
    assert 0.0020 < quantisation_error_bound_m(4.5) < 0.0021


def test_32bit_too_near_to_quantise_is_no_return_not_a_wrapped_value() -> None:
    # A / (65535 - B) = 10100 / 66544 = 0.1518 m: nearer would overflow uint16.
    depth = np.array([[0.1, 0.152, 0.5]], dtype=np.float32)

    decoded = compressed_depth_to_array(array_to_compressed_depth(depth, STAMP, 'f'))

    assert np.isnan(decoded[0, 0])
    np.testing.assert_allclose(decoded[0, 1:], depth[0, 1:], atol=1e-4)


# --------------------------------------------------------------------------------------------
# rosbags messages (ROS 2 and ROS 1)


def test_rosbags_ros2_message_decodes_like_the_rclpy_one() -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    for depth in (_depth_mm((30, 40)), _depth_m((30, 40))):
        msg = array_to_compressed_depth(depth, STAMP, 'f')
        rosbags_msg = store.deserialize_cdr(serialize_message(msg),
                                            'sensor_msgs/msg/CompressedImage')

        assert isinstance(rosbags_msg.data, np.ndarray)
        np.testing.assert_array_equal(compressed_depth_to_array(rosbags_msg),
                                      compressed_depth_to_array(msg))


def test_rosbags_ros1_message_from_iai_kinect2_decodes() -> None:
    store = get_typestore(Stores.ROS1_NOETIC)
    compressed = store.types['sensor_msgs/msg/CompressedImage']
    header = store.types['std_msgs/msg/Header']
    time = store.types['builtin_interfaces/msg/Time']
    depth = _depth_mm((30, 40))
    msg = compressed(header=header(seq=7, stamp=time(sec=5, nanosec=0), frame_id='f'),
                     format='16UC1; compressedDepth',
                     data=np.frombuffer(_garbage_header() + _tiff(depth), np.uint8))
    wire = store.serialize_ros1(msg, 'sensor_msgs/msg/CompressedImage')

    decoded = compressed_depth_to_array(
        store.deserialize_ros1(wire, 'sensor_msgs/msg/CompressedImage'))

    np.testing.assert_array_equal(decoded, depth)


# --------------------------------------------------------------------------------------------
# Refusals, each with its reason


def _valid_data() -> bytes:
    return bytes(array_to_compressed_depth(_depth_mm((20, 30)), STAMP, 'f').data)


def _flip(data: bytes, index: int) -> bytes:
    damaged = bytearray(data)
    damaged[index] ^= 0xFF
    return bytes(damaged)


def _idat_offset(data: bytes) -> int:
    return data.index(b'IDAT') + 8


BAD = {
    'truncated png': ('16UC1; compressedDepth png', lambda: _valid_data()[:-30],
                      'corrupt PNG: OpenCV cannot decode'),
    'flipped png byte': ('16UC1; compressedDepth png',
                         lambda: _flip(_valid_data(), _idat_offset(_valid_data())),
                         'corrupt PNG: OpenCV cannot decode'),
    'too short': ('16UC1; compressedDepth png', lambda: b'\x00' * 5,
                  'has 5 bytes: too short for the 12-byte ConfigHeader'),
    'other compression': ('16UC1; compressedDepth png',
                          lambda: struct.pack('<iff', 7, 0, 0) + _valid_data()[12:],
                          'compression format 7, expected 0'),
    'no png after header': ('16UC1; compressedDepth png',
                            lambda: _valid_data()[:12] + b'GIF89a' + b'\x00' * 40,
                            'no PNG or TIFF after the 12-byte ConfigHeader'),
    'colour image': ('bgr8; jpeg compressed bgr8', _valid_data,
                     "must be a depth encoding .*got 'bgr8'"),
    'rvl with a png inside': ('16UC1; compressedDepth rvl', _valid_data,
                              'RVL image announces 1196314761x169478669 pixels: more than'),
    'jpeg': ('16UC1; jpeg compressed', _valid_data, 'JPEG is lossy'),
    'unknown': ('16UC1; zstd', _valid_data, 'unknown compressed depth format'),
    '8-bit png': ('16UC1; png compressed',
                  lambda: _png(np.zeros((4, 4), np.uint8)),
                  'PNG holds 1 channel.s. of uint8, expected one channel of uint16'),
    'rgb png': ('16UC1; png compressed',
                lambda: _png(np.zeros((4, 4, 3), np.uint16)), '3 channel.s. of uint16'),
    'corrupt tiff': ('16UC1; compressedDepth',
                     lambda: _garbage_header() + _tiff(_depth_mm((20, 30)))[:200],
                     'corrupt TIFF: OpenCV cannot decode'),
    '32FC1 without header': ('32FC1; png compressed', lambda: _png(np.ones((4, 4), np.uint16)),
                             'quantisation parameters .* missing'),
    '32FC1 zero quantA': ('32FC1; compressedDepth png',
                          lambda: struct.pack('<iff', 0, 0.0, 1.0)
                          + _png(np.ones((4, 4), np.uint16)),
                          'depthQuantA=0'),
}


@pytest.mark.parametrize('case', sorted(BAD))
def test_bad_data_is_refused_with_the_reason(case: str, capfd: pytest.CaptureFixture[str]
                                              ) -> None:
    fmt, make, reason = BAD[case]
    msg = _message(fmt, make())

    with pytest.raises(RosInputError, match=reason) as caught:
        compressed_depth_to_array(msg)

    assert isinstance(caught.value, RosInputError) and isinstance(caught.value, ValueError)
    err = capfd.readouterr().err   # the reason is in the exception (libpng may add its own line)
    assert all(line.startswith('libpng error') for line in err.splitlines()), err


@pytest.mark.parametrize(('kwargs', 'reason'), [
    ({'depth_max_m': 0.5}, 'depth_max_m=0.5 outside'),
    ({'depth_quantization': 200.0}, 'depth_quantization=200.0 outside'),
    ({'png_level': 10}, 'png_level=10'),
    ({'encoding': '32FC1'}, "encoding '32FC1' does not fit a uint16 array"),
])
def test_encoder_refuses_bad_parameters(kwargs: dict, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        array_to_compressed_depth(_depth_mm((4, 4)), STAMP, 'f', **kwargs)


def test_encoder_refuses_an_array_that_is_not_depth() -> None:
    with pytest.raises(RosInputError, match=r'shape \(4, 4, 3\) of uint8'):
        array_to_compressed_depth(np.zeros((4, 4, 3), np.uint8), STAMP, 'f')


# --------------------------------------------------------------------------------------------
# Names


@pytest.mark.parametrize(('fmt', 'expected'), [
    ('16UC1; compressedDepth png', ('16UC1', False)),
    ('32FC1; compressedDepth png', ('32FC1', False)),
    ('16UC1; compressedDepth rvl', ('16UC1', True)),
    ('32FC1; compressedDepth rvl', ('32FC1', True)),
    ('16UC1; compressedDepth', ('16UC1', False)),
    ('mono16', ('mono16', False)),
    ('16UC1; tiff compressed', ('16UC1', False)),
])
def test_parse_format(fmt: str, expected: tuple[str, bool]) -> None:
    assert parse_format(fmt) == expected


@pytest.mark.parametrize(('topic', 'raw'), [
    ('/kinect2/sd/image_depth_rect/compressed', '/kinect2/sd/image_depth_rect'),
    ('/kinect2/sd/image_depth_rect/compressedDepth', '/kinect2/sd/image_depth_rect'),
    ('/kinect2/sd/image_depth_rect', '/kinect2/sd/image_depth_rect'),
    ('compressed', 'compressed'),
])
def test_raw_topic(topic: str, raw: str) -> None:
    assert raw_topic(topic) == raw
