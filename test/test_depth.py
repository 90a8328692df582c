"""Tests of obstacle_detection.pipeline.depth: decoding, cropping, lookup (median: test_median)."""

import numpy as np
import pytest

from obstacle_detection.pipeline.depth import (DepthFormatError, crop_borders, decode_depth,
                                               depth_lut, lookup)


# --------------------------------------------------------------------------- decode


def test_decode_uint16_millimetres() -> None:
    raw = np.array([[0, 1, 1000], [1500, 4500, 65535]], dtype=np.uint16)
    out = decode_depth(raw)
    assert out.dtype == np.float32 and out.shape == raw.shape and out.flags.c_contiguous
    expected = np.array([[0.0, 0.001, 1.0], [1.5, 4.5, 65.535]], dtype=np.float32)
    np.testing.assert_array_equal(out, expected)


def test_decode_uint16_tum_scale_and_big_endian() -> None:
    raw = np.array([[0, 5000, 12345]], dtype=np.uint16)
    np.testing.assert_allclose(decode_depth(raw, depth_scale=5000),
                               [[0.0, 1.0, 2.469]], rtol=1e-7)
    big_endian = raw.astype('>u2')
    np.testing.assert_array_equal(decode_depth(big_endian, depth_scale=5000),
                                  decode_depth(raw, depth_scale=5000))


@pytest.mark.parametrize('dtype', [np.float32, np.float64])
def test_decode_float_invalid_values_become_zero(dtype) -> None:
    raw = np.array([[0.0, np.nan, np.inf, -np.inf], [-0.5, -0.0, 1.25, 3.0]], dtype=dtype)
    out = decode_depth(raw)
    assert out.dtype == np.float32 and out.flags.c_contiguous
    np.testing.assert_array_equal(out, [[0, 0, 0, 0], [0, 0, 1.25, 3.0]])
    assert not np.signbit(out).any()   # -0.0 is normalised to +0.0 as well
    assert raw[0, 1] != raw[0, 1]      # input untouched (still NaN)


def test_decode_float64_beyond_float32_range_is_no_return() -> None:
    out = decode_depth(np.array([[1e300, 2.5]]))
    np.testing.assert_array_equal(out, [[0.0, 2.5]])


def test_decode_returns_contiguous_copy_of_a_view() -> None:
    base = np.arange(24, dtype=np.float32).reshape(4, 6) / 10
    view = base[:, ::2]
    out = decode_depth(view)
    assert out.flags.c_contiguous and not np.shares_memory(out, base)
    np.testing.assert_array_equal(out, view)


@pytest.mark.parametrize('dtype', [np.int8, np.uint8, np.bool_, np.complex64, np.int16,
                                   np.int32, np.float16])
def test_decode_rejects_bad_dtype(dtype) -> None:
    with pytest.raises(DepthFormatError, match=np.dtype(dtype).name):
        decode_depth(np.zeros((2, 3), dtype=dtype))


@pytest.mark.parametrize('shape', [(5,), (2, 3, 1), (0, 4), (3, 0), ()])
def test_decode_rejects_bad_shape(shape) -> None:
    with pytest.raises(DepthFormatError, match=r'shape \(' + ', ?'.join(map(str, shape))):
        decode_depth(np.zeros(shape, dtype=np.uint16))


def test_decode_format_error_is_a_value_error() -> None:
    assert issubclass(DepthFormatError, ValueError)


def test_decode_rejects_bad_scale() -> None:
    raw = np.ones((2, 2), np.uint16)
    for scale in (0, -1000, np.nan, np.inf):
        with pytest.raises(ValueError, match='depth_scale'):
            decode_depth(raw, depth_scale=scale)
    with pytest.raises(DepthFormatError, match='uint16'):
        decode_depth(np.ones((2, 2), np.float32), depth_scale=1000)


# --------------------------------------------------------------------------- crop


def test_crop_boundaries_exact() -> None:
    img = np.arange(1, 7 * 9 + 1, dtype=np.float32).reshape(7, 9)
    out = crop_borders(img, 1, 2, 3, 4)
    assert out.shape == img.shape and out.dtype == img.dtype and out.flags.c_contiguous
    assert not np.shares_memory(out, img)
    kept = np.zeros(img.shape, bool)
    kept[1:7 - 2, 3:9 - 4] = True
    np.testing.assert_array_equal(out[kept], img[kept])
    assert (out[~kept] == 0).all()
    # just inside kept, just outside zeroed
    assert out[1, 3] == img[1, 3] and out[4, 4] == img[4, 4]
    assert out[0, 3] == 0 and out[5, 3] == 0 and out[1, 2] == 0 and out[1, 5] == 0


def test_crop_zero_margins_is_a_copy() -> None:
    img = np.ones((3, 4), np.float32)
    out = crop_borders(img, 0, 0, 0, 0)
    np.testing.assert_array_equal(out, img)
    assert not np.shares_memory(out, img)


@pytest.mark.parametrize('margins', [(3, 0, 0, 0), (0, 3, 0, 0), (2, 1, 0, 0), (0, 0, 5, 0),
                                     (0, 0, 0, 5), (0, 0, 2, 3), (100, 100, 100, 100)])
def test_crop_covering_whole_image_gives_zeros(margins) -> None:
    out = crop_borders(np.ones((3, 5), np.float32), *margins)
    assert out.shape == (3, 5) and not out.any()


# --------------------------------------------------------------------------- lookup


def test_lookup_is_numpys_take(kernel_path) -> None:
    rng = np.random.default_rng(5)
    codes = rng.integers(0, 65536, (30, 41)).astype(np.uint16)
    for table in (depth_lut(1000.0), depth_lut(5000.0, 'float64'),
                  rng.normal(0, 1, 65536).astype(np.float32)):
        for view in (codes, codes[::2, 3:]):
            out = lookup(table, view)
            assert out.dtype == table.dtype and out.flags.c_contiguous
            np.testing.assert_array_equal(out, np.take(table, view))
