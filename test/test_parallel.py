"""The median on several threads (compute_threads) gives the one-thread result to the bit."""

import threading

import numpy as np
import pytest
from scipy import ndimage

from obstacle_detection.pipeline import jit, median, normals, parallel
from obstacle_detection.pipeline._compiled import knn as jit_knn
from obstacle_detection.pipeline._compiled import median as jit_median
from obstacle_detection.pipeline._compiled import traversal as jit_traversal
from obstacle_detection.pipeline.depth import decode_depth, depth_lut
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


def test_run_parts_does_not_wait_for_pool_threads_that_never_started() -> None:
    """Every pool thread busy elsewhere: the calling thread runs all the parts and returns."""
    release = threading.Event()
    busy = [parallel._helpers.submit(release.wait) for _ in range(parallel.MAX_THREADS - 1)]
    ran: list[int] = []
    worker = threading.Thread(target=parallel.run_parts,
                              args=([lambda: ran.append(threading.get_ident())] * 4, 2))
    try:
        worker.start()
        worker.join(timeout=60.0)
        assert not worker.is_alive(), 'run_parts waited for a pool thread that never started'
        assert ran == [worker.ident] * 4
    finally:
        release.set()
        for job in busy:
            job.result()


@pytest.mark.parametrize('bad, error', [(0, ValueError), (9, ValueError), (-1, ValueError),
                                        (True, TypeError), (1.5, TypeError), ('2', TypeError)])
def test_thread_counts_outside_1_to_8_are_refused(bad, error) -> None:
    with pytest.raises(error):
        parallel.check_threads(bad)
    with pytest.raises((TypeError, ValueError)):
        corridor(compute_threads=bad)


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
