"""Normals, the slope test and neighbour validation (seed section 4.3.5).

One k-nearest-neighbour query serves both the normals (N neighbours) and the validation (N1
neighbours): it asks for ``max(N, N1 + 1)`` neighbours, the point itself first.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def nearest_neighbours(points: np.ndarray, k: int) -> np.ndarray:
    """Return indices (V, k) int64 of the k nearest points of every point, nearest first.

    points: (V, 3) float32 [m]. The point itself is among its own neighbours (first, at
    distance 0). Exact Euclidean search with a k-d tree on one thread. If there are fewer
    than k points, k is clipped to V.
    """
    n = points.shape[0]
    k = min(int(k), n)
    if n == 0 or k == 0:
        return np.zeros((n, max(k, 0)), dtype=np.int64)
    tree = cKDTree(points, leafsize=16, balanced_tree=False, compact_nodes=False)
    _, idx = tree.query(points, k=k, workers=1)
    idx = np.asarray(idx, dtype=np.int64).reshape(n, k)
    return idx


def neighbourhood_covariance(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Covariance (V, 3, 3) float64 of each point's neighbours (seed: C = 1/N sum (p-p̄)(p-p̄)ᵀ).

    points: (V, 3) [m]; neighbours: (V, N) indices into points. Coordinates are taken
    relative to each query point before summing, so float32 sums stay exact enough for
    millimetre-scale spreads far from the origin; only the six distinct entries are summed.
    """
    n_nb = neighbours.shape[1]
    pts_t = np.ascontiguousarray(points.T, dtype=np.float32)      # (3, V)
    rel = pts_t[:, neighbours]                                     # (3, V, N)
    rel -= pts_t[:, :, None]
    mean = rel.sum(axis=2) / np.float32(n_nb)                      # (3, V)
    cov = np.empty((points.shape[0], 3, 3), dtype=np.float64)
    for a, b in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):
        second = np.einsum('vk,vk->v', rel[a], rel[b]) / np.float32(n_nb)
        cov[:, a, b] = second - mean[a] * mean[b]
        cov[:, b, a] = cov[:, a, b]
    return cov


def smallest_eigenvectors(cov: np.ndarray) -> np.ndarray:
    """Return unit eigenvector (V, 3) float64 of the smallest eigenvalue of symmetric 3x3 matrices.

    Closed form, vectorised: the eigenvalues come from the trigonometric solution of the
    characteristic cubic; the eigenvector of the smallest one is the longest of the three
    cross products of the rows of ``C - lambda I``. Where the matrix is (near) isotropic or
    the smallest eigenvalue is degenerate, ``numpy.linalg.eigh`` is used for those rows. The
    sign of each vector is arbitrary: callers use ``|n . up|``.
    """
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
    r = np.clip(det_b / (2.0 * safe_p ** 3), -1.0, 1.0)
    phi = np.arccos(r) / 3.0
    lam_min = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)

    row0 = np.stack([a00 - lam_min, a01, a02], axis=1)
    row1 = np.stack([a01, a11 - lam_min, a12], axis=1)
    row2 = np.stack([a02, a12, a22 - lam_min], axis=1)
    crosses = np.stack([np.cross(row0, row1), np.cross(row0, row2), np.cross(row1, row2)])
    norms2 = np.einsum('cvi,cvi->cv', crosses, crosses)
    best = np.argmax(norms2, axis=0)
    rows = np.arange(c.shape[0])
    vec = crosses[best, rows]
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


def estimate_normals(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Return unit normals (V, 3) float32: smallest-eigenvalue eigenvector of each neighbourhood.

    neighbours: (V, N) indices from :func:`nearest_neighbours`, the point itself included.
    """
    if points.shape[0] == 0:
        return np.zeros((0, 3), dtype=np.float32)
    cov = neighbourhood_covariance(points, neighbours)
    return smallest_eigenvectors(cov).astype(np.float32)


def slope_obstacles(normals: np.ndarray, cos_max_slope: float,
                    up: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Seed slope test: (V,) bool, True where ``|n . up| < cos(theta)`` (too steep)."""
    up_vec = np.asarray(up, dtype=np.float32)
    return np.abs(normals @ up_vec) < np.float32(cos_max_slope)


def validate_obstacles(is_obstacle: np.ndarray, neighbours: np.ndarray, n1: int) -> np.ndarray:
    """Seed validation: an obstacle stays one only if its N1 nearest neighbours are obstacles.

    is_obstacle: (V,) bool from the slope test; neighbours: (V, k) nearest-first indices with
    the point itself in column 0 and k >= N1 + 1. A cloud too small to give a point N1
    neighbours (fewer than N1 + 1 columns) validates no obstacle. n1 = 0 disables validation.
    Returns (V,) bool.
    """
    if n1 <= 0 or is_obstacle.size == 0:
        return is_obstacle.copy()
    if neighbours.shape[1] < n1 + 1:
        return np.zeros_like(is_obstacle)
    neighbour_flags = is_obstacle[neighbours[:, 1:n1 + 1]]
    return is_obstacle & np.all(neighbour_flags, axis=1)
