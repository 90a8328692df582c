"""The compiled k-NN and normals (optional numba) against scipy's k-d tree and numpy."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from obstacle_detection.pipeline._compiled import knn as jit_knn
from obstacle_detection.pipeline import normals
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.sim.scenes import render_scene, scene_params

pytestmark = pytest.mark.numba

PIPELINE_SCENES = ('corridor', 'people', 'farm_row')


def brute_force_knn(points, k):
    """Obviously right k-NN: full sort by (squared distance, index), the point itself first."""
    p = points.astype(np.float64)
    n = p.shape[0]
    k = min(k, n)
    out = np.empty((n, k), np.int64)
    for i in range(n):
        diff = p - p[i]
        d2 = (diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1]) + diff[:, 2] * diff[:, 2]
        d2[i] = -1.0
        out[i] = np.lexsort((np.arange(n), d2))[:k]
    return out


def distances(points, idx):
    """Euclidean distances (V, k) float64 of the neighbours idx, computed like cKDTree."""
    p = points.astype(np.float64)
    diff = p[idx] - p[:, None, :]
    return np.sqrt((diff[..., 0] ** 2 + diff[..., 1] ** 2) + diff[..., 2] ** 2)


def plane_cloud(rng, n, normal, noise):
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross(normal, [1.0, 0, 0] if abs(normal[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    a, b = rng.uniform(-1, 1, (2, n))
    return (a[:, None] * u + b[:, None] * v
            + rng.normal(0, noise, n)[:, None] * normal).astype(np.float32)


def small_clouds():
    """Clouds that stress the search: ties, duplicates, empty shells, sizes around k."""
    rng = np.random.default_rng(3)
    clouds = {f'uniform{n}': rng.uniform(-1, 1, (n, 3)).astype(np.float32)
              for n in (1, 2, 3, 5, 13, 14, 60)}
    axis = np.arange(5, dtype=np.float32) * np.float32(0.025)
    clouds['lattice'] = np.stack(np.meshgrid(axis, axis, axis), -1).reshape(-1, 3)
    twins = rng.uniform(0, 1, (60, 3)).astype(np.float32)
    clouds['duplicates'] = np.vstack([twins, twins, twins[:7]])
    clouds['one_place'] = np.full((25, 3), 1.5, np.float32)
    clouds['crowded_cell'] = np.vstack([np.full((150, 3), 0.5, np.float32),
                                        rng.uniform(0, 1, (40, 3)).astype(np.float32)])
    clouds['far_clusters'] = np.vstack([rng.normal(0, 0.01, (40, 3)),
                                        rng.normal(100, 0.01, (6, 3)),
                                        rng.normal(-1e4, 1, (3, 3))]).astype(np.float32)
    clouds['line'] = np.c_[np.linspace(0, 1, 80), np.zeros(80), np.zeros(80)].astype(np.float32)
    clouds['far_from_origin'] = (rng.uniform(0, 1, (150, 3)) + 1e4).astype(np.float32)
    # a cell table that would be too large: a coarser grid
    clouds['outlier'] = np.vstack([rng.uniform(0, 1, (300, 3)), np.full((1, 3), 1e3)]).astype(
        np.float32)
    return clouds


@pytest.fixture(scope='module')
def scene_points():
    """Voxel centroids (V, 3) float32 of a few scenes, by scene name."""
    points = {}
    for name in PIPELINE_SCENES:
        frame = render_scene(name)
        result = Detector(scene_params(frame)).process(frame.depth_mm, frame.intrinsics)
        points[name] = result.voxel_points
    return points


@pytest.mark.parametrize('name', list(small_clouds()))
@pytest.mark.parametrize('k', [1, 2, 3, 7, 13, 20])
def test_knn_equals_brute_force_order(name, k):
    """Exact neighbours in (distance, index) order, self first, k clipped to the cloud."""
    points = small_clouds()[name]
    got = jit_knn.knn_grid(points, k)
    np.testing.assert_array_equal(got, brute_force_knn(points, k))


@pytest.mark.parametrize('k', list(range(1, 21)))
def test_knn_matches_ckdtree_on_random_clouds(k):
    rng = np.random.default_rng(k)
    clouds = [rng.uniform(0, 1, (1500, 3)).astype(np.float32),
              plane_cloud(rng, 1500, (0.2, -0.3, 1.0), 0.002),
              np.vstack([plane_cloud(rng, 700, (0, 0, 1), 0.001),
                         plane_cloud(rng, 700, (1, 0, 0), 0.001) + np.float32(0.5)])]
    for points in clouds:
        got = jit_knn.knn_grid(points, k)
        ref_d, ref_i = cKDTree(points).query(points, k=k)
        ref_d = ref_d.reshape(len(points), k)
        ref_i = ref_i.reshape(len(points), k)
        np.testing.assert_allclose(distances(points, got), ref_d, rtol=1e-6, atol=1e-9)
        # where no two of a row's distances tie, the tree's order is the only right one
        distinct = np.all(np.diff(ref_d, axis=1) > 0, axis=1)
        np.testing.assert_array_equal(got[distinct], ref_i[distinct])
        np.testing.assert_array_equal(got, normals.nearest_neighbours.reference(points, k))


def test_knn_on_scene_voxel_centroids(scene_points):
    for name in PIPELINE_SCENES:
        points = scene_points[name]
        got = jit_knn.knn_grid(points, 13)
        ref_d, _ = cKDTree(points).query(points, k=13)
        np.testing.assert_allclose(distances(points, got), ref_d, rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(got, normals.nearest_neighbours.reference(points, 13))


@pytest.mark.parametrize('cell_m', [0.02, 0.1, 1.0, 10.0])
def test_knn_result_does_not_depend_on_grid(cell_m):
    """The cell size changes the speed only, never the answer."""
    rng = np.random.default_rng(8)
    points = np.vstack([plane_cloud(rng, 300, (0, 0.3, 1), 0.003),
                        rng.uniform(-3, 3, (20, 3))]).astype(np.float64)
    lo = points.min(axis=0)
    out = np.empty((points.shape[0], 9), np.int64)
    cell = np.full(3, cell_m)
    grid = jit_knn._build_grid(points, lo, cell)
    jit_knn._knn_queries(lo, cell, 9, 1e-12, *grid, out)
    np.testing.assert_array_equal(out, brute_force_knn(points, 9))


def test_knn_of_no_points_is_empty():
    assert jit_knn.knn_grid(np.zeros((0, 3), np.float32), 5).shape == (0, 0)


def well_conditioned(cov):
    """Rows whose smallest eigenvalue is well separated from the middle one."""
    w = np.linalg.eigvalsh(cov)
    return (w[:, 1] - w[:, 0]) > 1e-3 * np.maximum(w[:, 2], 1e-30)


def test_normals_match_numpy_path(scene_points):
    rng = np.random.default_rng(4)
    clouds = [rng.normal(0, 1, (800, 3)).astype(np.float32) * np.float32([1, 0.5, 0.1]),
              plane_cloud(rng, 800, (0.3, -0.2, 0.9), 0.001) + np.float32(500.0)]
    clouds += [scene_points[name] for name in PIPELINE_SCENES]
    for points in clouds:
        nb = jit_knn.knn_grid(points, 13)
        for n in (3, 10, 13):
            fast = jit_knn.normals_from_neighbours(points, nb, n)
            cov = normals.neighbourhood_covariance(points, nb[:, :n])
            slow = normals.smallest_eigenvectors(cov)
            ok = well_conditioned(cov)
            assert ok.mean() > 0.5
            np.testing.assert_allclose(np.linalg.norm(fast, axis=1), 1.0, atol=1e-6)
            np.testing.assert_allclose(np.abs(np.sum(fast[ok] * slow[ok], axis=1)), 1.0,
                                       atol=1e-5)


def test_normals_of_degenerate_neighbourhoods_are_unit_and_orthogonal():
    """A line or one repeated point has no unique normal; any orthogonal unit vector is right."""
    line = np.c_[np.linspace(0, 1, 30), np.linspace(0, 2, 30), np.zeros(30)].astype(np.float32)
    same = np.full((12, 3), 2.0, np.float32)
    for points in (line, same):
        nb = jit_knn.knn_grid(points, 10)
        fast = jit_knn.normals_from_neighbours(points, nb, 10)
        np.testing.assert_allclose(np.linalg.norm(fast, axis=1), 1.0, atol=1e-6)
    direction = np.array([1.0, 2.0, 0.0]) / np.sqrt(5.0)
    line_normals = jit_knn.normals_from_neighbours(line, jit_knn.knn_grid(line, 10), 10)
    np.testing.assert_allclose(line_normals @ direction, 0.0, atol=1e-5)
