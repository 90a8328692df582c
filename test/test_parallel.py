"""Stages on several threads (compute_threads) give the one-thread result to the bit."""

import functools
import os
import threading
import time

import numpy as np
import pytest

from obstacle_detection.pipeline import geometry, jit, median, normals, parallel, traversal, voxel
from obstacle_detection.pipeline._compiled import knn as jit_knn
from obstacle_detection.pipeline._compiled import median as jit_median
from obstacle_detection.pipeline._compiled import traversal as jit_traversal
from obstacle_detection.pipeline._compiled import voxel as jit_voxel
from obstacle_detection.pipeline.depth import decode_depth
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE, corridor
from obstacle_detection.sim.scenes import render_scene

compiled = pytest.mark.skipif(not jit_median.AVAILABLE, reason='numba is not installed')


@pytest.fixture(autouse=True)
def _compiled_path(monkeypatch):
    monkeypatch.delenv(jit.NO_JIT_ENV, raising=False)


# ------------------------------------------------------------------------------ run_parts

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


two_cpus = pytest.mark.skipif(parallel.usable_cpus() < 2, reason='needs two usable CPUs')


def test_one_usable_cpu_runs_every_part_on_the_calling_thread(monkeypatch) -> None:
    monkeypatch.setattr(parallel, 'usable_cpus', lambda: 1)
    ran: list[int] = []
    parallel.wake(4)
    parallel.run_parts([lambda: ran.append(threading.get_ident())] * 5, 4)
    assert ran == [threading.get_ident()] * 5


@two_cpus
def test_run_parts_from_a_pool_thread_runs_them_there() -> None:
    inner: list[int] = []
    started = threading.Event()
    outer_thread: list[int] = []

    def outer() -> None:
        # a pool thread that waited for the pool could wait for itself: it runs them in turn
        outer_thread.append(threading.get_ident())
        started.set()
        parallel.run_parts([lambda: inner.append(threading.get_ident())] * 3, 2)

    def first() -> None:          # the calling thread takes this part and waits for outer
        assert started.wait(10.0)

    parallel.run_parts([first, outer], 2)
    assert outer_thread and outer_thread[0] != threading.get_ident()
    assert inner == [outer_thread[0]] * 3


@pytest.mark.parametrize('bad, error', [(0, ValueError), (9, ValueError), (-1, ValueError),
                                        (True, TypeError), (1.5, TypeError), ('2', TypeError)])
def test_thread_counts_outside_1_to_8_are_refused(bad, error) -> None:
    with pytest.raises(error):
        parallel.check_threads(bad)
    with pytest.raises((TypeError, ValueError)):
        corridor(compute_threads=bad)


def test_part_bounds_cover_the_range_in_order() -> None:
    for count in (1, 2, 7, 100):
        for parts in (1, 2, 3, 8, 200):
            bounds = parallel.part_bounds(count, parts)
            assert bounds[0][0] == 0 and bounds[-1][1] == count
            assert all(a < b for a, b in bounds)
            assert all(b == c for (_, b), (c, _) in zip(bounds[:-1], bounds[1:]))
            assert len(bounds) == min(parts, count)


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2 or parallel._pool._current_cpu is None,
                    reason='needs two CPUs and sched_getcpu')
def test_pool_threads_are_kept_off_the_callers_cpu() -> None:
    parallel.run_parts([lambda: None] * 2, 2)
    kept_off = parallel._pool._kept_off
    assert kept_off is not None
    for native_id in parallel._pool._native_ids:
        assert os.sched_getaffinity(native_id) == os.sched_getaffinity(0) - {kept_off}


# ------------------------------------------------------------------------------ the stages

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
    calls = []

    def run(functions):
        calls.append(len(functions))
        for function in reversed(functions):              # any order gives the same rows
            function()

    np.testing.assert_array_equal(jit_knn.knn_grid(pts, 13, parts=parts, run_parts=run), one)
    assert calls == [parts]
    np.testing.assert_array_equal(normals.nearest_neighbours(pts, 13, threads=2), one)


@compiled
def test_normals_in_ranges_equal_one_pass() -> None:
    pts = _cloud(np.random.default_rng(5), 3000)
    neighbours = jit_knn.knn_grid(pts, 13)[:, :10]
    one = jit_knn.normals_from_neighbours(pts, neighbours, 10)
    np.testing.assert_array_equal(
        jit_knn.normals_from_neighbours(pts, neighbours, 10, parts=4,
                                        run_parts=lambda fs: [f() for f in fs]), one)
    np.testing.assert_array_equal(normals.estimate_normals(pts, neighbours, threads=3), one)
    bad = neighbours.copy()
    bad[-1, 3] = pts.shape[0]                               # out of range in the last part
    with pytest.raises(ValueError, match='neighbour indices'):
        jit_knn.normals_from_neighbours(pts, bad, 10, parts=4,
                                        run_parts=lambda fs: [f() for f in fs])


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
                                                traversal.PLANAR_TOLERANCE, parts=parts,
                                                run_parts=lambda fs: [f() for f in fs[::-1]])
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
def test_back_projection_bands_in_any_order_and_a_failing_band() -> None:
    """The bands close their gaps in any run order; a band that raises hangs nobody."""
    frame = render_scene('people', seed=1, intrinsics=KINECT_V2_SD, size=KINECT_V2_SD_SIZE,
                         frame_index=0)
    params = corridor(camera_height_m=float(frame.height_m),
                      camera_pitch_rad=float(frame.pitch_rad))
    depth = decode_depth(frame.depth_mm)
    rays = geometry.ground_rays(depth.shape, KINECT_V2_SD, params)
    bounds = voxel.roi_bounds(params)
    one = jit_voxel.project_roi(depth, rays, bounds, params.voxel_size_m)
    assert one.points.shape[0] > 1000
    orders = {'reversed': lambda calls: [call() for call in calls[::-1]],
              'middle first': lambda calls: [calls[i]() for i in (3, 0, 4, 1, 5, 2)],
              'two threads': functools.partial(parallel.run_parts, threads=2)}
    one_grid = jit_voxel.voxelise(one)
    for name, run_parts in orders.items():
        got = jit_voxel.project_roi(depth, rays, bounds, params.voxel_size_m, parts=6,
                                    run_parts=run_parts)
        # the voxel grid reads the bands' stretches where they lie ...
        assert got.stretches is not None and got.stretches[0][1] > got.stretches[1][0]
        for a, b in zip(one_grid, jit_voxel.voxelise(got)):
            np.testing.assert_array_equal(b, a, err_msg=name)
        np.testing.assert_array_equal(got.pixel_voxel, one.pixel_voxel, err_msg=name)
        assert got.stretches is not None
        # ... and the points, read, are moved together once
        for a, b in zip((one.points, one.pixel_index, one.keys, one.labels),
                        (got.points, got.pixel_index, got.keys, got.labels)):
            np.testing.assert_array_equal(b, a, err_msg=name)
        assert got.stretches is None

    real = jit_voxel._project_kernel
    third_band = depth.shape[0] * 2 // 6 * depth.shape[1]

    def failing(depth_band, rays_band, offset, *args):
        if offset == third_band:
            raise RuntimeError('band 2 failed')
        return real(depth_band, rays_band, offset, *args)

    outcome: list[BaseException] = []

    def run() -> None:
        try:
            jit_voxel.project_roi(depth, rays, bounds, params.voxel_size_m, parts=6,
                                  run_parts=functools.partial(parallel.run_parts, threads=2))
        except RuntimeError as error:
            outcome.append(error)

    jit_voxel._project_kernel = failing
    try:
        worker = threading.Thread(target=run, daemon=True)
        worker.start()
        worker.join(timeout=30.0)
    finally:
        jit_voxel._project_kernel = real
    assert not worker.is_alive(), 'a band waited forever for the failed one'
    assert len(outcome) == 1 and 'band 2 failed' in str(outcome[0])


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
def test_awake_helpers_take_the_next_parts() -> None:
    parallel.warm_up()
    assert parallel._pool._spin is not None and parallel._pool._spin_rounds > 0
    generation = np.zeros(1, np.int64)
    assert not parallel._pool._spin(generation, 0, 50)        # nothing moved: gives up
    assert parallel._pool._spin(generation, 1, 50)            # moved already: at once
    for _ in range(20):                                       # woken, then parts at once
        parallel.wake(2)
        ran: list[int] = []
        parallel.run_parts([lambda: ran.append(threading.get_ident())] * 4, 2)
        assert len(ran) == 4 and len(set(ran)) <= 2


@compiled
def test_a_second_wake_at_once_is_skipped() -> None:
    """The detector's wake right after the node's hands nothing over; a later one does."""
    if parallel.usable_cpus() < 2:
        pytest.skip('one usable CPU: no helpers to wake')
    parallel.warm_up()
    parallel.wake(2)
    generation = int(parallel._pool._generation[0])
    parallel.wake(2)                                  # within _REWAKE_S: still awake
    assert int(parallel._pool._generation[0]) == generation
    time.sleep(2 * parallel._REWAKE_S)
    parallel.wake(2)
    assert int(parallel._pool._generation[0]) == generation + 1


@compiled
def test_knn_and_normals_in_one_pass_equal_the_two_stages() -> None:
    pts = _cloud(np.random.default_rng(9), 3000)
    neighbours = jit_knn.knn_grid(pts, 13)
    normals_one = jit_knn.normals_from_neighbours(pts, neighbours[:, :10], 10)
    for parts in (2, 5):
        nb, nv = jit_knn.knn_and_normals(pts, 13, 10, parts=parts,
                                         run_parts=lambda fs: [f() for f in fs[::-1]])
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


def test_wake_compiles_nothing_while_a_background_compile_runs(monkeypatch) -> None:
    """The node's worker calls wake() from its first frame, while its kernels compile."""
    fresh = parallel._Pool()
    monkeypatch.setattr(parallel, '_pool', fresh)
    monkeypatch.setattr(parallel, 'usable_cpus', lambda: 2)
    monkeypatch.setattr(jit, 'enabled', lambda: False)       # another thread compiles
    parallel.wake(2)
    assert fresh._spin is None and len(fresh._native_ids) == 1   # woken, nothing compiled
    ran: list[int] = []
    parallel.run_parts([lambda: ran.append(1)] * 3, 2)
    assert ran == [1, 1, 1]
