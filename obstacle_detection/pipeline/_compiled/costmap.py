"""Compiled (numba) costmap rasterisation (optional): the cells points fall in.

:func:`rasterise` writes a value into the cells of a row-major grid that points fall in, with
the floating-point operations of ``pipeline.costmap.Costmap.cell_of`` in the points' dtype
(``floor((x - origin_x) / resolution)``, the origin and resolution rounded to that dtype as
numpy rounds a Python float next to a float32 array), so the grid equals the numpy path's.
"""

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
    """Write ``value`` into the cells of ``flat`` ((ny * nx,) int8) that ``points`` hit.

    points: (M, >= 2) float32 or float64 [m] (TypeError for another dtype).
    """
    if points.dtype not in (np.float32, np.float64):
        raise TypeError(f'points must be float32 or float64, got {points.dtype}')
    cast = points.dtype.type
    _raster_kernel(points, np.int8(value), cast(origin_xy_m[0]), cast(origin_xy_m[1]),
                   cast(resolution_m), int(nx), int(ny), flat)
