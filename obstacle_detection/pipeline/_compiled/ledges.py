"""Compiled (numba) ledges: ``pipeline.traversal.ledges`` in one pass, the same flags."""

from __future__ import annotations

import numpy as np

from ._numba import jit as _jit
from .traversal import grid_cells

#: The 8 directions of the search across an edge (the numpy path's order; min is exact).
_DX = np.array((1, 0, -1, 0, 1, 1, -1, -1), np.int64)
_DY = np.array((0, 1, 0, -1, 1, -1, 1, -1), np.int64)


@_jit
def _ledges_kernel(points, steep, reached, above, size, step_up, step_down, shadow_cells,
                   out):  # pragma: no cover - compiled
    """out[v] = the voxel lies on a ledge (see ``pipeline.traversal.ledges``)."""
    n = points.shape[0]
    ix, iy, nx, ny, ox, oy = grid_cells(points, size)
    surface = np.full((nx, ny), np.inf)
    lowest = np.full((nx, ny), np.inf)
    seen = np.zeros((nx, ny), np.bool_)
    for v in range(n):
        cx = ix[v]
        cy = iy[v]
        seen[cx, cy] = True
        if not steep[v] and np.float64(points[v, 2]) < lowest[cx, cy]:
            lowest[cx, cy] = np.float64(points[v, 2])
        if reached[v] and not steep[v]:
            z = np.float64(points[v, 2])
            if z < surface[cx, cy]:
                surface[cx, cy] = z
    low = np.full((nx, ny), np.inf)
    high = np.full((nx, ny), -np.inf)
    for cx in range(nx):
        for cy in range(ny):
            lo = np.inf
            hi = -np.inf
            empty = False
            for ax in range(cx - 1, cx + 2):
                for ay in range(cy - 1, cy + 2):
                    if ax < 0 or ax >= nx or ay < 0 or ay >= ny:
                        continue
                    s = surface[ax, ay]
                    if s < lo:
                        lo = s
                    if s < np.inf and s > hi:
                        hi = s
                    if not seen[ax, ay]:
                        empty = True
            high[cx, cy] = hi
            if empty and surface[cx, cy] < np.inf:   # across the edge, over empty cells
                px = cx + ox + 0.5
                py = cy + oy + 0.5
                for d in range(8):
                    sx = _DX[d]
                    sy = _DY[d]
                    if sx * px < 0.0 or sy * py < 0.0:
                        continue
                    wx = cx
                    wy = cy
                    for k in range(1, shadow_cells + 1):
                        wx += sx
                        wy += sy
                        if wx < 0 or wx >= nx or wy < 0 or wy >= ny:
                            break
                        if seen[wx, wy]:
                            if k > 1 and lowest[wx, wy] < lo:
                                lo = lowest[wx, wy]
                            break
            low[cx, cy] = lo
    for v in range(n):
        cx = ix[v]
        cy = iy[v]
        lo = low[cx, cy]
        floor_low = lo >= -step_down and lo <= step_up
        if above[v]:
            out[v] = False
        elif reached[v]:
            s = surface[cx, cy]
            out[v] = (s - lo > step_down
                      and not (floor_low and s >= -step_down and s <= step_up))
            if not steep[v]:   # a cell the edge crosses: its raised voxels, by their own z
                zv = np.float64(points[v, 2])
                out[v] = out[v] or (zv - lo > step_down and not (
                    floor_low and zv >= -step_down and zv <= step_up))
        else:
            hi = high[cx, cy]
            out[v] = (hi - lo > step_up
                      and not (floor_low and hi >= -step_down and hi <= step_up)
                      and np.float64(points[v, 2]) - lo > step_up)


def ledges(points: np.ndarray, steep: np.ndarray, reached: np.ndarray, above: np.ndarray,
           size_m: float, step_up_m: float, step_down_m: float,
           shadow_cells: int) -> np.ndarray:
    """(V,) bool: ``pipeline.traversal.ledges`` compiled (the same flags)."""
    out = np.zeros(points.shape[0], np.bool_)
    if points.shape[0] == 0:
        return out
    _ledges_kernel(np.ascontiguousarray(points, np.float32), steep, reached, above,
                   np.float32(size_m), float(step_up_m), float(step_down_m),
                   int(shadow_cells), out)
    return out


@_jit
def _voxel_ijk(points, vx, vy, vz):  # pragma: no cover - compiled
    """(V, 3) voxel indices from 1, as the numpy twins: ``floor(p / v) + 1 - min``."""
    n = points.shape[0]
    ijk = np.empty((n, 3), np.int64)
    for v in range(n):
        ijk[v, 0] = np.int64(np.floor(points[v, 0] / vx))
        ijk[v, 1] = np.int64(np.floor(points[v, 1] / vy))
        ijk[v, 2] = np.int64(np.floor(points[v, 2] / vz))
    lo0, lo1, lo2 = ijk[:, 0].min(), ijk[:, 1].min(), ijk[:, 2].min()
    for v in range(n):
        ijk[v, 0] += 1 - lo0
        ijk[v, 1] += 1 - lo1
        ijk[v, 2] += 1 - lo2
    return ijk


@_jit
def _lone_kernel(points, vx, vy, vz, out):  # pragma: no cover - compiled
    """out[v] = no other voxel lies in the 26 voxels around voxel v."""
    ijk = _voxel_ijk(points, vx, vy, vz)
    grid = np.zeros((ijk[:, 0].max() + 2, ijk[:, 1].max() + 2, ijk[:, 2].max() + 2), np.bool_)
    for v in range(points.shape[0]):
        grid[ijk[v, 0], ijk[v, 1], ijk[v, 2]] = True
    for v in range(points.shape[0]):
        lone = True
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    if (dx or dy or dz) and grid[ijk[v, 0] + dx, ijk[v, 1] + dy, ijk[v, 2] + dz]:
                        lone = False
        out[v] = lone


def lone_voxels(points: np.ndarray, vx: float, vy: float, vz: float) -> np.ndarray:
    """(V,) bool: ``pipeline.traversal.lone_voxels``, compiled."""
    out = np.empty(points.shape[0], np.bool_)
    if points.shape[0]:
        _lone_kernel(np.ascontiguousarray(points, np.float32), np.float32(vx), np.float32(vy),
                     np.float32(vz), out)
    return out


@_jit
def _feet_kernel(points, candidates, marked, vx, vy, vz, reach, out):  # pragma: no cover
    """out[v] = candidate v, not marked, has a marked voxel 1 to reach voxels above it."""
    n = points.shape[0]
    ijk = _voxel_ijk(points, vx, vy, vz)
    grid = np.zeros((ijk[:, 0].max() + 1, ijk[:, 1].max() + 1, ijk[:, 2].max() + 1 + reach),
                    np.bool_)
    for v in range(n):
        if marked[v]:
            grid[ijk[v, 0], ijk[v, 1], ijk[v, 2]] = True
    for v in range(n):
        found = False
        if candidates[v] and not marked[v]:
            for up in range(1, reach + 1):
                if grid[ijk[v, 0], ijk[v, 1], ijk[v, 2] + up]:
                    found = True
        out[v] = found


def feet(points: np.ndarray, candidates: np.ndarray, marked: np.ndarray, vx: float,
         vy: float, vz: float, reach: int) -> np.ndarray:
    """(V,) bool: ``pipeline.traversal.feet``, compiled."""
    out = np.empty(points.shape[0], np.bool_)
    if points.shape[0]:
        _feet_kernel(np.ascontiguousarray(points, np.float32), candidates, marked,
                     np.float32(vx), np.float32(vy), np.float32(vz), int(reach), out)
    return out
