"""Stages on several threads (compute_threads) give the one-thread result to the bit."""

import threading

import numpy as np
import pytest
from scipy import ndimage

from obstacle_detection.pipeline import geometry, jit, median, normals, parallel, traversal, voxel
from obstacle_detection.pipeline._compiled import knn as jit_knn
from obstacle_detection.pipeline._compiled import median as jit_median
from obstacle_detection.pipeline._compiled import traversal as jit_traversal
from obstacle_detection.pipeline._compiled import voxel as jit_voxel
from obstacle_detection.pipeline.depth import decode_depth, depth_lut
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE, corridor
from obstacle_detection.sim.scenes import render_scene

compiled = pytest.mark.skipif(not jit_median.AVAILABLE, reason='numba is not installed')


@pytest.fixture(autouse=True)
def _compiled_path(monkeypatch):
    monkeypatch.delenv(jit.NO_JIT_ENV, raising=False)


# ------------------------------------------------------------------------------ run_parts
# (the median's bands; the other stages cut their work in compiled prange loops)

def test_run_parts_runs_every_part_once_on_up_to_n_threads() -> None:
    seen: list[tuple[int, int]] = []
    lock = threading.Lock()

    def part(index: int) -> None:
        with lock:
            seen.append((index, threading.get_ident()))

    for threads in (1, 2, 3):
        seen.clear()
        parallel.run_parts([lambda i=i: part(i) for i in range(7)], threads)
        assert sorted(i for i, _ in seen) == list(range(7))
        assert len({ident for _, ident in seen}) <= threads
    seen.clear()
    parallel.run_parts([lambda i=i: part(i) for i in range(5)], 1)
    assert {ident for _, ident in seen} == {threading.get_ident()}


def test_run_parts_raises_the_first_error_after_all_parts_ran() -> None:
    done = []

    def fails(text: str) -> None:
        done.append(text)
        raise ValueError(text)

    parts = [lambda: done.append('a'), lambda: fails('first'), lambda: done.append('c'),
             lambda: fails('second')]
    with pytest.raises(ValueError, match='first'):
        parallel.run_parts(parts, 2)
    assert sorted(done) == ['a', 'c', 'first', 'second']
    parallel.run_parts([lambda: done.append('next')], 2)      # the pool still works
    assert done[-1] == 'next'


@pytest.mark.parametrize('bad, error', [(0, ValueError), (9, ValueError), (-1, ValueError),
                                        (True, TypeError), (1.5, TypeError), ('2', TypeError)])
def test_thread_counts_outside_1_to_8_are_refused(bad, error) -> None:
    with pytest.raises(error):
        jit.check_threads(bad)
    with pytest.raises(error):
        jit.use_threads(bad)
    with pytest.raises((TypeError, ValueError)):
        corridor(compute_threads=bad)


def test_use_threads_never_asks_for_more_than_numba_has() -> None:
    assert jit.use_threads(1) == 1
    assert 1 <= jit.use_threads(jit.MAX_THREADS) <= jit.MAX_THREADS
    if jit_knn.AVAILABLE:
        import numba
        assert jit.use_threads(jit.MAX_THREADS) == min(jit.MAX_THREADS,
                                                       numba.config.NUMBA_NUM_THREADS)
        used = jit.use_threads(2)
        assert numba.get_num_threads() == used


# ------------------------------------------------------------------------------ the stages

def scipy_median(img, k):
    return ndimage.median_filter(img, size=k, mode='nearest')


@compiled
@pytest.mark.parametrize('k', [7, 9, 17, 21])
@pytest.mark.parametrize('threads', [2, 3, 8])
def test_banded_median_equals_scipy(k, threads) -> None:
    rng = np.random.default_rng(k + threads)
    for shape in ((40, 45), (17, 70), (3, 33), (61, 9)):
        img = rng.integers(0, 5000, shape).astype(np.uint16)
        img[:, : shape[1] // 3] = 0                       # a block of no return
        np.testing.assert_array_equal(median.median_filter(img, k, threads=threads),
                                      scipy_median(img, k))


@compiled
def test_banded_median_of_a_frame_equals_one_thread() -> None:
    frame = render_scene('person_walking', seed=2, intrinsics=KINECT_V2_SD,
                         size=KINECT_V2_SD_SIZE, frame_index=4).depth_mm
    one = median.median_filter(frame, 17, threads=1)
    for threads in (2, 4):
        np.testing.assert_array_equal(median.median_filter(frame, 17, threads=threads), one)
    metres = decode_depth(frame)
    np.testing.assert_array_equal(median.median_filter(metres, 17, threads=2),
                                  median.median_filter(metres, 17))


@pytest.mark.parametrize('k', [3, 5, 7, 17])
def test_median_of_codes_is_the_median_of_the_decoded_depth(k) -> None:
    rng = np.random.default_rng(k)
    codes = rng.integers(0, 9000, (30, 37)).astype(np.uint16)
    codes[rng.random(codes.shape) < 0.3] = 0
    for scale in (1000.0, 5000.0, 3.0):
        table = depth_lut(scale)
        expected = scipy_median(table[codes], k)
        got = median.median_of_codes(codes, k, table, threads=2)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, expected)


def _cloud(rng, n):
    """Return a floor, a wall and a cube of 5 cm grid points (exact ties), and duplicates."""
    u = rng.uniform(0.0, 2.0, (n, 2))
    floor = np.column_stack((u, np.zeros(n)))
    wall = np.column_stack((np.full(n // 2, 1.5), u[: n // 2]))
    grid = np.stack(np.meshgrid(*[np.arange(6) * 0.05] * 3), -1).reshape(-1, 3)  # ties
    pts = np.concatenate((floor, wall, grid, grid[:20])) + rng.normal(0, 0.002, (1, 3))
    return pts.astype(np.float32)


@compiled
@pytest.mark.parametrize('parts', [2, 3, 7])
def test_knn_in_ranges_equals_one_search(parts) -> None:
    pts = _cloud(np.random.default_rng(parts), 3000)
    one = jit_knn.knn_grid(pts, 13)
    for threads in (1, 2):       # the ranges on one thread, or shared by two
        jit.use_threads(threads)
        np.testing.assert_array_equal(jit_knn.knn_grid(pts, 13, parts=parts), one)
    np.testing.assert_array_equal(normals.nearest_neighbours(pts, 13, threads=2), one)


@compiled
def test_normals_in_ranges_equal_one_pass() -> None:
    pts = _cloud(np.random.default_rng(5), 3000)
    neighbours = jit_knn.knn_grid(pts, 13)[:, :10]
    one = jit_knn.normals_from_neighbours(pts, neighbours, 10)
    np.testing.assert_array_equal(jit_knn.normals_from_neighbours(pts, neighbours, 10, parts=4),
                                  one)
    np.testing.assert_array_equal(normals.estimate_normals(pts, neighbours, threads=3), one)
    bad = neighbours.copy()
    bad[-1, 3] = pts.shape[0]                               # out of range in the last part
    with pytest.raises(ValueError, match='neighbour indices'):
        jit_knn.normals_from_neighbours(pts, bad, 10, parts=4)


@pytest.mark.parametrize('scene', ['person_walking', 'corridor', 'ramps'])
def test_detector_outputs_do_not_depend_on_compute_threads(scene) -> None:
    frame = render_scene(scene, seed=3, intrinsics=KINECT_V2_SD, size=KINECT_V2_SD_SIZE,
                         frame_index=2)
    mount = dict(camera_height_m=float(frame.height_m), camera_pitch_rad=float(frame.pitch_rad),
                 camera_roll_rad=float(frame.roll_rad))
    one = Detector(corridor(**mount)).process(frame.depth_mm, KINECT_V2_SD)
    two = Detector(corridor(compute_threads=2, **mount)).process(frame.depth_mm, KINECT_V2_SD)
    metres = Detector(corridor(compute_threads=2, **mount)).process(
        decode_depth(frame.depth_mm), KINECT_V2_SD)
    for result in (two, metres):
        for name in ('depth_m', 'labels', 'pixel_voxel', 'voxel_points', 'voxel_normals',
                     'voxel_neighbours', 'voxel_is_obstacle', 'obstacle_points',
                     'ground_points'):
            a, b = getattr(one, name), getattr(result, name)
            assert a.dtype == b.dtype and a.shape == b.shape, name
            assert a.tobytes() == b.tobytes(), name
        np.testing.assert_array_equal(result.costmap.data, one.costmap.data)
    assert one.obstacle_points.shape[0] > 0


@compiled
def test_smear_pass_in_row_ranges_equals_one_pass() -> None:
    frame = render_scene('people', seed=1, intrinsics=KINECT_V2_SD, size=KINECT_V2_SD_SIZE,
                         frame_index=1).depth_mm
    raw = decode_depth(frame)
    raw[100:140, 200:260] = 0.0                              # a hole for the fill rule
    filtered = median.median_filter(raw, 17)
    one = traversal.drop_smeared(filtered.copy(), raw, 0.02)
    assert np.count_nonzero(one != filtered) > 100           # the pass changed something
    for parts in (2, 3, 7):
        got = filtered.copy()
        assert jit_traversal.drop_smeared_fused(got, raw, 0.02, traversal.FLYING_JUMP,
                                                traversal.PLANAR_TOLERANCE, parts=parts)
        np.testing.assert_array_equal(got, one)
    np.testing.assert_array_equal(traversal.drop_smeared(filtered.copy(), raw, 0.02, 2), one)
    # the detector's promise that raw holds no NaN skips only the scan for one
    np.testing.assert_array_equal(
        traversal.drop_smeared(filtered.copy(), raw, 0.02, 2, raw_no_nan=True), one)
    with_nan = raw.copy()
    with_nan[10, 10] = np.nan
    assert not jit_traversal.drop_smeared_fused(filtered.copy(), with_nan, 0.02,
                                                traversal.FLYING_JUMP,
                                                traversal.PLANAR_TOLERANCE, parts=2)


@compiled
@pytest.mark.parametrize('model', ['table', 'factors'])
def test_back_projection_in_row_bands_equals_one_pass(model) -> None:
    frame = render_scene('corridor', seed=2, intrinsics=KINECT_V2_SD, size=KINECT_V2_SD_SIZE,
                         frame_index=0)
    params = corridor(camera_height_m=float(frame.height_m),
                      camera_pitch_rad=float(frame.pitch_rad))
    depth = decode_depth(frame.depth_mm)
    rays = (geometry.ground_rays(depth.shape, KINECT_V2_SD, params) if model == 'table' else
            geometry.ray_model(depth.shape, KINECT_V2_SD, params))
    one = voxel.points_in_roi(depth, rays, params)
    one = (one.points.copy(), one.pixel_index.copy(), one.projection.labels.copy(),
           one.projection.keys.copy())
    assert one[0].shape[0] > 1000
    for threads in (2, 3):
        roi = voxel.points_in_roi(depth, rays, params.replace(compute_threads=threads))
        for a, b in zip(one, (roi.points, roi.pixel_index, roi.projection.labels,
                              roi.projection.keys)):
            np.testing.assert_array_equal(b, a)


@compiled
def test_back_projection_bands_close_their_gaps_when_read() -> None:
    """The voxel grid reads the bands' stretches where they lie; the points, read, move once."""
    frame = render_scene('people', seed=1, intrinsics=KINECT_V2_SD, size=KINECT_V2_SD_SIZE,
                         frame_index=0)
    params = corridor(camera_height_m=float(frame.height_m),
                      camera_pitch_rad=float(frame.pitch_rad))
    depth = decode_depth(frame.depth_mm)
    rays = geometry.ground_rays(depth.shape, KINECT_V2_SD, params)
    bounds = voxel.roi_bounds(params)
    one = jit_voxel.project_roi(depth, rays, bounds, params.voxel_size_m)
    assert one.points.shape[0] > 1000
    one_grid = jit_voxel.voxelise(one)
    for parts in (2, 6):
        got = jit_voxel.project_roi(depth, rays, bounds, params.voxel_size_m, parts=parts)
        assert got.stretches is not None and got.stretches[0][1] > got.stretches[1][0]
        for a, b in zip(one_grid, jit_voxel.voxelise(got)):
            np.testing.assert_array_equal(b, a)
        np.testing.assert_array_equal(got.pixel_voxel, one.pixel_voxel)
        assert got.stretches is not None
        for a, b in zip((one.points, one.pixel_index, one.keys, one.labels),
                        (got.points, got.pixel_index, got.keys, got.labels)):
            np.testing.assert_array_equal(b, a)
        assert got.stretches is None


def test_validation_compiled_equals_the_definition() -> None:
    rng = np.random.default_rng(7)
    flags = rng.random(500) < 0.7
    neighbours = np.column_stack((np.arange(500), rng.integers(0, 500, (500, 12))))
    expected = np.array([flags[v] and all(flags[neighbours[v, 1:13]]) for v in range(500)])
    assert 0 < expected.sum() < 500 and not np.array_equal(expected, flags)
    np.testing.assert_array_equal(normals.validate_obstacles(flags, neighbours, 12), expected)
    if jit_knn.AVAILABLE:
        np.testing.assert_array_equal(jit_knn.validate(flags, neighbours, 12), expected)
        bad = neighbours.copy()
        bad[3, 5] = 500
        assert jit_knn.validate(flags, bad, 12) is None
        with pytest.raises(IndexError):
            normals.validate_obstacles(flags, bad, 12)


@compiled
def test_knn_and_normals_in_one_pass_equal_the_two_stages() -> None:
    pts = _cloud(np.random.default_rng(9), 3000)
    neighbours = jit_knn.knn_grid(pts, 13)
    normals_one = jit_knn.normals_from_neighbours(pts, neighbours[:, :10], 10)
    for parts in (2, 5):
        nb, nv = jit_knn.knn_and_normals(pts, 13, 10, parts=parts)
        np.testing.assert_array_equal(nb, neighbours)
        np.testing.assert_array_equal(nv, normals_one)
    nb, nv = normals.neighbours_and_normals(pts, 13, 10, threads=2)
    np.testing.assert_array_equal(nb, neighbours)
    np.testing.assert_array_equal(nv, normals_one)
    small = pts[:50]                                  # below MIN_SPLIT_POINTS: the two stages
    nb, nv = normals.neighbours_and_normals(small, 13, 10, threads=2)
    np.testing.assert_array_equal(nb, jit_knn.knn_grid(small, 13))
    with pytest.raises(ValueError):
        jit_knn.knn_and_normals(pts[:3], 13, 10, parts=2)
    bad = pts.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match='finite'):
        jit_knn.knn_and_normals(bad, 13, 10, parts=2)


@pytest.mark.parametrize('k', [3, 7, 17])
@pytest.mark.parametrize('threads', [1, 2])
def test_median_and_decode_gives_the_median_and_the_raw_depth(k, threads) -> None:
    rng = np.random.default_rng(k)
    codes = rng.integers(0, 9000, (45, 70)).astype(np.uint16)
    codes[rng.random(codes.shape) < 0.2] = 0
    table = depth_lut(1000.0)
    filtered, raw = median.median_and_decode(codes, k, table, threads)
    np.testing.assert_array_equal(filtered, scipy_median(table[codes], k))
    np.testing.assert_array_equal(raw, table[codes])
    assert filtered.dtype == raw.dtype == np.float32


def test_threaded_detector_refuses_what_the_decode_refuses() -> None:
    detector = Detector(corridor(compute_threads=2))
    depth = np.full((40, 50), 1500, np.uint16)
    for bad in (0.0, -5.0, float('nan')):
        with pytest.raises(ValueError, match='depth_scale'):
            detector.process(depth, KINECT_V2_SD, depth_scale=bad)
    with pytest.raises(ValueError):
        detector.process(np.zeros((0, 5), np.uint16), KINECT_V2_SD)
    tum = detector.process(depth, KINECT_V2_SD, depth_scale=5000.0)   # 0.3 m: all near
    one = Detector(corridor()).process(depth, KINECT_V2_SD, depth_scale=5000.0)
    np.testing.assert_array_equal(tum.depth_m, one.depth_m)
    assert tum.depth_m.max() == np.float32(1500 / 5000.0)


def _compiled_signatures() -> dict:
    """Every numba dispatcher of the pipeline's kernels -> its number of compiled signatures."""
    from obstacle_detection.pipeline import _compiled
    from obstacle_detection.pipeline._compiled import costmap as jit_costmap
    from obstacle_detection.pipeline._compiled import voxel as jit_voxel
    found = {}
    modules = (jit_median, jit_knn, jit_traversal, jit_voxel, jit_costmap, _compiled)
    kernels = [getattr(m, name) for m in modules for name in dir(m)]
    kernels += list(jit_median._REGISTER_KERNELS.values())
    for kernel in kernels:
        if hasattr(kernel, 'signatures') and hasattr(kernel, 'py_func'):
            found[kernel] = len(kernel.signatures)
    return found


_FIRST_FRAME_CHECK = """
import sys
sys.path.insert(0, {test_dir!r})
import test_parallel as t
from obstacle_detection.pipeline.depth import decode_depth
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE, corridor
from obstacle_detection.sim.scenes import render_scene
frame = render_scene('person_walking', seed=1, intrinsics=KINECT_V2_SD, size=KINECT_V2_SD_SIZE,
                     frame_index=0)
detector = Detector(corridor(compute_threads=2, camera_height_m=float(frame.height_m),
                             camera_pitch_rad=float(frame.pitch_rad)))
detector.warm_up()
before = t._compiled_signatures()
assert len(before) > 20, len(before)
detector.process(frame.depth_mm, KINECT_V2_SD)
detector.process(decode_depth(frame.depth_mm), KINECT_V2_SD)
after = t._compiled_signatures()
print(sorted(k.py_func.__name__ for k, n in after.items() if n != before.get(k, 0)))
"""


@compiled
def test_warm_up_compiles_every_kernel_a_threaded_frame_runs() -> None:
    """After Detector.warm_up no frame compiles anything.

    The node's first frame on the compiled path once stalled 3 s compiling the band kernels of
    compute_threads > 1. In a fresh process: in this one, earlier tests compiled them already.
    """
    import subprocess
    import sys
    from pathlib import Path
    code = _FIRST_FRAME_CHECK.format(test_dir=str(Path(__file__).parent))
    run = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=600, cwd=Path(__file__).parents[1])
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip().splitlines()[-1] == '[]'
