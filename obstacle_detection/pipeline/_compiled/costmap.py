"""Compiled (numba) costmap kernels: ``Costmap.cell_of``'s operations, the points' dtype."""

from __future__ import annotations

import numpy as np

from ._numba import jit as _jit


@_jit
def _raster_kernel(points, value, ox, oy, res, nx, ny, flat):  # pragma: no cover - compiled
    """flat[row * nx + col] = value for every point inside the nx x ny grid."""
    for p in range(points.shape[0]):
        col = np.floor((points[p, 0] - ox) / res)
        row = np.floor((points[p, 1] - oy) / res)
        # compared as floats: an integer cast of NaN or of a huge value would be undefined
        if col >= 0 and col < nx and row >= 0 and row < ny:
            flat[np.int64(row) * nx + np.int64(col)] = value


def rasterise(flat: np.ndarray, points: np.ndarray, value: int,
              origin_xy_m: tuple[float, float], resolution_m: float, nx: int, ny: int) -> None:
    """Write ``value`` into the cells of ``flat`` that points (M, >= 2) float32/64 hit."""
    cast = points.dtype.type
    _raster_kernel(points, np.int8(value), cast(origin_xy_m[0]), cast(origin_xy_m[1]),
                   cast(resolution_m), int(nx), int(ny), flat)


@_jit
def _halo_kernel(points, weights, ox, oy, res, nx, ny, share):  # pragma: no cover - compiled
    """(V,) bool: voxel v lies in a halo cell (costmap.halo_voxels, its float operations)."""
    n = points.shape[0]
    out = np.empty(n, np.bool_)
    held = np.zeros(nx * ny)
    total_x = np.zeros(nx * ny)
    total_y = np.zeros(nx * ny)
    cells = np.empty(n, np.int64)
    for v in range(n):
        tx = (points[v, 0] - ox) / res
        ty = (points[v, 1] - oy) / res
        col = np.floor(tx)
        row = np.floor(ty)
        if col >= 0 and col < nx and row >= 0 and row < ny:
            c = np.int64(row) * nx + np.int64(col)
            w = weights[v]
            held[c] += w
            total_x[c] += w * (np.float64(tx) - np.float64(np.int64(col)) - 0.5)
            total_y[c] += w * (np.float64(ty) - np.float64(np.int64(row)) - 0.5)
            cells[v] = c
        else:   # the numpy path adds 0 * offset to cell 0: NaN for a point at NaN or inf
            cells[v] = -1
            if not np.isfinite(tx):
                total_x[0] += np.nan
            if not np.isfinite(ty):
                total_y[0] += np.nan
    for v in range(n):
        c = cells[v]
        out[v] = False
        if c < 0:
            continue
        cx = c % nx
        cy = c // nx
        scale = max(held[c], 1.0)
        off_x = total_x[c] / scale
        off_y = total_y[c] / scale
        beside = 0.0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                bx = cx + dx
                by = cy + dy
                if (dx == 0 and dy == 0) or bx < 0 or bx >= nx or by < 0 or by >= ny:
                    continue
                if np.float64(dx) * off_x >= 0.0 and np.float64(dy) * off_y >= 0.0:
                    beside = max(beside, held[by * nx + bx])
        out[v] = held[c] < share * beside
    return out


def halo_voxels(points: np.ndarray, counts: np.ndarray, origin_xy_m: tuple[float, float],
                resolution_m: float, nx: int, ny: int, share: float) -> np.ndarray:
    """(V,) bool: costmap's halo_voxels on the grid given, points (V, >= 2) float32/64."""
    cast = points.dtype.type
    return _halo_kernel(points, counts.astype(np.float64), cast(origin_xy_m[0]),
                        cast(origin_xy_m[1]), cast(resolution_m), int(nx), int(ny), float(share))
