"""The floor fit's compiled path and its shortcuts give the numpy path's fit, to the bit.

On the robot-level suite's frames (obstacle_detection/evaluation/scenarios_robot.json: every scene,
a pitched and rolled mount, time-of-flight noise), with the K = 5 median the default configuration
uses: the floor samples, the RANSAC hypotheses kept, and the fitted mount (``FloorFit``) are
compared bit for bit between the numba kernels and numpy; and the fit, which skips refining a
hypothesis whose inliers an earlier one already refined, is compared with every hypothesis
refined in full (the plain loop, written out below).
"""

import functools
import math
from pathlib import Path

import numpy as np
import pytest

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline import floor, geometry
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.ros.parameters import detector_params_from_ros, read_params_file

REPO = Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=1)
def suite_inputs():
    """(name, filtered depth, sampled rays, params) of one frame per robot-suite scenario."""
    base = detector_params_from_ros(read_params_file(REPO / 'params' / 'corridor.yaml'))
    out = []
    for scenario in evaluation.load_scenarios(evaluation.SUITES['robot']):
        frame = next(evaluation.scenario_frames(scenario, max_frames=1))
        params = frame.params(base)
        result = Detector(params).process(frame.depth, frame.intrinsics)
        shape = result.depth_m.shape     # the rays the detector samples for its floor fit
        sub_rays = floor.sample_rays(geometry.ray_model(shape, result.intrinsics, params), shape)
        out.append((scenario.name, result.depth_m, sub_rays, params))
    return out


@pytest.mark.numba
def test_compiled_floor_fit_equals_numpy_on_the_robot_suite(both_paths):
    refined = 0
    for _, depth, sub_rays, params in suite_inputs():
        pts = both_paths(floor.floor_samples, depth, sub_rays, params)
        if pts.shape[1] >= params.floor_min_points:
            best = both_paths(floor._ransac_plane, pts, params)[0]
            for band in floor.REFIT_BANDS_M:   # laid out as numpy's, so lstsq sums alike
                both_paths(floor._in_band, pts, *best, band)
                assert (floor._in_band.compiled(pts, *best, band).strides
                        == floor._in_band.reference(pts, *best, band).strides)
        refined += both_paths(floor.fit_floor, depth, sub_rays, params).refined
    assert refined >= 10   # the suite's frames do fit a floor: the comparison has teeth


def fit_every_hypothesis(depth, sub_rays, params):
    """fit_floor's plain loop: every hypothesis refined in full (no repeated-inlier skip)."""
    pts = floor.floor_samples(depth, sub_rays, params)
    if pts.shape[1] < params.floor_min_points:
        return None
    best = None
    for coef in floor._ransac_plane(pts, params):
        used = 0
        for band in floor.REFIT_BANDS_M:
            resid = pts[2] - (coef[0] * pts[0] + coef[1] * pts[1] + coef[2])
            inliers = pts[:, np.abs(resid) <= band]
            used = inliers.shape[1]
            if used < 3:
                break
            coef = floor._lstsq_plane(inliers)
        resid = pts[2] - (coef[0] * pts[0] + coef[1] * pts[1] + coef[2])
        support = int(np.count_nonzero(np.abs(resid) <= floor.REFIT_BANDS_M[-1]))
        if best is None or support > best[0]:
            best = (support, coef, used)
    return best


def test_skipping_repeated_refits_keeps_the_fit(kernel_path):
    skipped = 0
    for name, depth, sub_rays, params in suite_inputs():
        best = fit_every_hypothesis(depth, sub_rays, params)
        fit = floor.fit_floor(depth, sub_rays, params)
        if best is None or best[2] < params.floor_min_points or not fit.refined:
            continue
        _, coef, used = best
        want = floor._corrected_mount(params, *(float(v) for v in coef), used)
        assert fit == want, name
        pts = floor.floor_samples(depth, sub_rays, params)
        first, second = floor._ransac_plane(pts, params)
        skipped += floor._same(floor._in_band(pts, *first, floor.REFIT_BANDS_M[0]),
                               floor._in_band(pts, *second, floor.REFIT_BANDS_M[0]))
    assert skipped >= 1   # some frame does take the shortcut


def test_corrected_mount_of_a_known_plane():
    # the floor z = 0.1 x - 0.05 = the configured frame pitched by atan(0.1) more, 5 cm lower
    from obstacle_detection.pipeline.params import corridor
    params = corridor(camera_height_m=0.6, camera_pitch_rad=math.radians(10.0),
                      camera_roll_rad=0.0)
    fit = floor._corrected_mount(params, 0.1, 0.0, -0.05, 500)
    norm = math.sqrt(1.01)
    assert fit.refined and fit.samples == 500
    assert fit.height_m == pytest.approx(0.65 / norm, abs=1e-12)
    assert fit.pitch_rad == pytest.approx(math.radians(10.0) + math.atan(0.1), abs=1e-12)
    assert fit.roll_rad == pytest.approx(0.0, abs=1e-12)
