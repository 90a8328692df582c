"""Costmap: projection of points onto the ground grid."""

import numpy as np
import pytest

from obstacle_detection.labels import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN
from obstacle_detection.pipeline.costmap import build_costmap, costmap_geometry
from obstacle_detection.pipeline.params import DetectorParams

P = DetectorParams(costmap_resolution_m=0.1, costmap_length_m=2.0, costmap_width_m=1.0)


def test_geometry_from_params():
    origin, nx, ny = costmap_geometry(P)
    assert (nx, ny) == (20, 10)
    assert origin == (0.0, -0.5)


def test_points_fall_in_the_right_cells():
    obstacles = np.array([[1.05, 0.05, 0.3], [1.05, 0.05, 0.9], [0.01, -0.49, 0.2]], np.float32)
    ground = np.array([[1.05, 0.05, 0.0], [1.55, -0.25, 0.01], [5.0, 0.0, 0.0]], np.float32)
    grid = build_costmap(obstacles, ground, P)
    assert grid.data.shape == (10, 20) and grid.data.dtype == np.int8
    assert grid.data[5, 10] == CELL_OCCUPIED      # obstacle wins over ground in one cell
    assert grid.data[0, 0] == CELL_OCCUPIED
    assert grid.data[2, 15] == CELL_FREE          # y = -0.25 -> row 2, x = 1.55 -> col 15
    assert (grid.data == CELL_OCCUPIED).sum() == 2
    assert (grid.data == CELL_FREE).sum() == 1    # the point at x = 5 m is off the grid
    assert (grid.data == CELL_UNKNOWN).sum() == 200 - 3
    row, col, inside = grid.cell_of(obstacles)
    np.testing.assert_array_equal(row, [5, 5, 0])
    np.testing.assert_array_equal(col, [10, 10, 0])
    assert inside.all()


def test_cell_centres():
    grid = build_costmap(np.zeros((0, 3)), np.zeros((0, 3)), P)
    x, y = grid.cell_centres()
    assert x[0] == 0.05 and np.isclose(y[0], -0.45)
    assert (grid.data == CELL_UNKNOWN).all()


def test_compiled_rasterisation_equals_numpy(both_paths):
    """Same cells for float32 and float64 points, edges, outside, NaN, inf and huge values."""
    params = DetectorParams(costmap_resolution_m=0.05, costmap_length_m=2.0,
                            costmap_width_m=4.0, camera_y_m=0.013)
    rng = np.random.default_rng(11)
    pts = rng.uniform(-0.5, 2.5, (4000, 3))
    pts[:, 1] = rng.uniform(-2.5, 2.5, 4000)
    origin, nx, ny = costmap_geometry(params)
    pts[:50, 0] = origin[0] + np.arange(50) * 0.05        # on cell borders
    pts[50:100, 1] = origin[1] + np.arange(50) * 0.05
    pts[100:110] = [np.nan, 0.0, 0.0]
    pts[110:120] = [np.inf, 1.0, 0.0]
    pts[120:130] = [1.0, -np.inf, 0.0]
    pts[130:140] = [1e30, 1e30, 0.0]
    for dtype in (np.float32, np.float64):
        p = pts.astype(dtype)
        obstacles, ground = p[:1500], p[1500:]
        with np.errstate(invalid='ignore'):   # numpy's cast of NaN and inf to int warns
            grid = both_paths(build_costmap, obstacles, ground, params)
        assert set(np.unique(grid.data)) == {CELL_UNKNOWN, CELL_FREE, CELL_OCCUPIED}


def test_halo_cells_are_the_sparse_border_tail_of_a_dense_neighbour():
    from obstacle_detection.pipeline.costmap import HALO_SHARE, halo_voxels

    # P: 0.1 m cells, origin (0, -0.5). A face at x = 1.005 (cell column 10) holds 2000 px.
    face = np.array([[1.005, 0.05, 0.3]], np.float32)
    near_border = np.array([[0.995, 0.05, 0.3]], np.float32)   # column 9, its half at x = 1.0
    far_half = np.array([[0.92, 0.05, 0.3]], np.float32)       # column 9, the other half
    pixels = 2000.0
    few = int(HALO_SHARE * pixels) - 1
    for points, counts, expected in (
            ((face, near_border), (pixels, few), [False, True]),    # the range-noise tail
            ((face, near_border), (pixels, few + 2), [False, False]),   # 1 % or more: a surface
            ((face, far_half), (pixels, few), [False, False]),      # not at the border
            ((near_border,), (few,), [False])):                     # nothing beside it
        got = halo_voxels(np.concatenate(points), np.array(counts, np.int64), P)
        assert got.tolist() == expected, (points, counts)


def test_halo_is_decided_per_cell_and_ignores_points_outside_the_grid():
    from obstacle_detection.pipeline.costmap import halo_voxels

    points = np.array([[1.005, 0.05, 0.3], [0.995, 0.05, 0.2], [0.99, 0.04, 0.6],
                       [9.0, 0.0, 0.1]], np.float32)
    counts = np.array([5000, 10, 30, 10], np.int64)   # cell 9 holds 40 < 1 % of 5000
    assert halo_voxels(points, counts, P).tolist() == [False, True, True, False]
    counts[2] = 60                                     # 70: 1.4 %, kept
    assert halo_voxels(points, counts, P).tolist() == [False, False, False, False]


@pytest.mark.numba
def test_compiled_halo_equals_numpy(both_paths):
    """The same halo flags: known cells, float32 and float64, outside, NaN, inf, huge values."""
    from obstacle_detection.pipeline.costmap import halo_voxels

    rng = np.random.default_rng(5)
    origin, nx, ny = costmap_geometry(P)
    for trial in range(40):
        n = int(rng.integers(1, 600))
        pts = np.empty((n, 3))
        pts[:, 0] = origin[0] + rng.uniform(-2.0, nx + 2.0, n) * 0.1
        pts[:, 1] = origin[1] + rng.uniform(-2.0, ny + 2.0, n) * 0.1
        pts[:, 2] = rng.uniform(0.0, 1.0, n)
        border = rng.random(n) < 0.2                          # on cell borders
        pts[border, 0] = origin[0] + rng.integers(0, nx, border.sum()) * 0.1
        pts[:3, trial % 2] = (np.nan, np.inf, 1e30)[trial % 3]
        dense = rng.random(n) < 0.3                           # faces beside sparse tails
        counts = np.where(dense, rng.integers(1000, 5000, n), rng.integers(1, 40, n))
        for dtype in (np.float32, np.float64):
            with np.errstate(invalid='ignore'):   # numpy's cast of NaN and inf to int warns
                both_paths(halo_voxels, pts.astype(dtype), counts, P)
    # the known halo of the test above: a face at x = 1.005, its tail at 0.995
    points = np.array([[1.005, 0.05, 0.3], [0.995, 0.05, 0.2], [0.99, 0.04, 0.6],
                       [9.0, 0.0, 0.1]], np.float32)
    got = both_paths(halo_voxels, points, np.array([5000, 10, 30, 10], np.int64), P)
    assert got.tolist() == [False, True, True, False]
