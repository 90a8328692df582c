"""Results do not depend on compute_threads (the median's threads), to the bit."""

import numpy as np
import pytest

from obstacle_detection.pipeline import normals
from obstacle_detection.pipeline._compiled import knn as jit_knn
from obstacle_detection.pipeline._compiled import median as jit_median
from obstacle_detection.pipeline._compiled import traversal as jit_traversal
from obstacle_detection.pipeline.depth import decode_depth
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE, corridor
from obstacle_detection.sim.scenes import render_scene


@pytest.mark.parametrize('bad, words', [(0, 'out of range'), (9, 'out of range'),
                                        (-1, 'out of range'), (True, 'must be an integer'),
                                        (1.5, 'must be an integer'), ('2', 'must be an integer')])
def test_thread_counts_outside_1_to_8_are_refused(bad, words) -> None:
    with pytest.raises(ValueError, match=f'compute_threads=.*{words}'):
        corridor(compute_threads=bad)


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


def test_validation_equals_the_definition(kernel_path: str) -> None:
    rng = np.random.default_rng(7)
    flags = rng.random(500) < 0.7
    neighbours = np.column_stack((np.arange(500), rng.integers(0, 500, (500, 12))))
    expected = np.array([flags[v] and all(flags[neighbours[v, 1:13]]) for v in range(500)])
    assert 0 < expected.sum() < 500 and not np.array_equal(expected, flags)
    np.testing.assert_array_equal(normals.validate_obstacles(flags, neighbours, 12), expected)


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


def compiled_signatures() -> dict:
    """Every numba dispatcher of the pipeline's kernels -> its number of compiled signatures."""
    from obstacle_detection.pipeline import _compiled
    from obstacle_detection.pipeline._compiled import costmap as jit_costmap
    from obstacle_detection.pipeline._compiled import depth as jit_depth
    from obstacle_detection.pipeline._compiled import voxel as jit_voxel
    found = {}
    modules = (jit_median, jit_depth, jit_knn, jit_traversal, jit_voxel, jit_costmap, _compiled)
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
before = t.compiled_signatures()
assert len(before) > 20, len(before)
detector.process(frame.depth_mm, KINECT_V2_SD)
detector.process(decode_depth(frame.depth_mm), KINECT_V2_SD)
after = t.compiled_signatures()
print(sorted(k.py_func.__name__ for k, n in after.items() if n != before.get(k, 0)))
"""


@pytest.mark.numba
def test_warm_up_compiles_every_kernel_a_threaded_frame_runs() -> None:
    """After Detector.warm_up no frame compiles anything.

    The node's first frame on the compiled path once stalled 3 s compiling kernels that the
    warm-up had not run. In a fresh process: in this one, earlier tests compiled them already.
    """
    import subprocess
    import sys
    from pathlib import Path
    code = _FIRST_FRAME_CHECK.format(test_dir=str(Path(__file__).parent))
    run = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=600, cwd=Path(__file__).parents[1])
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip().splitlines()[-1] == '[]'
