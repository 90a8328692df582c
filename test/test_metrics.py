"""Metrics against confusion counts worked out by hand."""

import math

import numpy as np
import pytest

from obstacle_detection.labels import (CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN, GT_ABOVE_ROBOT,
                                       GT_NO_RETURN, GT_OBSTACLE, GT_TRAVERSABLE, LABEL_GROUND,
                                       LABEL_NO_RETURN, LABEL_OBSTACLE, LABEL_OUTSIDE_ROI)
from obstacle_detection.evaluation import metrics
from obstacle_detection.evaluation.metrics import Confusion


def test_confusion_counts_of_two_bool_arrays():
    predicted = np.array([1, 1, 0, 0, 1, 0], dtype=bool)
    truth = np.array([1, 0, 1, 0, 1, 0], dtype=bool)
    assert metrics.confusion(predicted, truth) == Confusion(tp=2, fp=1, fn=1, tn=2)


def test_scores_from_counts():
    c = Confusion(tp=6, fp=2, fn=3, tn=9)
    assert c.precision == pytest.approx(6 / 8)
    assert c.recall == pytest.approx(6 / 9)
    assert c.f1 == pytest.approx(12 / 17)
    assert c.iou == pytest.approx(6 / 11)
    assert c.false_alarm_rate == pytest.approx(2 / 11)
    assert c.accuracy == pytest.approx(15 / 20)


def test_undefined_ratios_are_nan():
    c = Confusion(tp=0, fp=0, fn=0, tn=5)
    assert math.isnan(c.precision) and math.isnan(c.recall) and math.isnan(c.f1)
    assert c.false_alarm_rate == 0.0


def test_confusions_add_up():
    assert Confusion(1, 2, 3, 4) + Confusion(10, 20, 30, 40) == Confusion(11, 22, 33, 44)



def test_pixel_confusion_excludes_no_return_and_unpredicted_pixels():
    # Columns: truth obstacle/traversable/no return; rows: pipeline calls.
    pipeline = np.array([
        [LABEL_OBSTACLE, LABEL_OBSTACLE, LABEL_OBSTACLE],
        [LABEL_GROUND, LABEL_GROUND, LABEL_GROUND],
        [LABEL_NO_RETURN, LABEL_OUTSIDE_ROI, LABEL_OBSTACLE],
        [LABEL_OBSTACLE, LABEL_GROUND, LABEL_OUTSIDE_ROI],
    ], dtype=np.uint8)
    truth = np.array([
        [GT_OBSTACLE, GT_TRAVERSABLE, GT_NO_RETURN],
        [GT_OBSTACLE, GT_TRAVERSABLE, GT_NO_RETURN],
        [GT_OBSTACLE, GT_OBSTACLE, GT_NO_RETURN],
        [GT_OBSTACLE, GT_OBSTACLE, GT_TRAVERSABLE],
    ], dtype=np.uint8)
    # Evaluated: rows 0-1 cols 0-1, row 3 cols 0-1 -> 6 pixels.
    # tp: (0,0), (3,0); fp: (0,1); fn: (1,0), (3,1); tn: (1,1).
    assert metrics.pixel_confusion(pipeline, truth) == Confusion(tp=2, fp=1, fn=2, tn=1)


def test_cell_confusion_on_hand_made_grids():
    o, f, u = CELL_OCCUPIED, CELL_FREE, CELL_UNKNOWN
    truth = np.array([[o, o, f, u],
                      [f, f, o, u],
                      [u, o, f, f]], dtype=np.int8)
    predicted = np.array([[o, f, o, o],
                          [f, o, u, u],
                          [o, o, f, u]], dtype=np.int8)
    # Known truth cells: 9. tp: (0,0), (2,1) = 2; fp: (0,2), (1,1) = 2;
    # fn: (0,1), (1,2) [pred unknown counts as negative] = 2; tn: (1,0), (2,2), (2,3) = 3.
    c = metrics.cell_confusion(predicted, truth)
    assert c == Confusion(tp=2, fp=2, fn=2, tn=3)
    assert c.iou == pytest.approx(2 / 6)
    assert c.false_alarm_rate == pytest.approx(2 / 5)


def test_truth_grid_occupied_wins_over_free():
    obstacle = np.array([[0.12, 0.01, 0.3]], dtype=np.float32)
    traversable = np.array([[0.11, 0.02, 0.0], [0.31, -0.04, 0.0], [5.0, 0.0, 0.0]],
                           dtype=np.float32)
    # Origin (0, -0.1), 0.1 m cells, 3 x 4 grid: obstacle cell ix=1, iy=1; free ix=3, iy=0.
    grid = metrics.truth_grid(obstacle, traversable, (0.0, -0.1), 0.1, (3, 4))
    expected = np.full((3, 4), CELL_UNKNOWN, np.int8)
    expected[1, 1] = CELL_OCCUPIED
    expected[0, 3] = CELL_FREE
    np.testing.assert_array_equal(grid, expected)


def test_truth_points_keeps_finite_roi_points():
    points = np.zeros((2, 2, 3), np.float32)
    points[0, 1] = np.nan
    labels = np.array([[GT_OBSTACLE, GT_OBSTACLE], [GT_TRAVERSABLE, GT_OBSTACLE]], np.uint8)
    roi = np.array([[True, True], [True, False]])
    obstacle, traversable = metrics.truth_points(points, labels, roi)
    assert obstacle.shape == (1, 3) and traversable.shape == (1, 3)


# -- robot-level helpers (issue 9) ------------------------------------------------------------

def test_above_robot_points_count_free_and_marked_points_occupied():
    points = np.array([[[0.1, 0.1, 1.5], [0.3, 0.1, 0.0]],
                       [[0.1, 0.3, 0.0], [0.3, 0.3, 0.2]]], np.float32)
    labels = np.array([[GT_ABOVE_ROBOT, GT_TRAVERSABLE],
                       [GT_TRAVERSABLE, GT_OBSTACLE]], np.uint8)
    roi = np.ones((2, 2), bool)
    marked = np.array([[False, True], [False, False]])
    obstacle, traversable = metrics.truth_points(points, labels, roi, marked)
    np.testing.assert_allclose(obstacle[:, :2], [[0.3, 0.1], [0.3, 0.3]], rtol=1e-6)
    np.testing.assert_allclose(traversable[:, :2], [[0.1, 0.1], [0.1, 0.3]], rtol=1e-6)
    grid = metrics.truth_grid(obstacle, traversable, (0.0, 0.0), 0.2, (2, 2))
    np.testing.assert_array_equal(grid, [[CELL_FREE, CELL_OCCUPIED], [CELL_FREE, CELL_OCCUPIED]])
    # a marked pixel without a return is not a point
    labels[0, 1] = GT_NO_RETURN
    obstacle, _ = metrics.truth_points(points, labels, roi, marked)
    assert obstacle.shape == (1, 3)


def test_point_cells_bins_like_the_truth_grid():
    points = np.array([[0.05, 0.05, 0.0], [0.25, 0.15, 0.0], [0.99, 0.0, 0.0],
                       [-0.01, 0.0, 0.0]])
    cells = metrics.point_cells(points, (0.0, 0.0), 0.1, (2, 3))
    expected = np.zeros((2, 3), bool)
    expected[0, 0] = expected[1, 2] = True
    np.testing.assert_array_equal(cells, expected)


def test_cell_share_counts_the_cells_hit_with_and_without_tolerance():
    grid = np.full((3, 4), CELL_UNKNOWN, np.int8)
    grid[0, 0] = CELL_OCCUPIED
    grid[2, 3] = CELL_FREE
    cells = np.zeros((3, 4), bool)
    cells[0, 0] = cells[1, 1] = cells[2, 3] = True
    occupied = grid == CELL_OCCUPIED
    assert metrics.cell_share(occupied, cells) == (1, 3)
    assert metrics.cell_share(metrics.grow_cells(occupied, 1), cells) == (2, 3)   # (1, 1)
    assert metrics.cell_share(metrics.grow_cells(occupied, 3), cells) == (3, 3)
    assert metrics.cell_share(grid == CELL_FREE, cells) == (1, 3)


def test_surface_gap_points_fill_sparse_samples_of_one_surface_only():
    points = np.array([[[0.0, 0.0, 0.5], [0.3, 0.0, 0.5], [0.32, 0.0, 0.5], [1.5, 0.0, 0.5]]])
    ids = np.array([[4, 4, 4, 4]], np.int16)
    mask = np.ones((1, 4), bool)
    gaps = metrics.surface_gap_points(points, ids, mask, step_m=0.05, max_gap_m=0.5)
    # only the first pair: 0.3 m apart (the second is closer than a step, the third too far)
    x = np.sort(gaps[:, 0])
    assert x.size == 9 and x.min() > 0.0 and x.max() < 0.3
    assert np.all(np.diff(x) <= 0.05) and np.all(gaps[:, 1:] == [0.0, 0.5])
    ids[0, 1] = 5   # another object: no surface between them
    assert metrics.surface_gap_points(points, ids, mask, step_m=0.05,
                                      max_gap_m=0.5).shape == (0, 3)


def test_tolerant_cells_count_a_mark_one_cell_off_and_not_two():
    truth = np.full((6, 8), CELL_FREE, np.int8)
    truth[2, 3] = CELL_OCCUPIED
    truth[0, 7] = CELL_UNKNOWN
    predicted = np.zeros((6, 8), np.int8)
    predicted[3, 4] = CELL_OCCUPIED     # one cell off (diagonal): counts both ways
    predicted[2, 6] = CELL_OCCUPIED     # three cells off: a far alarm
    predicted[0, 7] = CELL_OCCUPIED     # on an unscored cell: not counted
    tol = metrics.tolerant_cells(predicted, truth, cells=1)
    assert (tol.hit_truth, tol.truth) == (1, 1)
    assert (tol.hit_marked, tol.marked) == (1, 2)
    assert (tol.far_alarms, tol.free) == (1, 6 * 8 - 2)
    assert tol.f1 == pytest.approx(2 * 0.5 * 1.0 / 1.5)
    strict = metrics.tolerant_cells(predicted, truth, cells=0)
    assert strict.hit_truth == 0 and strict.far_alarms == 2
    pooled = tol + tol
    assert pooled.truth == 2 and pooled.far_alarm_rate == tol.far_alarm_rate
