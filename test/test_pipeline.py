"""The whole pipeline on ray-cast scenes whose ground truth is known."""

import math

import numpy as np
import pytest

from obstacle_detection.labels import (CELL_OCCUPIED, CELL_UNKNOWN, GT_OBSTACLE, LABEL_GROUND,
                                       LABEL_NO_RETURN, LABEL_OBSTACLE, LABEL_OUTSIDE_ROI)
from obstacle_detection.pipeline import geometry
from obstacle_detection.evaluation import metrics
from obstacle_detection.pipeline.costmap import build_costmap
from obstacle_detection.pipeline.depth import DepthFormatError
from obstacle_detection.pipeline.params import SEED_TABLE_4_1, table_4_2
from obstacle_detection.pipeline.detector import STAGES, Detector
from obstacle_detection.sim.scenes import render_scene, scene_params

#: Costmap F1 floor on the corridor scene with the seed's Table 4.2 (K = 5). The detector
#: marks the walls and box sides; it misses the cells whose only obstacle surface is a box
#: top: flat, so "ground" by the seed's slope test. The corridor's boxes are large, their tops
#: cover about half the truth cells, and the measured F1 is 0.54-0.59 on seeds 0-4. The floor
#: sits under that with room for noise, not for a broken stage (without validation, or with
#: normals off by a few degrees, it falls far lower).
CORRIDOR_F1_FLOOR = 0.5


def run(frame, **overrides):
    params = scene_params(frame, table_4_2(**overrides))
    return params, Detector(params).process(frame.depth_mm, frame.intrinsics)


def truth_cells(frame, params, primitive=None):
    """Truth grid of a frame; with ``primitive``, only that primitive's visible vertical faces.

    The seed's slope-only truth (``labels_seed``): these tests run the seed preset.

    A box's top is flat, so the seed's slope test calls it ground by design; the per-primitive
    truth leaves it out (the whole-frame truth keeps it, and the F1 below pays for it).
    """
    flat = frame.points_ground.reshape(-1, 3)
    finite = np.isfinite(flat).all(axis=1)
    roi = np.zeros(flat.shape[0], bool)
    roi[finite] = geometry.roi_mask(flat[finite], params)
    roi = roi.reshape(frame.labels.shape)
    if primitive is not None:
        roi &= frame.hit_index == primitive
        top = getattr(frame.primitives[primitive], 'max_m', (0.0, 0.0, np.inf))[2]
        roi &= ~(frame.points_ground[..., 2] > top - 1e-3)
    obstacle, free = metrics.truth_points(frame.points_ground, frame.labels_seed, roi)
    return build_costmap(obstacle, free, params).data


@pytest.mark.parametrize('pitch_deg', [0, 10, 20, 30, 40, 45])
def test_flat_floor_has_no_obstacle_at_any_pitch(pitch_deg):
    frame = render_scene('flat_floor', seed=pitch_deg, pitch_rad=math.radians(pitch_deg))
    _, result = run(frame, median_kernel=5)
    assert result.obstacle_points.shape[0] == 0
    assert not (result.costmap.data == CELL_OCCUPIED).any()
    assert result.ground_points.shape[0] > 500           # the floor was seen


def test_corridor_boxes_and_walls_are_occupied():
    frame = render_scene('corridor', seed=0)
    params, result = run(frame, median_kernel=5)
    occupied = result.costmap.data == CELL_OCCUPIED
    near = occupied.copy()                                   # occupied or next to it
    near[1:] |= occupied[:-1]
    near[:-1] |= occupied[1:]
    near[:, 1:] |= occupied[:, :-1]
    near[:, :-1] |= occupied[:, 1:]
    checked = 0
    for index, prim in enumerate(frame.primitives):
        if type(prim).__name__ not in ('Box', 'Wall'):
            continue
        cells = truth_cells(frame, params, index) == CELL_OCCUPIED
        if cells.sum() < 3:                                  # out of view or a sliver
            continue
        checked += 1
        share, near_share = occupied[cells].mean(), near[cells].mean()
        assert share > 0.6, f'{type(prim).__name__} {index}: only {share:.2f} occupied'
        assert near_share >= 0.8, f'{type(prim).__name__} {index}: {near_share:.2f} near'
    assert checked >= 4                                      # two walls and the boxes


def test_corridor_costmap_f1_above_floor():
    scores = []
    for seed in range(3):
        frame = render_scene('corridor', seed=seed)
        params, result = run(frame, median_kernel=5)
        conf = metrics.cell_confusion(result.costmap.data, truth_cells(frame, params))
        scores.append(conf.f1)
    print(f'corridor costmap F1 per seed: {[round(s, 3) for s in scores]}')
    assert min(scores) > CORRIDOR_F1_FLOOR


def test_labels_agree_with_voxels_and_depth():
    frame = render_scene('people', seed=1)
    _, result = run(frame, median_kernel=5)
    labels, pv = result.labels, result.pixel_voxel
    assert labels.shape == frame.depth_mm.shape and labels.dtype == np.uint8
    np.testing.assert_array_equal(labels == LABEL_NO_RETURN, result.depth_m == 0)
    in_roi = pv >= 0
    np.testing.assert_array_equal(in_roi, (labels == LABEL_GROUND) | (labels == LABEL_OBSTACLE))
    np.testing.assert_array_equal(labels[in_roi] == LABEL_OBSTACLE,
                                  result.voxel_is_obstacle[pv[in_roi]])
    assert (labels == LABEL_OUTSIDE_ROI).any()
    # obstacle pixels are mostly true obstacles
    truth = frame.labels_seed[labels == LABEL_OBSTACLE]   # the seed's slope-only truth
    assert (truth == GT_OBSTACLE).mean() > 0.9
    # validated obstacles are a subset of the slope test's
    assert not (result.voxel_is_obstacle & ~result.voxel_slope_obstacle).any()
    assert set(result.timings_ms) == {*STAGES, 'total'}


def test_obstacle_points_are_the_obstacle_voxels():
    frame = render_scene('corridor', seed=2)
    _, result = run(frame, median_kernel=5)
    np.testing.assert_array_equal(result.obstacle_points,
                                  result.voxel_points[result.voxel_is_obstacle])
    np.testing.assert_array_equal(result.ground_points,
                                  result.voxel_points[~result.voxel_is_obstacle])
    assert result.obstacle_points.dtype == np.float32


def test_uint16_and_float32_depth_give_the_same_result():
    frame = render_scene('ramps', seed=0)
    params = scene_params(frame, table_4_2(median_kernel=5))
    det = Detector(params)
    a = det.process(frame.depth_mm, frame.intrinsics)
    b = det.process(frame.depth_mm.astype(np.float32) / 1000.0, frame.intrinsics)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.costmap.data, b.costmap.data)


def test_missing_intrinsics_fall_back_to_table_4_1():
    frame = render_scene('corridor', seed=0)
    result = Detector(table_4_2(median_kernel=5)).process(frame.depth_mm)
    assert result.intrinsics == SEED_TABLE_4_1


@pytest.mark.parametrize('depth', [np.zeros((424, 512), np.uint16),
                                   np.full((424, 512), np.nan, np.float32)],
                         ids=['zeros', 'nan'])
def test_frame_without_returns_gives_an_empty_result(depth):
    result = Detector(table_4_2(median_kernel=5)).process(depth)
    assert result.obstacle_points.shape == (0, 3)
    assert result.ground_points.shape == (0, 3)
    assert (result.labels == LABEL_NO_RETURN).all()
    assert (result.costmap.data == CELL_UNKNOWN).all()


@pytest.mark.parametrize('depth, pattern', [
    (np.zeros((4, 4), np.int8), 'int8'),
    (np.zeros((4, 4, 3), np.uint16), r'\(4, 4, 3\)'),
    (np.zeros((0, 4), np.float32), r'\(0, 4\)'),
], ids=['dtype', 'shape', 'empty'])
def test_bad_depth_raises_a_clear_error(depth, pattern):
    with pytest.raises(DepthFormatError, match=pattern):
        Detector().process(depth)


def test_crop_removes_border_pixels():
    frame = render_scene('corridor', seed=0)
    _, result = run(frame, median_kernel=1, crop_top_px=30, crop_left_px=20, crop_right_px=10,
                    crop_bottom_px=5)
    labels = result.labels
    assert (labels[:30] == LABEL_NO_RETURN).all() and (labels[-5:] == LABEL_NO_RETURN).all()
    assert (labels[:, :20] == LABEL_NO_RETURN).all()
    assert (labels[:, -10:] == LABEL_NO_RETURN).all()
    assert (labels[30:-5, 20:-10] != LABEL_NO_RETURN).mean() > 0.5


def test_outputs_are_in_the_base_frame_of_a_camera_off_the_base_origin(monkeypatch) -> None:
    """A box 1 m ahead of a camera at x = 0.2 m, y = 0.1 m, yaw = 10 deg on the robot."""
    import dataclasses

    from obstacle_detection.pipeline import costmap
    from obstacle_detection.pipeline.params import PRESETS

    # the halo is decided on the base frame's cells, whose borders a moved camera moves
    monkeypatch.setattr(costmap, 'HALO_SHARE', 0.0)
    from obstacle_detection.sim.primitives import Box, Floor
    from obstacle_detection.sim.render import render, Scene

    frame = render(Scene('box_ahead', (Floor(), Box.on_floor(1.05, 0.0, 0.1, 0.3, 0.5))),
                   seed=1)
    at_origin = PRESETS['corridor']()
    mounted = dataclasses.replace(at_origin, camera_x_m=0.2, camera_y_m=0.1,
                                  camera_yaw_rad=math.radians(10.0))
    here = Detector(at_origin).process(frame.depth_mm, frame.intrinsics)
    there = Detector(mounted).process(frame.depth_mm, frame.intrinsics)

    c, s = math.cos(math.radians(10.0)), math.sin(math.radians(10.0))
    expected = here.obstacle_points.astype(np.float64) @ np.array(
        [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) + np.array([0.2, 0.1, 0.0])
    np.testing.assert_allclose(there.obstacle_points, expected, atol=1e-6)
    # the box's front face, x = 1.0 m ahead of the camera, is at R(10 deg) (1.0, 0) + (0.2,
    # 0.1) = (1.185, 0.274) m in the base frame: that cell is occupied, its camera-frame twin
    # (1.0, 0.0) is not when the camera is off the origin.
    row, col, inside = there.costmap.cell_of(np.array([[0.2 + c, 0.1 + s, 0.0]]))
    assert inside[0] and there.costmap.data[row[0], col[0]] == CELL_OCCUPIED
    assert there.costmap.origin_xy_m[0] == pytest.approx(0.2)
    assert there.costmap.origin_xy_m[1] == pytest.approx(0.1 - 2.0)
    row, col, inside = there.costmap.cell_of(np.array([[1.0, -0.1, 0.0]]))
    assert not inside[0] or there.costmap.data[row[0], col[0]] != CELL_OCCUPIED
