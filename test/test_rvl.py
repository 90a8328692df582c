"""RVL (``compressedDepth rvl``): the numpy and numba decoders against a test-side encoder.

``rvl_encoder.encode_rvl`` writes streams as compressed_depth_image_transport's CompressRVL
does; both decoders of ``obstacle_detection.ros.rvl`` must give the pixels back, equal to
each other, and refuse what is not a stream of the announced size. No ROS graph.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rvl_encoder import encode_rvl, rvl_message

from obstacle_detection.ros import RosInputError, frame_gate, rvl
from message_helpers import array_to_compressed_depth
from obstacle_detection.ros.compressed_depth import (
    CONFIG_HEADER_SIZE,
    compressed_depth_to_array,
)

STAMP = Time(sec=1700000000, nanosec=5)
RNG_SEED = 20261202
DECODERS: dict[str, Callable[[bytes, int], np.ndarray]] = {
    'numpy': rvl.decode_rvl.reference, 'compiled': rvl.decode_rvl.compiled}


def _runs(rng: np.random.Generator, size: int, zero_share: float = 0.3,
          high: int = 65535) -> np.ndarray:
    """Return (size,) uint16: runs of zeros and of random values (1..high), random lengths."""
    pixels = np.zeros(size, dtype=np.uint16)
    i = 0
    while i < size:
        length = int(rng.integers(1, 40))
        if rng.random() >= zero_share:
            pixels[i:i + length] = rng.integers(1, high, size=min(length, size - i),
                                                endpoint=True)
        i += length
    return pixels


EDGE_CASES = {
    'empty': np.zeros(0, np.uint16),
    'one zero': np.zeros(1, np.uint16),
    'one pixel': np.array([1234], np.uint16),
    'all zero': np.zeros(10_001, np.uint16),
    'all max': np.full(999, 65535, np.uint16),
    'largest steps': np.tile(np.array([1, 65535], np.uint16), 301),     # +65534, -65534
    'from zero to max': np.array([0, 65535, 0, 1, 0, 65535], np.uint16),
    'ends in zeros': np.array([5, 6, 7, 0, 0, 0], np.uint16),
    'starts with values': np.array([7, 7, 7, 0, 9], np.uint16),
    'odd size 3x5': np.arange(15, dtype=np.uint16) * 4099,
}


@pytest.mark.parametrize('decoder', sorted(DECODERS))
@pytest.mark.parametrize('case', sorted(EDGE_CASES))
def test_edge_cases_round_trip(decoder: str, case: str) -> None:
    pixels = EDGE_CASES[case]

    decoded = DECODERS[decoder](encode_rvl(pixels), pixels.size)

    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, pixels)


@pytest.mark.parametrize('decoder', sorted(DECODERS))
@pytest.mark.parametrize('shape', [(1, 1), (3, 5), (7, 11), (31, 17), (48, 64)])
def test_random_depth_with_zero_runs_round_trips(decoder: str, shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(RNG_SEED + shape[0])
    for zero_share, high in ((0.3, 65535), (0.8, 4500), (0.0, 9)):
        pixels = _runs(rng, shape[0] * shape[1], zero_share, high)
        np.testing.assert_array_equal(DECODERS[decoder](encode_rvl(pixels), pixels.size),
                                      pixels)


def test_compiled_and_numpy_decoders_agree_on_many_streams() -> None:
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(200):
        size = int(rng.integers(0, 600))
        pixels = _runs(rng, size, float(rng.random()), int(rng.integers(1, 65536)))
        stream = encode_rvl(pixels)
        np.testing.assert_array_equal(rvl.decode_rvl.compiled(stream, size),
                                      rvl.decode_rvl.reference(stream, size))


def test_decode_rvl_on_either_path(kernel_path: str) -> None:
    pixels = _runs(np.random.default_rng(RNG_SEED), 500)
    stream = encode_rvl(pixels)
    np.testing.assert_array_equal(rvl.decode_rvl(stream, pixels.size), pixels)


def _stream(pixels: list[int]) -> bytes:
    return encode_rvl(np.array(pixels, np.uint16))


def _words(*words: int) -> bytes:
    return struct.pack(f'<{len(words)}I', *words)


#: name -> (stream, pixels announced, what the refusal says)
CORRUPT = {
    'a word short': (_stream(list(range(1, 40)))[:-4], 39, 'truncated: its .* words end after'),
    'not whole words': (_stream(list(range(1, 40)))[:-1], 39, 'not whole 32-bit words'),
    'no data': (b'', 10, 'truncated'),
    'a word too many': (_stream([1, 2, 3]) + b'\x00' * 4, 3, 'words left after the last'),
    'more pixels than announced': (_stream([0] * 9 + [3] * 9), 10, 'run goes beyond'),
    'fewer pixels than announced': (_stream([4] * 9), 10, 'truncated'),
    # zeros 0, non-zeros 1, then a 7-nibble code: 2^18 - 1 > 131070
    'difference beyond 16 bits': (_words(0x01FFFFFF, 0x70000000), 1, 'beyond 16 bits'),
    # zeros 0, then a code of 12 nibbles
    'code too long': (_words(0x0FFFFFFF, 0xFFFF7000), 5, 'longer than 11 nibbles'),
}


@pytest.mark.parametrize('decoder', sorted(DECODERS))
@pytest.mark.parametrize('case', sorted(CORRUPT))
def test_corrupt_streams_are_refused_with_the_reason(decoder: str, case: str) -> None:
    stream, size, reason = CORRUPT[case]

    with pytest.raises(RosInputError, match=reason):
        DECODERS[decoder](stream, size)


def test_random_bytes_never_crash_a_decoder() -> None:
    """Garbage either decodes to some pixels or is refused; both decoders say the same."""
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(300):
        stream = rng.integers(0, 256, size=4 * int(rng.integers(0, 12)), dtype=np.uint8)
        size = int(rng.integers(0, 50))
        outcomes = []
        for decode in DECODERS.values():
            try:
                outcomes.append(decode(stream.tobytes(), size).tolist())
            except RosInputError:
                outcomes.append('refused')
        assert outcomes[0] == outcomes[1]


# --------------------------------------------------------------------------------------------
# In a CompressedImage ("<encoding>; compressedDepth rvl")


def _depth_mm(shape: tuple[int, int]) -> np.ndarray:
    rng = np.random.default_rng(RNG_SEED)
    return _runs(rng, shape[0] * shape[1], 0.2, 9000).reshape(shape)


@pytest.mark.parametrize('encoding', ['16UC1', 'mono16'])
@pytest.mark.parametrize('shape', [(424, 512), (1, 1), (5, 7)])
def test_16bit_rvl_message_is_bit_identical(encoding: str, shape: tuple[int, int]) -> None:
    depth = _depth_mm(shape)

    msg = rvl_message(depth, STAMP, 'cam', encoding=encoding)

    assert msg.format == f'{encoding}; compressedDepth rvl'
    decoded = compressed_depth_to_array(msg)
    assert decoded.dtype == np.uint16 and decoded.shape == shape
    np.testing.assert_array_equal(decoded, depth)


def test_32bit_rvl_message_gives_what_the_png_codec_gives() -> None:
    """32FC1: the same quantised inverse depth, coded by RVL instead of PNG."""
    rng = np.random.default_rng(RNG_SEED)
    depth = rng.uniform(0.3, 9.5, size=(60, 80)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.2] = np.nan

    decoded = compressed_depth_to_array(rvl_message(depth, STAMP, 'cam'))
    expected = compressed_depth_to_array(array_to_compressed_depth(depth, STAMP, 'cam'))

    np.testing.assert_array_equal(decoded, expected)   # NaN where expected is NaN
    assert np.isnan(decoded).sum() >= (np.isnan(depth)).sum()


def _with_data(msg: object, data: bytes) -> object:
    msg.data = data
    return msg


def _size_header(width: int, height: int, valid: bytes) -> bytes:
    return valid[:CONFIG_HEADER_SIZE] + struct.pack('<II', width, height)


@pytest.mark.parametrize(('change', 'reason'), [
    (lambda d: d[:-8], 'RVL stream truncated'),
    (lambda d: d[:CONFIG_HEADER_SIZE + 4], 'too short for the 12-byte ConfigHeader '
                                           'and the RVL image size'),
    (lambda d: _size_header(0, 424, d) + d[CONFIG_HEADER_SIZE + 8:],
     'announces 0x424 pixels: empty'),
    (lambda d: _size_header(70000, 70000, d) + d[CONFIG_HEADER_SIZE + 8:], 'more than 16,777,216'),
    (lambda d: _size_header(16, 24, d) + d[CONFIG_HEADER_SIZE + 8:], 'run goes beyond|words left'),
    (lambda d: struct.pack('<iff', 3, 0, 0) + d[CONFIG_HEADER_SIZE:], 'compression format 3'),
])
def test_bad_rvl_messages_are_refused_with_the_reason(change: Callable[[bytes], bytes],
                                                       reason: str) -> None:
    msg = rvl_message(_depth_mm((24, 32)), STAMP, 'cam')

    with pytest.raises(RosInputError, match=reason):
        compressed_depth_to_array(_with_data(msg, change(bytes(msg.data))))


def test_the_frame_gate_skips_a_corrupt_rvl_frame_with_the_reason() -> None:
    msg = rvl_message(_depth_mm((24, 32)), STAMP, 'cam')
    msg.data = bytes(msg.data)[:-8]

    verdict = frame_gate.decode(msg)

    assert isinstance(verdict, frame_gate.Skip) and verdict.kind == 'compressed'
    assert 'RVL stream truncated' in verdict.reason
