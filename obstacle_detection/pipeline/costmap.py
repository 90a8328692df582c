"""Costmap generation (seed 4.3.6): points projected onto the ground plane (OccupancyGrid)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..labels import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN
from . import jit
from ._compiled import costmap as jit_costmap
from .params import DetectorParams

#: A cell holding less than this share of the obstacle points (pixels) of a neighbour, near
#: their border, is the tail of that neighbour's range noise, its halo (docs/accuracy.md).
HALO_SHARE = 0.01


@dataclass(frozen=True)
class Costmap:
    """A ground-plane grid: data (ny, nx) int8 CELL_*, rows along y, origin_xy_m a corner."""

    data: np.ndarray
    resolution_m: float
    origin_xy_m: tuple[float, float]

    @property
    def width(self) -> int:
        """Number of cells along x (columns)."""
        return int(self.data.shape[1])

    @property
    def height(self) -> int:
        """Number of cells along y (rows)."""
        return int(self.data.shape[0])

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, inside) for ground-frame points xy (M, 2) or (M, 3) [m]."""
        col = np.floor((xy[:, 0] - self.origin_xy_m[0]) / self.resolution_m).astype(np.int64)
        row = np.floor((xy[:, 1] - self.origin_xy_m[1]) / self.resolution_m).astype(np.int64)
        inside = (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        return row, col, inside

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground-frame x (nx,) and y (ny,) of the cell centres [m]."""
        x = self.origin_xy_m[0] + (np.arange(self.width) + 0.5) * self.resolution_m
        y = self.origin_xy_m[1] + (np.arange(self.height) + 0.5) * self.resolution_m
        return x, y


def costmap_geometry(params: DetectorParams) -> tuple[tuple[float, float], int, int]:
    """(origin_xy_m, nx, ny) of the grid in the base frame: ahead of the camera, centred on it."""
    res = params.costmap_resolution_m
    nx = max(1, int(np.ceil(params.costmap_length_m / res - 1e-9)))
    ny = max(1, int(np.ceil(params.costmap_width_m / res - 1e-9)))
    origin = (0.0 + params.camera_x_m, -0.5 * ny * res + params.camera_y_m)
    return origin, nx, ny


def _reference_rasterise(flat: np.ndarray, points: np.ndarray, value: int,
                         origin_xy_m: tuple[float, float], resolution_m: float, nx: int,
                         ny: int) -> None:
    """Write ``value`` into the cells of ``flat`` ((ny * nx,) int8) that ``points`` hit."""
    row, col, inside = Costmap(flat.reshape(ny, nx), resolution_m, origin_xy_m).cell_of(points)
    flat[row[inside] * nx + col[inside]] = value


# compiled: the same cells, 0.1 ms of numpy temporaries less a frame in the pipeline
rasterise = jit.choose(_reference_rasterise, jit_costmap.rasterise)


def build_costmap(obstacle_points: np.ndarray, ground_points: np.ndarray,
                  params: DetectorParams) -> Costmap:
    """Grid of the points: CELL_OCCUPIED where an obstacle point fell, else CELL_FREE / UNKNOWN."""
    origin, nx, ny = costmap_geometry(params)
    grid = Costmap(np.full((ny, nx), CELL_UNKNOWN, dtype=np.int8),
                   params.costmap_resolution_m, origin)
    for points, value in ((ground_points, CELL_FREE), (obstacle_points, CELL_OCCUPIED)):
        if points.shape[0]:
            rasterise(grid.data.reshape(-1), points, value, origin, params.costmap_resolution_m,
                      nx, ny)
    return grid


def halo_voxels(points: np.ndarray, counts: np.ndarray, params: DetectorParams) -> np.ndarray:
    """(V,) bool: obstacle voxels (base frame; counts: pixels) in a halo cell (docs/method.md)."""
    origin, nx, ny = costmap_geometry(params)
    return _halo_voxels(points, counts, origin, params.costmap_resolution_m, nx, ny, HALO_SHARE)


def _reference_halo_voxels(points: np.ndarray, counts: np.ndarray,
                           origin: tuple[float, float], res: float, nx: int, ny: int,
                           share: float) -> np.ndarray:
    """:func:`halo_voxels` on the nx x ny grid of ``res`` cells from ``origin`` (numpy)."""
    row, col, inside = Costmap(np.empty((ny, nx), np.int8), res, origin).cell_of(points)
    cell = np.where(inside, row * nx + col, 0)
    weights = np.where(inside, counts, 0).astype(np.float64)
    held = np.bincount(cell, weights=weights, minlength=nx * ny)
    # the pixels' mean offset in their cell, -0.5 to 0.5 cells along x and y
    offsets = []
    for axis, index in ((0, col), (1, row)):
        within = (points[:, axis] - origin[axis]) / res - index - 0.5
        total = np.bincount(cell, weights=weights * within, minlength=nx * ny)
        offsets.append((total / np.maximum(held, 1.0)).reshape(ny, nx))
    held = held.reshape(ny, nx)
    padded = np.pad(held, 1)
    beside = np.zeros((ny, nx))
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx or dy:
                towards = (dx * offsets[0] >= 0.0) & (dy * offsets[1] >= 0.0)
                shifted = padded[1 + dy:1 + dy + ny, 1 + dx:1 + dx + nx]
                np.maximum(beside, np.where(towards, shifted, 0.0), out=beside)
    weak = held < share * beside
    return inside & weak.reshape(-1)[cell]


# compiled: only the cells of the voxels, not 8 passes over the whole grid
_halo_voxels = jit.choose(_reference_halo_voxels, jit_costmap.halo_voxels)
