"""Normals, slope test and validation against geometry whose answer is known.

Every test runs twice (the ``kernel_path`` fixture of test/conftest.py): on the numpy/scipy
path and on the compiled (numba) path, which is skipped where numba is not installed.
"""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from obstacle_detection.pipeline._compiled import knn as jit_knn
from obstacle_detection.pipeline.normals import (estimate_normals, nearest_neighbours,
                                                 neighbourhood_covariance, smallest_eigenvectors,
                                                 slope_obstacles, validate_obstacles)


pytestmark = pytest.mark.usefixtures('kernel_path')   # test/conftest.py: both paths


def plane_points(normal, n=400, seed=0, spread=1.0, noise=0.0):
    """Random points on the plane through the origin with the given normal."""
    rng = np.random.default_rng(seed)
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    helper = np.array([1.0, 0, 0]) if abs(normal[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    a, b = rng.uniform(-spread, spread, (2, n))
    pts = a[:, None] * u + b[:, None] * v + rng.normal(0, noise, n)[:, None] * normal
    return pts.astype(np.float32), normal


def test_knn_matches_brute_force_and_includes_self():
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 1, (300, 3)).astype(np.float32)
    idx = nearest_neighbours(pts, 8)
    np.testing.assert_array_equal(idx[:, 0], np.arange(300))
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    ref = np.argsort(d, axis=1, kind='stable')[:, :8]
    np.testing.assert_array_equal(np.sort(idx, axis=1), np.sort(ref, axis=1))


def test_knn_clips_k_to_cloud_size():
    pts = np.zeros((2, 3), np.float32) + np.array([[0, 0, 0], [1, 0, 0]], np.float32)
    assert nearest_neighbours(pts, 10).shape == (2, 2)


@pytest.mark.parametrize('normal', [(0, 0, 1), (1, 0, 0), (0.3, -0.2, 0.9), (1, 1, 1)])
def test_plane_normals(normal):
    pts, n = plane_points(normal, noise=0.001)
    normals = estimate_normals(pts, nearest_neighbours(pts, 10))
    np.testing.assert_allclose(np.abs(normals @ n), 1.0, atol=1e-3)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)


def test_normals_equal_per_point_eigh_loop():
    """The vectorised normals against an obviously right per-point loop (a few hundred)."""
    rng = np.random.default_rng(7)
    pts = rng.normal(0, 1, (300, 3)).astype(np.float32) * np.float32([1.0, 0.5, 0.1])
    nb = nearest_neighbours(pts, 10)
    fast = estimate_normals(pts, nb)
    for i in range(pts.shape[0]):
        q = pts[nb[i]].astype(np.float64)
        cov = np.cov(q.T, bias=True)
        w, v = np.linalg.eigh(cov)
        assert abs(abs(float(fast[i] @ v[:, 0])) - 1.0) < 1e-4, i


def test_closed_form_eigenvector_on_random_spd_and_degenerate():
    rng = np.random.default_rng(11)
    a = rng.normal(size=(2000, 3, 3))
    cov = a @ np.transpose(a, (0, 2, 1))
    cov[:5] = np.eye(3)                                   # isotropic: any vector is right
    cov[5:10] = np.diag([1.0, 1e-9, 1e-9])                # a line
    cov[10] = 0.0
    vec = smallest_eigenvectors(cov)
    w, v = np.linalg.eigh(cov)
    lam = np.einsum('vi,vij,vj->v', vec, cov, vec)
    np.testing.assert_allclose(np.linalg.norm(vec, axis=1), 1.0, atol=1e-9)
    err = np.abs(lam - w[:, 0]) / (1.0 + np.abs(w[:, 2]))
    assert err.max() < 1e-8


@pytest.mark.parametrize('slope_deg, expect_obstacle', [(0, False), (15, False), (29, False),
                                                       (31, True), (45, True), (90, True)])
def test_ramp_slope_test_at_theta_30(slope_deg, expect_obstacle):
    s = math.radians(slope_deg)
    # a ramp rising along x: normal (-sin s, 0, cos s)
    pts, _ = plane_points((-math.sin(s), 0.0, math.cos(s)), n=500, noise=0.0005)
    normals = estimate_normals(pts, nearest_neighbours(pts, 10))
    steep = slope_obstacles(normals, math.cos(math.radians(30)))
    assert steep.mean() == (1.0 if expect_obstacle else 0.0)


def test_validation_removes_isolated_noise_and_keeps_walls():
    wall, _ = plane_points((1, 0, 0), n=400, seed=2, spread=0.5)
    floor, _ = plane_points((0, 0, 1), n=2000, seed=3, spread=2.0)
    floor[:, 2] -= 0.5
    pts = np.vstack([wall, floor])
    flags = np.zeros(pts.shape[0], bool)
    flags[:400] = True                    # the wall is steep
    isolated = 400 + np.array([10, 500, 1500])
    flags[isolated] = True                # three noisy floor points
    nb = nearest_neighbours(pts, 13)
    kept = validate_obstacles(flags, nb, 12)
    assert not kept[isolated].any()
    assert kept[:400].mean() > 0.8        # only the wall's rim can lose points
    assert not kept[400:].any()
    # N1 = 0 switches validation off
    np.testing.assert_array_equal(validate_obstacles(flags, nb, 0), flags)


def test_validation_needs_all_n1_neighbours():
    pts = np.array([[i * 0.01, 0, 0] for i in range(6)], np.float32)
    flags = np.array([True, True, True, True, False, True])
    nb = nearest_neighbours(pts, 3)
    kept = validate_obstacles(flags, nb, 2)
    np.testing.assert_array_equal(kept, [True, True, True, False, False, False])
    # a cloud too small to give N1 neighbours validates nothing
    assert not validate_obstacles(flags, nb, 5).any()


def test_single_query_serves_both_stages():
    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 1, (500, 3)).astype(np.float32)
    nb = nearest_neighbours(pts, 13)
    _, ref = cKDTree(pts).query(pts, k=10)
    np.testing.assert_array_equal(np.sort(nb[:, :10], axis=1), np.sort(ref, axis=1))


def brute_force_order(points, k):
    """Neighbours by (squared float64 distance, index), the point itself first."""
    p = points.astype(np.float64)
    out = []
    for i in range(p.shape[0]):
        diff = p - p[i]
        d2 = (diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1]) + diff[:, 2] * diff[:, 2]
        d2[i] = -1.0
        out.append(np.lexsort((np.arange(p.shape[0]), d2))[:k])
    return np.array(out)


def test_equal_distances_are_ordered_by_index_self_first():
    """A lattice (many exact ties) and duplicated points give one well-defined answer."""
    axis = np.arange(6, dtype=np.float32) * np.float32(0.025)
    lattice = np.stack(np.meshgrid(axis, axis, axis), -1).reshape(-1, 3)
    rng = np.random.default_rng(9)
    twins = rng.uniform(0, 1, (80, 3)).astype(np.float32)
    for pts in (lattice, np.vstack([twins, twins])):
        ref = brute_force_order(pts, 13)
        np.testing.assert_array_equal(nearest_neighbours(pts, 13), ref)
        np.testing.assert_array_equal(nearest_neighbours.reference(pts, 13), ref)


def test_covariance_sums_in_column_order_in_float64():
    """The covariance equals a per-point loop summing the neighbours in order, bit for bit."""
    rng = np.random.default_rng(12)
    pts = (rng.normal(0, 0.02, (60, 3)) + [3000.0, -2000.0, 1.0]).astype(np.float32)
    nb = nearest_neighbours.reference(pts, 10)
    cov = neighbourhood_covariance(pts, nb)
    for i in range(pts.shape[0]):
        rel = pts[nb[i]].astype(np.float64) - pts[i].astype(np.float64)
        sums = rel[0].copy()
        second = np.outer(rel[0], rel[0])
        for t in range(1, 10):
            sums += rel[t]
            second += np.outer(rel[t], rel[t])
        mean = sums / 10
        np.testing.assert_array_equal(cov[i], second / 10 - np.outer(mean, mean))
    # millimetre spreads kilometres from the origin keep their precision
    ref = np.stack([np.cov(pts[nb[i]].astype(np.float64).T, bias=True) for i in range(60)])
    np.testing.assert_allclose(cov, ref, rtol=1e-9, atol=1e-15)


@pytest.mark.numba
def test_paths_agree_on_normals():
    """The compiled and the numpy normals are the same (to the last bit where libm agrees)."""
    rng = np.random.default_rng(13)
    pts = rng.normal(0, 1, (500, 3)).astype(np.float32) * np.float32([1.0, 0.6, 0.05])
    nb = nearest_neighbours.reference(pts, 10)
    numpy_normals = smallest_eigenvectors(neighbourhood_covariance(pts, nb)).astype(np.float32)
    np.testing.assert_allclose(jit_knn.normals_from_neighbours(pts, nb, 10), numpy_normals,
                               atol=1e-6)
