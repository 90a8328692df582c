"""Compiled (numba) costmap rasterisation: ``Costmap.cell_of``'s operations, the points' dtype."""

from __future__ import annotations

import numpy as np

from ._numba import AVAILABLE, jit as _jit

__all__ = ['AVAILABLE', 'rasterise']


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
    if points.dtype not in (np.float32, np.float64):
        raise TypeError(f'points must be float32 or float64, got {points.dtype}')
    cast = points.dtype.type
    _raster_kernel(points, np.int8(value), cast(origin_xy_m[0]), cast(origin_xy_m[1]),
                   cast(resolution_m), int(nx), int(ny), flat)
