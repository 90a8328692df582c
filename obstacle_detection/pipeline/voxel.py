"""Voxel-grid downsampling (seed section 4.3.4): one centroid per occupied voxel."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._compiled import voxel as jit_voxel

#: Largest dense voxel lattice [cells] indexed directly; larger extents fall back to sorting.
_DENSE_LIMIT = 16_000_000


@dataclass(frozen=True)
class VoxelGrid:
    """Result of :func:`voxel_downsample`.

    centroids: (V, 3) float32, mean of the points in each occupied voxel [m].
    point_voxel: (M,) int64, for every input point the row of its voxel in ``centroids``.
    counts: (V,) int64, points per voxel.
    voxel_ijk: (V, 3) int64, integer voxel coordinates ``floor(p / size)``.
    """

    centroids: np.ndarray
    point_voxel: np.ndarray
    counts: np.ndarray
    voxel_ijk: np.ndarray


def voxel_downsample(points: np.ndarray, voxel_size_m: tuple[float, float, float],
                     ) -> VoxelGrid:
    """Replace the points of every occupied voxel by their centroid.

    points: (M, 3) float32 [m] (a view with contiguous columns, ``cols.T``, is fastest).
    Voxels are the cells ``[i*Vx, (i+1)*Vx) x [j*Vy, ...) x ...`` of a lattice anchored at
    the frame origin, so a point's voxel does not depend on the other points. Voxels are
    ordered by their linear index (x slowest, z fastest), so the output is deterministic.
    An empty input gives empty arrays. Runs the compiled kernel
    (:func:`.jit_voxel.voxel_downsample`, same result) when :func:`.jit_voxel.enabled`.
    """
    size = np.asarray(voxel_size_m, dtype=np.float64)
    if size.shape != (3,) or np.any(size <= 0.0):
        raise ValueError(f'voxel size {voxel_size_m!r} must be three positive numbers')
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f'points must have shape (M, 3), got {pts.shape}')
    if pts.shape[0] and jit_voxel.enabled():
        grid = jit_voxel.voxel_downsample(pts, voxel_size_m)
        if grid is not None:
            return grid
    return voxel_downsample_numpy(pts, voxel_size_m)


def voxel_downsample_numpy(points: np.ndarray, voxel_size_m: tuple[float, float, float],
                           ) -> VoxelGrid:
    """:func:`voxel_downsample` in numpy (the reference the compiled kernel matches)."""
    size = np.asarray(voxel_size_m, dtype=np.float64)
    pts = np.asarray(points)
    if pts.shape[0] == 0:
        return VoxelGrid(np.zeros((0, 3), np.float32), np.zeros(0, np.int64),
                         np.zeros(0, np.int64), np.zeros((0, 3), np.int64))

    cols = np.ascontiguousarray(pts.T)
    ijk = [np.floor(cols[a] / cols.dtype.type(size[a])).astype(np.int64) for a in range(3)]
    low = np.array([c.min() for c in ijk])
    dims = np.array([c.max() for c in ijk]) - low + 1
    keys = ijk[0] - low[0]
    keys *= dims[1]
    keys += ijk[1] - low[1]
    keys *= dims[2]
    keys += ijk[2] - low[2]
    n_cells = int(dims[0] * dims[1] * dims[2])

    if n_cells <= _DENSE_LIMIT:
        occupied = np.zeros(n_cells, dtype=bool)
        occupied[keys] = True
        cell_keys = np.flatnonzero(occupied)
        lookup = np.empty(n_cells, dtype=np.int64)  # read only where occupied
        lookup[cell_keys] = np.arange(cell_keys.size)
        point_voxel = lookup[keys]
    else:
        cell_keys, point_voxel = np.unique(keys, return_inverse=True)
        point_voxel = point_voxel.reshape(-1)
    n_vox = cell_keys.size

    counts = np.bincount(point_voxel, minlength=n_vox)
    centroids = np.empty((n_vox, 3), dtype=np.float32)
    for axis in range(3):
        sums = np.bincount(point_voxel, weights=cols[axis], minlength=n_vox)
        centroids[:, axis] = sums / counts
    vox_ijk = np.empty((n_vox, 3), dtype=np.int64)
    rest, vox_ijk[:, 2] = np.divmod(cell_keys, dims[2])
    vox_ijk[:, 0], vox_ijk[:, 1] = np.divmod(rest, dims[1])
    vox_ijk += low
    return VoxelGrid(centroids, point_voxel, counts, vox_ijk)
