"""Seed 4.5 logistic refinement: the fit, the features, the model file."""

from types import SimpleNamespace

import numpy as np
import pytest

from obstacle_detection.labels import LABEL_GROUND, LABEL_NO_RETURN, LABEL_OBSTACLE
from obstacle_detection.pipeline import refine
from obstacle_detection.pipeline.depth import DepthFormatError
from obstacle_detection.pipeline.refine import FEATURE_NAMES, LogisticRefiner


def _known_model_data(n=20000, seed=0):
    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.normal(size=n), rng.normal(size=n), rng.random(n) < 0.3])
    true_w = np.array([-0.5, 2.0, -1.0, 1.5])
    p = 1.0 / (1.0 + np.exp(-(true_w[0] + x @ true_w[1:])))
    return x, rng.random(n) < p, true_w


def test_fit_recovers_known_coefficients():
    x, y, true_w = _known_model_data()
    w = refine.fit_logistic(x, y, l2=1e-6)
    np.testing.assert_allclose(w, true_w, atol=0.1)


def test_fit_stays_finite_on_separable_data():
    x = np.array([[-2.0], [-1.0], [1.0], [2.0]])
    w = refine.fit_logistic(x, np.array([0, 0, 1, 1]), l2=1e-3)
    assert np.isfinite(w).all() and w[1] > 0


def _fake_result(rng, height=12, width=16):
    """Return a DetectionResult-like object: a voxel per 2x2 block, random normals and depth."""
    rows, cols = np.mgrid[0:height, 0:width]
    pixel_voxel = (rows // 2) * (width // 2) + cols // 2
    pixel_voxel[0, :] = -1  # a row without voxels
    n_voxels = (height // 2) * (width // 2)
    normals = rng.normal(size=(n_voxels, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    labels = np.where(rng.random((height, width)) < 0.4, LABEL_OBSTACLE, LABEL_GROUND)
    labels[pixel_voxel < 0] = LABEL_NO_RETURN
    return SimpleNamespace(
        pixel_voxel=pixel_voxel.astype(np.int32), voxel_normals=normals,
        voxel_points=rng.random((n_voxels, 3)).astype(np.float32),
        depth_m=(1.0 + rng.random((height, width))).astype(np.float32),
        labels=labels.astype(np.uint8))


def test_neighbour_states_follow_seed_offsets():
    prev = np.zeros((5, 5), dtype=bool)
    prev[2, 2] = True  # row 2, column 2
    states = refine.neighbour_states(prev)
    for k, (dx, dy) in enumerate(refine.NEIGHBOUR_OFFSETS_XY):
        # Pixel (x, y) sees prev[y + dy, x + dx]; it is True only at x = 2 - dx, y = 2 - dy.
        assert states[2 - dy, 2 - dx, k]
        assert np.count_nonzero(states[:, :, k]) == 1


def test_features_of_pixels_with_voxels():
    result = _fake_result(np.random.default_rng(1))
    features, index = refine.pixel_features(result, None)
    assert features.shape == (index.size, len(FEATURE_NAMES))
    assert index.size == np.count_nonzero(result.pixel_voxel >= 0)
    expected_slope = np.abs(result.voxel_normals[result.pixel_voxel.reshape(-1)[index], 2])
    np.testing.assert_allclose(features[:, 0], expected_slope, rtol=1e-6)
    # Offset (0, 0) is the pixel's own previous state (here: the frame's own rule-based mask).
    own = refine.NEIGHBOUR_OFFSETS_XY.index((0, 0))
    np.testing.assert_array_equal(features[:, 2 + own],
                                  result.labels.reshape(-1)[index] == LABEL_OBSTACLE)


def test_model_file_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    result = _fake_result(rng)
    features, _ = refine.pixel_features(result, None)
    targets = rng.random(features.shape[0]) < 0.5
    model = LogisticRefiner.fit(features, targets, frames=3)
    path = tmp_path / 'refiner.json'
    model.save(path)
    loaded = LogisticRefiner.load(path)
    assert loaded == model
    prev = rng.random(result.labels.shape) < 0.5
    np.testing.assert_array_equal(loaded.predict_labels(result, prev),
                                  model.predict_labels(result, prev))


def test_model_file_with_other_features_is_refused(tmp_path):
    model = LogisticRefiner((0.0,) * 10, (0.0,) * 9, (1.0,) * 9)
    data = model.to_dict()
    data['features'] = data['features'][:-1]
    with pytest.raises(DepthFormatError, match='features'):
        LogisticRefiner.from_dict(data)


def test_predicted_pixels_only_where_voxels():
    result = _fake_result(np.random.default_rng(3))
    always = LogisticRefiner((50.0,) + (0.0,) * 9, (0.0,) * 9, (1.0,) * 9)
    mask = always.predict_labels(result, None)
    np.testing.assert_array_equal(mask, result.pixel_voxel >= 0)


def test_voxel_votes_are_majorities():
    pixel_voxel = np.array([[0, 0, 1, 1], [0, -1, 1, 2]])
    mask = np.array([[True, True, True, False], [False, True, False, True]])
    np.testing.assert_array_equal(refine.voxel_votes(pixel_voxel, mask, 4),
                                  [True, False, True, False])


def _small_scene_result(name='corridor', seed=0):
    from obstacle_detection.evaluation import runner as evaluation
    from obstacle_detection.pipeline.params import table_4_2
    from obstacle_detection.pipeline.detector import Detector
    frame = next(evaluation.scenario_frames(evaluation.Scenario(name, name, seeds=(seed,)),
                                            size=(160, 132)))
    params = frame.params(table_4_2())
    return frame, params, Detector(params).process(frame.depth, frame.intrinsics)


def test_refining_with_the_rule_based_mask_gives_the_rule_based_costmap():
    _, params, result = _small_scene_result()
    refined = refine.refine_result(result, refine.obstacle_mask(result),
                                   params.replace(validation_neighbours=0))
    np.testing.assert_array_equal(refined.voxel_is_obstacle, result.voxel_is_obstacle)
    np.testing.assert_array_equal(refined.costmap.data, result.costmap.data)
    np.testing.assert_array_equal(refined.labels, result.labels)
    assert refined.obstacle_points.shape == result.obstacle_points.shape


def test_refined_costmap_follows_the_refined_pixels():
    _, params, result = _small_scene_result()
    nothing = np.zeros(result.labels.shape, dtype=bool)
    refined = refine.refine_result(result, nothing, params)
    assert refined.obstacle_points.shape[0] == 0
    assert not (refined.costmap.data == 100).any()
    assert not (refined.labels == LABEL_OBSTACLE).any()


def test_evaluate_trains_the_refiner_and_scores_it_on_the_held_out_frames(tmp_path, capsys):
    import json

    from obstacle_detection.tools import evaluate
    out = tmp_path / 'model.json'
    code = evaluate.main(['--suite', 'seed', '--scene', 'corridor', '--scene', 'people',
                          '--scene', 'ramps',
                          '--max-frames', '1', '--train-frames', '1', '--quiet',
                          '--max-pixels', '5000', '--train-refiner', str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert 'refiner fitted on 1 frames' in text and f'refined by {out}' in text
    report = json.loads(text.splitlines()[-1])
    assert report['overall']['frames'] == 2 and 'refined' in report['overall']
    model = LogisticRefiner.load(out)
    assert model.coefficients[1] < 0  # steeper surface (smaller |n.up|) -> more likely obstacle
    # nothing left to score
    assert evaluate.main(['--suite', 'seed', '--scene', 'corridor', '--max-frames', '1',
                          '--train-frames', '1', '--train-refiner', str(out)]) == 2


def test_validation_drops_isolated_refined_voxels():
    _, params, result = _small_scene_result()
    rule = refine.obstacle_mask(result)
    speckled = rule.copy()
    ground_pixels = np.flatnonzero((result.pixel_voxel >= 0).reshape(-1) & ~rule.reshape(-1))
    lonely_voxel = result.pixel_voxel.reshape(-1)[ground_pixels[len(ground_pixels) // 2]]
    speckled[result.pixel_voxel == lonely_voxel] = True  # one floor voxel turned obstacle
    plain = refine.refine_result(result, speckled, params.replace(validation_neighbours=0))
    checked = refine.refine_result(result, speckled, params)
    assert plain.voxel_is_obstacle[lonely_voxel]
    assert not checked.voxel_is_obstacle[lonely_voxel]
    assert not (checked.voxel_is_obstacle & ~plain.voxel_is_obstacle).any()


def test_refined_detector_uses_the_previous_rule_based_mask():
    from obstacle_detection.pipeline.detector import Detector
    frame, params, first = _small_scene_result()
    # a model that predicts exactly "the pixel was an obstacle in the previous frame" (e4 is
    # offset (0, 0)): so the first frame stands in for itself, later frames copy the previous
    copy_previous = LogisticRefiner((-20.0,) + (0.0,) * 5 + (40.0,) + (0.0,) * 3,
                                    (0.0,) * 9, (1.0,) * 9)
    assert FEATURE_NAMES[5] == 'e4_prev(+0,+0)'
    stream = refine.RefinedDetector(Detector(params), copy_previous)
    out1 = stream.process(frame.depth, frame.intrinsics)
    np.testing.assert_array_equal(out1.labels == LABEL_OBSTACLE, refine.obstacle_mask(first))
    assert 'refine' in out1.timings_ms and out1.timings_ms['total'] >= out1.timings_ms['refine']
    empty = np.zeros_like(frame.depth)
    out2 = stream.process(empty, frame.intrinsics)      # nothing to label in an empty frame
    assert not (out2.labels == LABEL_OBSTACLE).any()
    out3 = stream.process(frame.depth, frame.intrinsics)  # previous mask: the empty frame's
    assert not (out3.labels == LABEL_OBSTACLE).any()
    assert out3.obstacle_points.shape[0] == 0
