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
            both_paths(floor.ransac_plane, pts, params)
        refined += both_paths(floor.fit_floor, depth, sub_rays, params).refined
    assert refined >= 10   # the suite's frames do fit a floor: the comparison has teeth


def in_band(pts, coef, band):
    """Return the samples pts (3, M) within band of the plane coef (a, b, c): z = a x + b y + c."""
    resid = pts[2] - (coef[0] * pts[0] + coef[1] * pts[1] + coef[2])
    return pts[:, np.abs(resid) <= band]


def fit_every_hypothesis(depth, sub_rays, params):
    """fit_floor's plain loop: every hypothesis refined in full (no repeated-inlier skip)."""
    pts = floor.floor_samples(depth, sub_rays, params)
    if pts.shape[1] < params.floor_min_points:
        return None
    best = None
    for coef in floor.ransac_plane(pts, params):
        used = 0
        for band in floor.REFIT_BANDS_M:
            inliers = in_band(pts, coef, band)
            used = inliers.shape[1]
            if used < 3:
                break
            coef = floor.lstsq_plane(inliers)
        resid = pts[2] - (coef[0] * pts[0] + coef[1] * pts[1] + coef[2])
        support = int(np.count_nonzero(np.abs(resid) <= floor.REFIT_BANDS_M[-1]))
        if best is None or support > best[0]:
            best = (support, coef, used)
    return best


def _same_plane(a, b):
    return np.asarray(a).tobytes() == np.asarray(b).tobytes()


def test_skipping_repeated_refits_keeps_the_fit(kernel_path):
    skipped = 0
    for name, depth, sub_rays, params in suite_inputs():
        best = fit_every_hypothesis(depth, sub_rays, params)
        if best is None:
            continue
        pts = floor.floor_samples(depth, sub_rays, params)
        coef, used = floor.best_plane(pts, params)
        assert used == best[2] and _same_plane(coef, best[1]), name
        first, second = floor.ransac_plane(pts, params)
        skipped += _same_plane(in_band(pts, first, floor.REFIT_BANDS_M[0]),
                               in_band(pts, second, floor.REFIT_BANDS_M[0]))
    assert skipped >= 1   # some frame does take the shortcut


def test_corrected_mount_of_a_known_plane():
    # the floor z = 0.1 x - 0.05 = the configured frame pitched by atan(0.1) more, 5 cm lower
    from obstacle_detection.pipeline.params import corridor
    params = corridor(camera_height_m=0.6, camera_pitch_rad=math.radians(10.0),
                      camera_roll_rad=0.0)
    fit = floor.corrected_mount(params, 0.1, 0.0, -0.05, 500)
    norm = math.sqrt(1.01)
    assert fit.refined and fit.samples == 500
    assert fit.height_m == pytest.approx(0.65 / norm, abs=1e-12)
    assert fit.pitch_rad == pytest.approx(math.radians(10.0) + math.atan(0.1), abs=1e-12)
    assert fit.roll_rad == pytest.approx(0.0, abs=1e-12)


def _platform_samples(step_m=0.1):
    """(3, M) samples: the floor z = 0 beside a platform 18 cm up, |y| < 0.45, 1.8-3 m ahead."""
    x, y = np.meshgrid(np.arange(1.05, 3.0, step_m), np.arange(-1.5, 1.5, step_m))
    x, y = x.ravel(), y.ravel()
    z = np.where((np.abs(y) < 0.45) & (x > 1.8), 0.18, 0.0)
    return np.stack((x, y, z))


def test_the_floor_beneath_a_plane_run_through_a_platform():
    from obstacle_detection.pipeline.params import corridor
    params = corridor()
    pts = _platform_samples()
    # a plane tilted 3.9 deg in roll through the platform and the floor on one side, as the
    # RANSAC found on the scene open_ramp_ahead: the floor under it is found
    coef, used = floor.floor_beneath(pts, np.array([0.0, -0.068, 0.044]), 100, params)
    assert np.allclose(coef, 0.0, atol=1e-9) and used == np.count_nonzero(pts[2] == 0.0)
    # the floor itself has nothing beneath it: kept
    same, _ = floor.floor_beneath(pts, np.zeros(3), 100, params)
    assert np.array_equal(same, np.zeros(3))


def test_a_lower_floor_beyond_a_drop_is_not_the_floor():
    from obstacle_detection.pipeline.params import corridor
    params = corridor()
    pts = _platform_samples()
    pts[2] = np.where(pts[0] > 1.6, -0.3, 0.0)   # the floor drops 0.3 m 1.6 m ahead
    coef, _ = floor.floor_beneath(pts, np.zeros(3), 100, params)
    assert np.array_equal(coef, np.zeros(3))


def test_the_fit_of_the_open_ramp_seen_along_it_is_the_floor():
    # issue 22: a raised walkway in the middle of the view once tilted the fit by 3.9 deg
    for name, depth, sub_rays, params in suite_inputs():
        if name == 'open_ramp_ahead':
            fit = floor.fit_floor(depth, sub_rays, params)
            assert fit.refined and abs(fit.d_height_m) < 0.01, fit.summary()
            assert abs(fit.d_roll_deg) < 0.5 and abs(fit.d_pitch_deg) < 0.5, fit.summary()
            return
    pytest.fail('no open_ramp_ahead scene in the robot suite')
