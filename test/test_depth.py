"""Tests of obstacle_detection.pipeline.depth (decode, crop) and .median (exact, vs. scipy).

The median tests that take the ``median_path`` fixture run twice: through the compiled network
of :mod:`obstacle_detection.pipeline._compiled.median` ('jit', skipped without numba) and
through the numpy / OpenCV code (``OBSTACLE_DETECTION_NO_JIT=1``).
"""

import warnings

import cv2
import numpy as np
import pytest
from scipy import ndimage

from obstacle_detection.pipeline import depth, jit, median
from obstacle_detection.pipeline._compiled import median as jit_median
from obstacle_detection.pipeline.depth import DepthFormatError, crop_borders, decode_depth
from obstacle_detection.pipeline.median import MEDIAN_MODE, median_filter
from obstacle_detection.sim.scenes import render_scene

ODD_K = list(range(1, 18, 2))
# Odd sizes, sizes smaller than K (down to 1 x 1) and one larger image.
SIZES = [(1, 1), (1, 6), (5, 1), (3, 4), (8, 13), (17, 16), (23, 31), (41, 38)]


def scipy_median(img: np.ndarray, k: int) -> np.ndarray:
    return ndimage.median_filter(img, size=k, mode=MEDIAN_MODE)


_SCIPY_CACHE: dict = {}


def scipy_median_cached(key: tuple, img: np.ndarray, k: int) -> np.ndarray:
    """Return scipy's median of a full frame, computed once for both median paths."""
    if (key, k) not in _SCIPY_CACHE:
        _SCIPY_CACHE[key, k] = scipy_median(img, k)
    return _SCIPY_CACHE[key, k]


@pytest.fixture(params=['jit', 'numpy'])
def median_path(request, monkeypatch) -> str:
    """Run the test with the compiled median ('jit') or with the numpy / OpenCV code."""
    if request.param == 'jit':
        if not jit_median.AVAILABLE:
            pytest.skip('numba is not installed')
        monkeypatch.delenv(jit.NO_JIT_ENV, raising=False)
        assert jit.enabled()
    else:
        monkeypatch.setenv(jit.NO_JIT_ENV, '1')
        assert not jit.enabled()
    return request.param


def depth_mm_image(rng: np.random.Generator, shape: tuple[int, int],
                   zero_fraction: float = 0.3) -> np.ndarray:
    """uint16 mm frame: a smooth ramp with noise, zero (no return) pixels and zero blocks."""
    h, w = shape
    ramp = 800 + 3000 * np.linspace(0, 1, h)[:, None] + 40 * np.linspace(0, 1, w)[None, :]
    mm = np.rint(ramp + rng.normal(0, 15, shape)).astype(np.uint16)
    mm[rng.random(shape) < zero_fraction] = 0
    mm[h // 3:h // 2, w // 4:w // 2] = 0
    return mm


def random_images(rng: np.random.Generator, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """Named test images of one shape covering every median code path."""
    n = shape[0] * shape[1]
    arbitrary_values = rng.normal(2.0, 1.5, size=max(n // 3, 1)).astype(np.float32)
    return {
        'uint16_full_range': rng.integers(0, 65536, size=shape).astype(np.uint16),
        'uint16_small_range': rng.integers(0, 200, size=shape).astype(np.uint16),
        'float32_mm_many_zeros': decode_depth(depth_mm_image(rng, shape, 0.45)),
        # arbitrary floats (not millimetres), some negative, <= 65536 distinct values
        'float32_arbitrary': rng.choice(arbitrary_values, size=shape),
    }


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


def test_crop_rejects_negative_margin() -> None:
    with pytest.raises(ValueError, match='left'):
        crop_borders(np.ones((3, 3), np.float32), 0, 0, -1, 0)


# --------------------------------------------------------------------------- median


@pytest.mark.parametrize('shape', SIZES)
def test_median_equals_scipy(shape, median_path) -> None:
    rng = np.random.default_rng(sum(shape))
    for name, img in random_images(rng, shape).items():
        for k in ODD_K:
            out = median_filter(img, k)
            assert out.dtype == img.dtype and out.shape == img.shape, name
            assert out.flags.c_contiguous, name
            np.testing.assert_array_equal(out, scipy_median(img, k), err_msg=f'{name} K={k}')


@pytest.mark.parametrize('k', [3, 7, 17])
def test_median_network_path_directly(k) -> None:
    """The sorting network itself on raw uint16, float32, float64 and int32 images."""
    rng = np.random.default_rng(k)
    for shape in [(2, 3), (19, 29), (33, 20)]:
        for img in (rng.integers(0, 65536, shape).astype(np.uint16),
                    rng.normal(0, 1, shape).astype(np.float32),
                    rng.normal(0, 1, shape),
                    rng.integers(-5, 5, shape).astype(np.int32)):
            np.testing.assert_array_equal(median._network_median(img, k), scipy_median(img, k))


def test_median_float32_with_more_than_65536_distinct_values(median_path) -> None:
    rng = np.random.default_rng(7)
    img = rng.random((300, 260), dtype=np.float32)
    assert np.unique(img).size > 65536
    for k in (5, 9):
        np.testing.assert_array_equal(median_filter(img, k), scipy_median(img, k))


def test_median_other_dtypes(median_path) -> None:
    rng = np.random.default_rng(3)
    imgs = [rng.integers(0, 256, (20, 25)).astype(np.uint8),
            decode_depth(depth_mm_image(rng, (20, 25))).astype(np.float64),
            rng.normal(0, 1, (20, 25)),
            rng.integers(-1000, 1000, (20, 25)).astype(np.int16)]
    for img in imgs:
        for k in (3, 5, 9, 15):
            np.testing.assert_array_equal(median_filter(img, k), scipy_median(img, k),
                                          err_msg=f'{img.dtype} K={k}')


def test_median_inf_and_nan_match_scipy(median_path) -> None:
    rng = np.random.default_rng(11)
    img = decode_depth(depth_mm_image(rng, (15, 18)))
    img[2, 3] = np.inf
    for k in (3, 7):
        np.testing.assert_array_equal(median_filter(img, k), scipy_median(img, k))
    img[5, 5] = np.nan   # delegated to scipy
    np.testing.assert_array_equal(median_filter(img, 5), scipy_median(img, 5))


def test_median_realistic_frame_size(median_path) -> None:
    rng = np.random.default_rng(5)
    img = decode_depth(depth_mm_image(rng, (424, 512), 0.05))
    for k in (5, 17):
        np.testing.assert_array_equal(median_filter(img, k),
                                      scipy_median_cached(('ramp', 5), img, k))


def test_median_k1_is_a_copy(median_path) -> None:
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    out = median_filter(img, 1)
    np.testing.assert_array_equal(out, img)
    assert not np.shares_memory(out, img)


def test_median_fills_isolated_pepper_zero(median_path) -> None:
    img = np.full((9, 11), 1.5, np.float32)
    img[4, 5] = 0.0
    for k in (3, 5, 7):
        np.testing.assert_array_equal(median_filter(img, k), np.full_like(img, 1.5))


def test_median_removes_isolated_valid_pixel_among_zeros(median_path) -> None:
    img = np.zeros((9, 9), np.float32)
    img[4, 4] = 2.0
    assert not median_filter(img, 3).any()


def test_median_does_not_modify_input(median_path) -> None:
    rng = np.random.default_rng(2)
    img = decode_depth(depth_mm_image(rng, (20, 20)))
    before = img.copy()
    median_filter(img, 7)
    np.testing.assert_array_equal(img, before)


@pytest.mark.parametrize('k', [0, -1, -3, 2, 4, 16])
def test_median_rejects_bad_kernel(k) -> None:
    with pytest.raises(ValueError, match='odd'):
        median_filter(np.ones((5, 5), np.float32), k)


def test_median_rejects_non_integer_kernel() -> None:
    with pytest.raises(TypeError):
        median_filter(np.ones((5, 5), np.float32), 3.0)


@pytest.mark.parametrize('img', [np.ones((5,), np.float32), np.ones((0, 3), np.float32),
                                 np.ones((2, 2, 2), np.float32), np.ones((3, 3), bool),
                                 np.ones((3, 3), np.complex64)])
def test_median_rejects_bad_image(img) -> None:
    with pytest.raises(DepthFormatError, match=r'shape|dtype'):
        median_filter(img, 3)


def test_median_decoded_frames_take_the_millimetre_key_path(median_path) -> None:
    rng = np.random.default_rng(4)
    mm = depth_mm_image(rng, (30, 40))
    frame = decode_depth(mm)
    keys, values = median._order_keys(frame)
    np.testing.assert_array_equal(keys, mm)       # millimetres, not ranks
    np.testing.assert_array_equal(np.take(values, keys), frame)
    if median_path == 'numpy':
        assert values is depth.depth_lut(depth.MM_PER_M, 'float32')
    tum = decode_depth(depth_mm_image(rng, (30, 40)), depth_scale=5000)  # rank path
    for k in (7, 11):
        np.testing.assert_array_equal(median_filter(tum, k), scipy_median(tum, k))


# --------------------------------------------------------------------------- median: two-pass


def scene_mm(name: str, seed: int = 0) -> np.ndarray:
    return render_scene(name, seed=seed).depth_mm


@pytest.mark.parametrize('name, k', [('corridor', 7), ('corridor', 17), ('farm_row', 9),
                                     ('farm_row', 17), ('step_down', 17)])
def test_median_kinect_frames_equal_scipy(name, k, median_path) -> None:
    """Full 512 x 424 frames, uint16 mm and float32 m (as the scene makes it, not LUT)."""
    frame = render_scene(name, seed=3)
    for img in (frame.depth_mm, frame.depth_m):
        out = median_filter(img, k)
        assert out.dtype == img.dtype and out.flags.c_contiguous
        np.testing.assert_array_equal(out, scipy_median_cached((name, 3, img.dtype.name), img, k),
                                      err_msg=str(img.dtype))


@pytest.mark.parametrize('name, k', [('people', 17), ('ramps', 19), ('dark_materials', 17)])
def test_median_two_pass_runs_and_is_exact(name, k) -> None:
    """The coarse + fine 8-bit passes handle Kinect frames (no network fallback)."""
    keys = scene_mm(name)
    out = median._two_pass_median(keys, k)
    assert out is not None and out.dtype == np.uint16 and out.flags.c_contiguous
    np.testing.assert_array_equal(out, scipy_median(keys, k))


@pytest.mark.parametrize('k', [21, 31])
def test_median_large_kernels_on_frame_crops(k, median_path) -> None:
    keys = scene_mm('people', seed=1)[60:260, 100:420]
    np.testing.assert_array_equal(median_filter(keys, k), scipy_median(keys, k))
    metres = keys.astype(np.float32) * np.float32(1e-3)
    np.testing.assert_array_equal(median_filter(metres, k), scipy_median(metres, k))


@pytest.mark.parametrize('shape', [(1, 1), (1, 40), (40, 1), (5, 7), (17, 17), (18, 16),
                                   (23, 31), (70, 45), (33, 300)])
def test_median_two_pass_small_and_odd_sizes(shape, median_path) -> None:
    """Images smaller than K, thin strips and sizes that are not tile multiples."""
    rng = np.random.default_rng(sum(shape))
    keys = depth_mm_image(rng, shape, 0.3)
    keys[0, 0] = 4500                       # 13-bit keys: the coarse shift is 5
    for k in (17, 21, 31):
        np.testing.assert_array_equal(median_filter(keys, k), scipy_median(keys, k),
                                      err_msg=f'K={k}')


def test_median_two_pass_depth_edges_and_steep_ramps() -> None:
    """Tiles spanning several 256 mm groups (edges), thin bands along rows and columns."""
    yy, xx = np.mgrid[0:300, 0:400]
    checker = np.where(((yy // 40) + (xx // 56)) % 2 == 0, 800, 4000)
    ramp_x = 500 + 15 * xx                           # 15 mm per column
    ramp_y = 600 + 12 * yy                           # 12 mm per row
    rng = np.random.default_rng(9)
    for base in (checker, ramp_x, np.minimum(ramp_y, 9000)):
        keys = np.clip(base + rng.normal(0, 12, base.shape), 0, 65535).astype(np.uint16)
        keys[rng.random(keys.shape) < 0.2] = 0
        out = median._two_pass_median(keys, 17)
        assert out is not None
        np.testing.assert_array_equal(out, scipy_median(keys, 17))


def test_median_two_pass_zero_level_resolution() -> None:
    """Zeros resolve from the coarse pass only when no other key shares their level."""
    rng = np.random.default_rng(12)
    keys = depth_mm_image(rng, (90, 120), 0.6)   # mostly zeros: many zero medians
    keys[0, 0] = 4000
    np.testing.assert_array_equal(median._two_pass_median(keys, 17), scipy_median(keys, 17))
    keys[rng.random(keys.shape) < 0.05] = 7      # a key in the zero level: no shortcut
    np.testing.assert_array_equal(median._two_pass_median(keys, 17), scipy_median(keys, 17))
    offset = np.where(keys == 0, 1000, keys + 1500).astype(np.uint16)   # lowest key 1000
    np.testing.assert_array_equal(median._two_pass_median(offset, 17),
                                  scipy_median(offset, 17))
    flat = np.full((30, 40), 1234, np.uint16)     # one key value: no fine pass at all
    np.testing.assert_array_equal(median._two_pass_median(flat, 17), flat)


def test_median_two_pass_falls_back_on_noise() -> None:
    """Full-range noise spans every 256-key group in every tile: the network takes over."""
    rng = np.random.default_rng(13)
    noise = rng.integers(0, 65536, (60, 80)).astype(np.uint16)
    assert median._two_pass_median(noise, 17) is None
    np.testing.assert_array_equal(median_filter(noise, 17), scipy_median(noise, 17))


def test_median_image_larger_than_the_largest_tile(median_path) -> None:
    yy, xx = np.mgrid[0:300, 0:700]
    rng = np.random.default_rng(14)
    keys = (700 + 3 * yy + 2 * xx + rng.normal(0, 10, yy.shape)).astype(np.uint16)
    np.testing.assert_array_equal(median_filter(keys, 17), scipy_median(keys, 17))


def test_order_keys_accepts_any_rounding_of_millimetres(median_path) -> None:
    """float32(mm) * 1e-3 (not decode_depth's rounding) still maps to the mm keys."""
    frame = render_scene('corridor')
    metres = frame.depth_m
    assert not np.array_equal(metres, decode_depth(frame.depth_mm))
    keys, values = median._order_keys(metres)
    np.testing.assert_array_equal(keys, frame.depth_mm)
    np.testing.assert_array_equal(np.take(values, keys), metres)
    tum = decode_depth(frame.depth_mm, depth_scale=5000)
    keys, values = median._order_keys(tum)
    np.testing.assert_array_equal(keys, frame.depth_mm)
    np.testing.assert_array_equal(np.take(values, keys), tum)
    if median_path == 'numpy':
        assert values is depth.depth_lut(5000.0, 'float32')


def test_order_keys_rejects_colliding_values(median_path) -> None:
    """Two values rounding to the same millimetre must not share a key (rank fallback)."""
    img = np.array([[1.0, 1.0002, 1.0004], [2.0, 0.0, 1.0001]], np.float32)
    keys, values = median._order_keys(img)
    np.testing.assert_array_equal(np.take(values, keys), img)
    assert np.unique(keys).size == np.unique(img).size
    order = np.argsort(img, axis=None, kind='stable')
    assert (np.diff(keys.ravel()[order].astype(int)) >= 0).all()


def test_median_two_pass_with_sparse_far_outliers() -> None:
    """65535 codes above mm depths (scattered and a patch): the keys are ranked first."""
    keys = scene_mm('corridor', seed=5)[:240, :320].copy()
    rng = np.random.default_rng(15)
    keys[rng.random(keys.shape) < 0.01] = 65535
    keys[100:160, 200:260] = 65535
    out = median._two_pass_median(keys, 17)
    assert out is not None
    np.testing.assert_array_equal(out, scipy_median(keys, 17))


# --------------------------------------------------------------------------- median: compiled

needs_numba = pytest.mark.skipif(not jit_median.AVAILABLE, reason='numba is not installed')


@needs_numba
@pytest.mark.parametrize('name, k', [('people', 7), ('ramps', 9), ('pitched_floor', 13),
                                     ('dark_materials', 17), ('step_down', 21)])
def test_jit_median_kinect_frames_equal_scipy(name, k, monkeypatch) -> None:
    """Full 512 x 424 frames through the compiled network, uint16 mm and float32 m.

    scipy runs once, on the millimetres: the scene's metres are ``float32(mm) * 1e-3``, a
    non-decreasing map, and the median of an odd count commutes with any such map, so scipy's
    median of the metres is the same map applied to its median of the millimetres.
    """
    monkeypatch.delenv(jit.NO_JIT_ENV, raising=False)
    frame = render_scene(name, seed=7)
    expected_mm = scipy_median(frame.depth_mm, k)
    out_mm = median_filter(frame.depth_mm, k)
    np.testing.assert_array_equal(out_mm, expected_mm)
    out_m = median_filter(frame.depth_m, k)
    assert out_m.dtype == np.float32 and out_m.flags.c_contiguous
    np.testing.assert_array_equal(out_m, expected_mm.astype(np.float32) * np.float32(1e-3))


@needs_numba
@pytest.mark.parametrize('k', [7, 9, 17, 21])
def test_jit_network_chunk_and_band_edges(k) -> None:
    """Widths around the 64-pixel lanes and 512-pixel chunks, heights around the bands."""
    rng = np.random.default_rng(k)
    program = median._jit_program(k)
    for h, w in [(1, 1), (1, 65), (3, 64), (4, 63), (5, 511), (9, 512), (17, 513), (6, 1100),
                 (33, 20), (2, 1030)]:
        for keys in (rng.integers(0, 65536, (h, w)).astype(np.uint16),
                     rng.integers(0, 3, (h, w)).astype(np.uint16)):       # many ties
            out = jit_median.network_median(keys, program)
            assert out.dtype == np.uint16 and out.flags.c_contiguous
            np.testing.assert_array_equal(out, scipy_median(keys, k), err_msg=f'{h}x{w}')


@needs_numba
def test_jit_network_constant_and_extreme_keys() -> None:
    for value in (0, 1, 65535):
        keys = np.full((20, 30), value, np.uint16)
        np.testing.assert_array_equal(
            jit_median.network_median(keys, median._jit_program(9)), keys)
    keys = np.zeros((40, 50), np.uint16)
    keys[::2, ::3] = 65535
    np.testing.assert_array_equal(jit_median.network_median(keys, median._jit_program(7)),
                                  scipy_median(keys, 7))


@needs_numba
def test_jit_median_runs_for_k_7_to_31_only(monkeypatch) -> None:
    monkeypatch.delenv(jit.NO_JIT_ENV, raising=False)
    calls = []
    real = jit_median.network_median

    def spy(keys, program, **options):
        calls.append(program.k)
        return real(keys, program, **options)

    monkeypatch.setattr(jit_median, 'network_median', spy)
    keys = np.random.default_rng(0).integers(0, 5000, (40, 45)).astype(np.uint16)
    for k in (3, 5, 7, 9, 17, 31, 33):
        np.testing.assert_array_equal(median_filter(keys, k), scipy_median(keys, k))
    assert calls == [7, 9, 17, 31]
    monkeypatch.setenv(jit.NO_JIT_ENV, '1')
    median_filter(keys, 9)
    assert calls == [7, 9, 17, 31]


def test_jit_warm_up(monkeypatch) -> None:
    monkeypatch.setenv(jit.NO_JIT_ENV, '1')
    assert median.warm_up(17) == 0.0
    monkeypatch.delenv(jit.NO_JIT_ENV)
    seconds = median.warm_up(17)
    assert seconds >= 0.0 and (seconds > 0.0) is jit_median.AVAILABLE


@needs_numba
def test_jit_quantised_keys() -> None:
    frame = render_scene('farm_row')
    keys, values = jit_median.quantised_keys(frame.depth_m, 1000.0)
    np.testing.assert_array_equal(keys, frame.depth_mm)
    np.testing.assert_array_equal(np.take(values, keys), frame.depth_m)
    np.testing.assert_array_equal(jit_median.take(values, keys), frame.depth_m)
    # Rounds like np.rint, ties to even: halves i + 0.5 for i % 4 in (0, 1) -> 0, 2, 4, 6, ...
    i = np.arange(400)
    ties = ((i[i % 4 < 2] + 0.5) / 2).astype(np.float32)
    keys, _ = jit_median.quantised_keys(ties[None, :], 2.0)
    np.testing.assert_array_equal(keys[0], np.rint(ties * 2))
    for bad in (-0.001, np.nan, 65.6):                       # negative, NaN, beyond 16 bits
        img = np.full((3, 4), 1.5, np.float32)
        img[1, 2] = bad
        assert jit_median.quantised_keys(img, 1000.0) is None
    collide = np.array([[1.0, 1.0002]], np.float32)          # one mm, two values
    assert jit_median.quantised_keys(collide, 1000.0) is None


@pytest.mark.parametrize('k', [3, 7, 9, 17, 21])
def test_fused_network_code_never_writes_its_operands(k) -> None:
    """The compiled interpreter vectorises only when results do not overlap operands."""
    program = median._jit_program(k) if k >= 7 else None
    r = k // 2
    net, outputs = median._tiled_network(k, 4, lambda c: [('run', c, i) for i in range(k)],
                                        forget=True)
    leaves = [('run', c, i) for c in range(-r, 4 + r) for i in range(k)]
    code, _, _ = median._compile_fused(net, outputs, leaves)
    codes = [code] if program is None else [code, *program.code1, *program.code2]
    for c in codes:
        assert not ((c[:, :2, None] == c[:, None, 2:]) & (c[:, :2, None] >= 0)).any()
        assert ((c[:, 0] >= 0) | (c[:, 1] >= 0)).all() and (c[:, 2:] >= 0).all()


@needs_numba
@pytest.mark.parametrize('lowest', [0, 1000])
def test_jit_lowest_key_count_marks_exactly_the_lowest_medians(lowest) -> None:
    """The median is the lowest key iff more than K*K // 2 window keys equal it, borders too."""
    rng = np.random.default_rng(16 + lowest)
    for shape in [(1, 1), (3, 4), (6, 40), (45, 70)]:
        keys = rng.integers(lowest + 1, lowest + 3000, shape).astype(np.uint16)
        keys[rng.random(shape) < 0.55] = lowest
        keys[0, 0] = lowest                     # a corner repeated (R + 1)**2 times
        for k in (7, 17):
            fill, need = jit_median._known_lowest(keys, k)
            assert fill == lowest and need.shape == shape
            expected = scipy_median(keys, k) != lowest
            np.testing.assert_array_equal(need.astype(bool), expected, err_msg=f'{shape} K={k}')


@needs_numba
@pytest.mark.parametrize('k', [7, 17, 31])
def test_jit_network_skipped_lanes_and_bands_are_exact(k, monkeypatch) -> None:
    """Rows, bands and 64-lane blocks whose medians are all the lowest key are not merged.

    No-return (0) areas at both ends of the row chunks, in whole bands and in the middle of
    a row, valid patches one lane wide at a chunk edge, ties and 65535 outliers; also with a
    lowest key that is not 0. Both kernels; skipping forced on (as with >= 40 % no return).
    """
    monkeypatch.setattr(jit_median, '_SKIP_MIN_FRACTION', 0.0)
    rng = np.random.default_rng(k)
    program = median._jit_program(k)
    h, w = 70, 1100                             # three row chunks of 384 lanes
    base = rng.integers(1000, 4500, (h, w)).astype(np.uint16)
    base[rng.random((h, w)) < 0.1] = 65535
    base[:, 600:640] = 2000                     # ties
    layouts = []
    zeros = base.copy()
    zeros[:, :200] = 0                          # left end of chunk 0
    zeros[:, 300:460] = 0                       # end of chunk 0, start of chunk 1
    zeros[:, 1000:] = 0                         # right end of the last chunk
    zeros[:24, :] = 0                           # whole bands at the top
    zeros[rng.random((h, w)) < 0.3] = 0         # pepper
    layouts.append(zeros)
    sliver = np.zeros((h, w), np.uint16)
    sliver[30:50, 383:384] = 3000               # one lane at a chunk edge
    sliver[60:, 767:769] = 65535
    layouts.append(sliver)
    layouts.append(np.where(zeros == 0, 700, zeros).astype(np.uint16))   # lowest key 700
    for keys in layouts:
        fill, need = jit_median._known_lowest(keys, k)
        assert need.shape == keys.shape and not need.all()     # something is skipped
        expected = scipy_median(keys, k)
        for in_registers in (k <= jit_median.REGISTER_MAX_K, False):
            out = jit_median.network_median(keys, program, in_registers=in_registers)
            assert out.dtype == np.uint16 and out.flags.c_contiguous
            np.testing.assert_array_equal(out, expected)


@needs_numba
def test_jit_lowest_key_count_only_when_it_can_pay() -> None:
    """Under 40 % of the keys at the lowest value: no count, every output is merged."""
    keys = np.full((40, 60), 1500, np.uint16)
    keys[:, :20] = 0                            # 33 % no return: medians 0 on the left
    fill, need = jit_median._known_lowest(keys, 7)
    assert fill == 0 and need.shape == (0, 0)
    np.testing.assert_array_equal(jit_median.network_median(keys, median._jit_program(7)),
                                  scipy_median(keys, 7))
    keys[:, :30] = 0                            # 50 %: counted
    assert jit_median._known_lowest(keys, 7)[1].shape == keys.shape


@needs_numba
def test_key_range_is_min_max_and_count_of_the_min() -> None:
    """key_range against numpy on images whose lowest key is rare, common, 0, 65535, alone."""
    rng = np.random.default_rng(11)
    images = [rng.integers(0, 65536, (37, 53)).astype(np.uint16),
              np.full((5, 7), 65535, np.uint16), np.zeros((1, 1), np.uint16),
              np.array([[9, 3, 3], [4, 3, 65535]], np.uint16)]
    holes = rng.integers(500, 4500, (424, 512)).astype(np.uint16)
    holes[rng.random(holes.shape) < 0.45] = 0
    images.append(holes)
    images.append(holes[::2, 1::3])             # not contiguous
    for keys in images:
        assert jit_median.key_range(keys) == (int(keys.min()), int(keys.max()),
                                              int(np.count_nonzero(keys == keys.min())))


@needs_numba
def test_jit_median_mostly_no_return_frames(monkeypatch) -> None:
    """Float metres as the pipeline passes them: large no-return areas, K = 9 and 17."""
    monkeypatch.delenv(jit.NO_JIT_ENV, raising=False)
    frame = render_scene('ramps', seed=2)
    metres = frame.depth_m.copy()
    metres[:, 400:] = 0.0
    mm = frame.depth_mm.copy()
    mm[:, 400:] = 0
    for k in (9, 17):
        expected = scipy_median(mm, k)
        np.testing.assert_array_equal(median_filter(mm, k), expected)
        np.testing.assert_array_equal(median_filter(metres, k),
                                      expected.astype(np.float32) * np.float32(1e-3))


@needs_numba
@pytest.mark.parametrize('k', [7, 9, 17])
def test_jit_in_register_kernel_equals_interpreter_and_scipy(k) -> None:
    """The generated straight-line kernel and the interpreter run the same program.

    Widths around the 32-pixel vectors, 64-lane blocks and 512-pixel chunks, heights around
    the 8-row bands; full-range keys, ties, 65535 outliers, all-equal and all-zero windows.
    """
    rng = np.random.default_rng(100 + k)
    program = median._jit_program(k)
    assert program.tile == 8
    for h, w in [(1, 1), (2, 31), (7, 33), (8, 64), (9, 95), (17, 512), (3, 513), (25, 1100)]:
        full = rng.integers(0, 65536, (h, w)).astype(np.uint16)
        ties = rng.integers(0, 3, (h, w)).astype(np.uint16)
        depth_like = rng.integers(900, 1100, (h, w)).astype(np.uint16)
        depth_like[rng.random((h, w)) < 0.4] = 0
        depth_like[rng.random((h, w)) < 0.02] = 65535
        for keys in (full, ties, depth_like, np.zeros((h, w), np.uint16),
                     np.full((h, w), 65535, np.uint16)):
            expected = scipy_median(keys, k)
            for in_registers in (True, False):
                out = jit_median.network_median(keys, program, in_registers=in_registers)
                assert out.dtype == np.uint16 and out.flags.c_contiguous
                np.testing.assert_array_equal(out, expected,
                                              err_msg=f'{h}x{w} in_registers={in_registers}')


@needs_numba
def test_jit_in_register_kernel_runs_for_k_up_to_21(monkeypatch) -> None:
    """K <= REGISTER_MAX_K runs in registers, larger K through the interpreter."""
    calls = []
    real = jit_median.register_kernel

    def spy(program):
        calls.append(program.k)
        return real(program)

    monkeypatch.setattr(jit_median, 'register_kernel', spy)
    keys = np.random.default_rng(1).integers(0, 5000, (30, 70)).astype(np.uint16)
    for k in (7, jit_median.REGISTER_MAX_K, jit_median.REGISTER_MAX_K + 2):
        out = jit_median.network_median(keys, median._jit_program(k))
        np.testing.assert_array_equal(out, scipy_median(keys, k))
    assert calls == [7, jit_median.REGISTER_MAX_K]


@needs_numba
def test_jit_warm_up_compiles_the_in_register_kernel(monkeypatch) -> None:
    monkeypatch.delenv(jit.NO_JIT_ENV, raising=False)
    median.warm_up(9)
    kernel = jit_median.register_kernel(median._jit_program(9))
    assert kernel.signatures        # compiled: the first frame does not pay for it


@needs_numba
def test_jit_in_register_compile_failure_is_said_and_falls_back(monkeypatch) -> None:
    """A numba that cannot generate the kernel: one warning, then the interpreter, same result."""
    def broken(program):
        raise RuntimeError('no code generation here')

    monkeypatch.setattr(jit_median, 'register_kernel', broken)
    monkeypatch.setattr(jit_median, '_REGISTER_FAILED', [])
    keys = np.random.default_rng(2).integers(0, 5000, (20, 30)).astype(np.uint16)
    program = median._jit_program(9)
    with pytest.warns(RuntimeWarning, match='in-register median kernels failed'):
        out = jit_median.network_median(keys, program)
    np.testing.assert_array_equal(out, scipy_median(keys, 9))
    with warnings.catch_warnings():
        warnings.simplefilter('error')           # said once
        np.testing.assert_array_equal(jit_median.network_median(keys, program), out)
    with pytest.raises(RuntimeError, match='no code generation'):
        jit_median.network_median(keys, program, in_registers=True)


@needs_numba
def test_jit_in_register_kernel_source_is_written_for_the_disk_cache(tmp_path,
                                                                     monkeypatch) -> None:
    """The generated kernel module goes to a writable directory, for numba's disk cache.

    With none, it is compiled in memory. Both give scipy's median.
    """
    program = median._jit_program(7)
    keys = np.random.default_rng(3).integers(0, 4000, (12, 50)).astype(np.uint16)
    keys[:, :30] = 0
    tables = jit_median._register_tables(program, 64)
    r = 3
    padded = cv2.copyMakeBorder(keys, r, r + 4, r, r + 14, cv2.BORDER_REPLICATE)
    fill, need = jit_median._known_lowest(keys, 7)

    def run(kernel):
        out = np.empty((12, 50), np.uint16)
        plan = jit_median.band_plan(12, 50, 64, program.tile, r)
        mem = jit_median.aligned_registers(int(tables[3][-1]) + 64)
        kernel(padded, 12, 50, 64, *tables, need, fill, plan, out, mem)
        return out

    monkeypatch.setattr(jit_median, '_kernel_directories', lambda: [tmp_path / 'kernels'])
    kernel = jit_median._make_register_kernel(program)
    written = list((tmp_path / 'kernels').glob('median_k7_t8_*.py'))
    assert len(written) == 1 and 'cache=True' in written[0].read_text()
    np.testing.assert_array_equal(run(kernel), scipy_median(keys, 7))
    blocked = tmp_path / 'a_file'
    blocked.write_text('not a directory')
    monkeypatch.setattr(jit_median, '_kernel_directories', lambda: [blocked / 'kernels'])
    kernel = jit_median._make_register_kernel(program)
    np.testing.assert_array_equal(run(kernel), scipy_median(keys, 7))
