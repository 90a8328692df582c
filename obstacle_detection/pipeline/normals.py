"""Normals, the slope test and neighbour validation (seed section 4.3.5).

One k-NN query of ``max(N, N1 + 1)`` neighbours, the point itself first, serves both.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from . import jit
from ._compiled import knn as jit_knn

# The six distinct entries of a symmetric 3 x 3 matrix: (0,0) (0,1) (0,2) (1,1) (1,2) (2,2).
_PAIR_A = np.array([0, 0, 0, 1, 1, 2])
_PAIR_B = np.array([0, 1, 2, 1, 2, 2])


def _reference_knn_grid(points: np.ndarray, k: int) -> np.ndarray:
    """Return indices (V, min(k, V)) int64 of the k nearest points: itself, then (d2, index)."""
    n = points.shape[0]
    k = min(int(k), n)
    if n == 0 or k <= 0:
        return np.zeros((n, max(k, 0)), dtype=np.int64)
    tree = cKDTree(points, leafsize=16, balanced_tree=False, compact_nodes=False)
    k_query = min(k + 1, n)
    dist, idx = tree.query(points, k=k_query, workers=1)
    dist = np.asarray(dist).reshape(n, k_query)
    idx = np.asarray(idx, dtype=np.int64).reshape(n, k_query)
    tied = np.flatnonzero(np.any(dist[:, 1:] == dist[:, :-1], axis=1))
    if tied.size:
        _order_ties(points, tree, idx, dist, tied, k)
    return np.ascontiguousarray(idx[:, :k])


nearest_neighbours = jit.choose(_reference_knn_grid, jit_knn.knn_grid)


def _order_ties(points: np.ndarray, tree: cKDTree, idx: np.ndarray, dist: np.ndarray,
                rows: np.ndarray, k: int) -> None:
    """Rewrite idx[rows, :k] in (squared distance, index) order, the query point first."""
    pts = np.asarray(points, dtype=np.float64)
    radius = dist[rows, k - 1] * (1.0 + 1e-9) + 1e-300     # a hair wider than the k-th
    for row, near in zip(rows, tree.query_ball_point(points[rows], radius, workers=1)):
        near = np.asarray(near, dtype=np.int64)
        diff = pts[near] - pts[row]
        d2 = (diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1]) + diff[:, 2] * diff[:, 2]
        d2[near == row] = -1.0
        idx[row, :k] = near[np.lexsort((near, d2))[:k]]


def neighbourhood_covariance(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Covariance (V, 3, 3) float64 of each point's neighbours (V, N), as the kernel sums it."""
    n_nb = neighbours.shape[1]
    pts_t = np.ascontiguousarray(points.T, dtype=np.float32).astype(np.float64)   # (3, V)
    rel = pts_t[:, np.ascontiguousarray(neighbours.T)]             # (3, N, V)
    rel -= pts_t[:, None, :]
    sums = rel[:, 0].copy()                                         # (3, V)
    second = rel[_PAIR_A, 0] * rel[_PAIR_B, 0]                      # (6, V)
    for t in range(1, n_nb):
        sums += rel[:, t]
        second += rel[_PAIR_A, t] * rel[_PAIR_B, t]
    mean = sums / n_nb
    cov = np.empty((points.shape[0], 3, 3), dtype=np.float64)
    for e, (a, b) in enumerate(zip(_PAIR_A, _PAIR_B)):
        cov[:, a, b] = second[e] / n_nb - mean[a] * mean[b]
        cov[:, b, a] = cov[:, a, b]
    return cov


def smallest_eigenvectors(cov: np.ndarray) -> np.ndarray:
    """Return unit eigenvectors (V, 3) of the smallest eigenvalue of 3x3 C (closed form)."""
    c = np.asarray(cov, dtype=np.float64)
    a00, a01, a02 = c[:, 0, 0], c[:, 0, 1], c[:, 0, 2]
    a11, a12, a22 = c[:, 1, 1], c[:, 1, 2], c[:, 2, 2]
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    safe_p = np.where(p > 0.0, p, 1.0)
    # det(B / p) / 2 with B = A - qI
    det_b = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
             + a02 * (a01 * a12 - b11 * a02))
    r = np.clip(det_b / (2.0 * (safe_p * safe_p * safe_p)), -1.0, 1.0)
    phi = np.arccos(r) / 3.0
    lam_min = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)

    r00, r11, r22 = a00 - lam_min, a11 - lam_min, a22 - lam_min
    # rows of C - lambda I: (r00, a01, a02), (a01, r11, a12), (a02, a12, r22)
    crosses = np.stack([_cross(r00, a01, a02, a01, r11, a12),
                        _cross(r00, a01, a02, a02, a12, r22),
                        _cross(a01, r11, a12, a02, a12, r22)])         # (3 pairs, 3, V)
    norms2 = crosses[:, 0] * crosses[:, 0] + crosses[:, 1] * crosses[:, 1]
    norms2 += crosses[:, 2] * crosses[:, 2]
    best = np.argmax(norms2, axis=0)
    rows = np.arange(c.shape[0])
    vec = crosses[best, :, rows]                                       # (V, 3)
    length = np.sqrt(norms2[best, rows])

    # Rows where the cross products vanish relative to the matrix scale: the two smallest
    # eigenvalues coincide (a line, a point) or the matrix is zero. Let LAPACK decide there.
    scale = np.maximum(p2, np.finfo(np.float64).tiny)
    bad = length * length <= 1e-12 * scale * scale
    out = np.empty_like(vec)
    good = ~bad
    out[good] = vec[good] / length[good, None]
    if np.any(bad):
        _, vecs = np.linalg.eigh(c[bad])
        out[bad] = vecs[:, :, 0]
    return out


def _cross(ux: np.ndarray, uy: np.ndarray, uz: np.ndarray,
           wx: np.ndarray, wy: np.ndarray, wz: np.ndarray) -> np.ndarray:
    """Cross products (3, V) of the vectors u and w given by their components (V,)."""
    return np.stack([uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx])


def _reference_normals_from_neighbours(points: np.ndarray, neighbours: np.ndarray,
                                       n: int) -> np.ndarray:
    """Return unit normals (V, 3) float32 of the first ``n`` neighbours, in numpy."""
    cov = neighbourhood_covariance(points, neighbours[:, :n])
    return smallest_eigenvectors(cov).astype(np.float32)


_normals_from_neighbours = jit.choose(_reference_normals_from_neighbours,
                                      jit_knn.normals_from_neighbours)


def estimate_normals(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Return unit normals (V, 3) float32 of the neighbourhoods (V, N), the point included."""
    if points.shape[0] == 0:
        return np.zeros((0, 3), dtype=np.float32)
    return _normals_from_neighbours(points, neighbours, neighbours.shape[1])


def slope_obstacles(normals: np.ndarray, cos_max_slope: float) -> np.ndarray:
    """Seed slope test: (V,) bool, True where ``|n . up| < cos(theta)`` (too steep)."""
    return np.abs(normals[:, 2]) < np.float32(cos_max_slope)


def validate_obstacles(is_obstacle: np.ndarray, neighbours: np.ndarray, n1: int) -> np.ndarray:
    """Seed validation: an obstacle stays one only if its N1 nearest neighbours are obstacles.

    neighbours: (V, k), the point itself first; fewer than N1 + 1 columns validate none.
    """
    if n1 <= 0 or is_obstacle.size == 0:
        return is_obstacle.copy()
    if neighbours.shape[1] < n1 + 1:
        return np.zeros_like(is_obstacle)
    return _validate(is_obstacle, neighbours, n1)


def _reference_validate(is_obstacle: np.ndarray, neighbours: np.ndarray, n1: int) -> np.ndarray:
    """:func:`validate_obstacles` for 1 <= n1 < neighbours.shape[1], in numpy."""
    neighbour_flags = is_obstacle[neighbours[:, 1:n1 + 1]]
    return is_obstacle & np.all(neighbour_flags, axis=1)


# compiled: the same flags without the (V, N1) gather (0.3 ms)
_validate = jit.choose(_reference_validate, jit_knn.validate)
