"""Tests of obstacle_detection.pipeline.median: every path equals scipy's median filter.

The tests that take the ``kernel_path`` fixture (test/conftest.py) run twice: with the
compiled kernel ('compiled', skipped without numba) and with the numpy / OpenCV code.
"""

import numpy as np
import pytest

from obstacle_detection.pipeline.depth import decode_depth, depth_lut
from obstacle_detection.pipeline.median import median_filter, median_of_codes, reference_median
from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE
from obstacle_detection.sim.scenes import render_scene

KERNELS = (1, 3, 5, 7, 17, 21)
# Sizes smaller than K (down to 1 x 1), odd sizes and one larger than two bands of rows.
SIZES = [(1, 1), (1, 6), (5, 1), (3, 4), (8, 13), (17, 16), (23, 31), (61, 70)]


def depth_mm_image(rng: np.random.Generator, shape: tuple[int, int],
                   zero_fraction: float = 0.3) -> np.ndarray:
    """uint16 mm frame: a smooth ramp with noise, zero (no return) pixels and a zero block."""
    h, w = shape
    ramp = 800 + 3000 * np.linspace(0, 1, h)[:, None] + 40 * np.linspace(0, 1, w)[None, :]
    mm = np.rint(ramp + rng.normal(0, 15, shape)).astype(np.uint16)
    mm[rng.random(shape) < zero_fraction] = 0
    mm[h // 3:h // 2, w // 4:w // 2] = 0
    return mm


def sample_images(rng: np.random.Generator, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """Named images of one shape: every dtype and value pattern the paths treat apart."""
    n = shape[0] * shape[1]
    with_nan = decode_depth(depth_mm_image(rng, shape))
    with_nan[rng.random(shape) < 0.2] = np.nan
    with_inf = decode_depth(depth_mm_image(rng, shape))
    with_inf[rng.random(shape) < 0.1] = np.inf
    return {
        'uint16_full_range': rng.integers(0, 65536, shape).astype(np.uint16),
        'uint16_mm_zero_holes': depth_mm_image(rng, shape, 0.45),
        'uint16_constant': np.full(shape, 1234, np.uint16),
        'uint16_extremes': rng.choice(np.array([0, 65535], np.uint16), shape),
        'float32_metres_zero_holes': decode_depth(depth_mm_image(rng, shape, 0.45)),
        'float32_nan_holes': with_nan,
        'float32_inf': with_inf,
        'float32_random': rng.normal(2.0, 1.5, shape).astype(np.float32),
        'float32_few_values': rng.choice(rng.normal(0, 1, max(n // 3, 1)), shape).astype(
            np.float32),
        'float64': rng.normal(0, 1, shape),
        'int16_negative': rng.integers(-1000, 1000, shape).astype(np.int16),
        'uint8': rng.integers(0, 256, shape).astype(np.uint8),
    }


_REFERENCE_CACHE: dict = {}


def cached_reference(key: tuple, image: np.ndarray, k: int) -> np.ndarray:
    """``reference_median(image, k)``, computed once per key for every path and test."""
    if key not in _REFERENCE_CACHE:
        _REFERENCE_CACHE[key] = reference_median(image, k)
    return _REFERENCE_CACHE[key]


@pytest.mark.parametrize('shape', SIZES)
def test_median_equals_the_reference(shape, kernel_path) -> None:
    rng = np.random.default_rng(sum(shape))
    # threads split the compiled kernel's rows; OpenCV and scipy take no threads argument
    thread_counts = (1, 2) if kernel_path == 'compiled' else (1,)
    for name, img in sample_images(rng, shape).items():
        for k in KERNELS:
            expected = cached_reference((shape, name, k), img, k)
            for threads in thread_counts:
                out = median_filter(img, k, threads)
                message = f'{name} K={k} threads={threads}'
                assert out.dtype == img.dtype and out.flags.c_contiguous, message
                np.testing.assert_array_equal(out, expected, err_msg=message)


# Whole frames: the compiled kernel's bands of rows at full size. On the reference path
# K = 17 is scipy itself and K = 5 is OpenCV, as on the compiled path: the small images
# above check that path.
@pytest.mark.parametrize('kernel_path', ['compiled'], indirect=True)
@pytest.mark.parametrize('name', ['corridor', 'people', 'farm_row'])
def test_median_of_kinect_frames_equals_the_reference(name, kernel_path) -> None:
    frame = render_scene(name, seed=1, intrinsics=KINECT_V2_SD, size=KINECT_V2_SD_SIZE)
    for k in (5, 17):
        expected = cached_reference((name, k), frame.depth_mm, k)
        for threads in (1, 2):
            np.testing.assert_array_equal(median_filter(frame.depth_mm, k, threads), expected)
        np.testing.assert_array_equal(median_filter(decode_depth(frame.depth_mm), k),
                                      np.take(depth_lut(1000.0), expected))


@pytest.mark.parametrize('k', [3, 5, 7, 17])
def test_median_of_codes_is_the_median_of_the_decoded_depth(k, kernel_path) -> None:
    rng = np.random.default_rng(k)
    codes = rng.integers(0, 9000, (30, 37)).astype(np.uint16)
    codes[rng.random(codes.shape) < 0.3] = 0
    for scale in (1000.0, 5000.0, 3.0):
        table = depth_lut(scale)
        got = median_of_codes(codes, k, table, threads=2)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, reference_median(table[codes], k))


def test_median_k1_is_a_copy(kernel_path) -> None:
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    out = median_filter(img, 1)
    np.testing.assert_array_equal(out, img)
    assert not np.shares_memory(out, img)


def test_median_fills_isolated_pepper_zero(kernel_path) -> None:
    img = np.full((9, 11), 1.5, np.float32)
    img[4, 5] = 0.0
    for k in (3, 5, 7):
        np.testing.assert_array_equal(median_filter(img, k), np.full_like(img, 1.5))


def test_median_removes_isolated_valid_pixel_among_zeros(kernel_path) -> None:
    img = np.zeros((9, 9), np.float32)
    img[4, 4] = 2.0
    for k in (3, 7):
        assert not median_filter(img, k).any()


def test_median_does_not_modify_input(kernel_path) -> None:
    img = depth_mm_image(np.random.default_rng(2), (20, 20))
    before = img.copy()
    for k in (5, 7):
        median_filter(img, k)
        median_filter(decode_depth(img), k)
    np.testing.assert_array_equal(img, before)
