"""Back-projection, region of interest and voxel grid (seed 4.3.2 to 4.3.4), pixel labels."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..labels import LABEL_GROUND, LABEL_NO_RETURN, LABEL_OBSTACLE, LABEL_OUTSIDE_ROI
from . import geometry, jit
from ._compiled import voxel as jit_voxel
from .params import DetectorParams


@dataclass(frozen=True)
class VoxelGrid:
    """Voxels in key order: centroids (V, 3) float32, point_voxel (M,), counts (V,)."""

    centroids: np.ndarray
    point_voxel: np.ndarray
    counts: np.ndarray


def voxel_downsample(points: np.ndarray, voxel_size_m: tuple[float, float, float],
                     ) -> VoxelGrid:
    """Replace the points (M, 3) of every voxel ``floor(p / size)`` by their centroid."""
    size = np.asarray(voxel_size_m, dtype=np.float64)
    pts = np.asarray(points)
    if pts.shape[0] == 0:
        return VoxelGrid(np.zeros((0, 3), np.float32), np.zeros(0, np.int64),
                         np.zeros(0, np.int64))

    cols = np.ascontiguousarray(pts.T)
    ijk = [np.floor(cols[a] / cols.dtype.type(size[a])).astype(np.int64) for a in range(3)]
    low = np.array([c.min() for c in ijk])
    dims = np.array([c.max() for c in ijk]) - low + 1
    keys = ijk[0] - low[0]
    keys *= dims[1]
    keys += ijk[1] - low[1]
    keys *= dims[2]
    keys += ijk[2] - low[2]
    cell_keys, point_voxel = np.unique(keys, return_inverse=True)
    point_voxel = point_voxel.reshape(-1)
    n_vox = cell_keys.size

    counts = np.bincount(point_voxel, minlength=n_vox)
    centroids = np.empty((n_vox, 3), dtype=np.float32)
    for axis in range(3):
        sums = np.bincount(point_voxel, weights=cols[axis], minlength=n_vox)
        centroids[:, axis] = sums / counts
    return VoxelGrid(centroids, point_voxel, counts)


# --------------------------------------------------------------------------- the frame stage

@dataclass(frozen=True)
class RoiPoints:
    """A frame's points in the region of interest; keyed: the compiled projection, or None."""

    points: np.ndarray
    pixel_index: np.ndarray
    labels: np.ndarray
    pixel_voxel: np.ndarray
    voxel_size_m: tuple[float, float, float]
    keyed: jit_voxel.Projection | None = None


def roi_bounds(params: DetectorParams) -> np.ndarray:
    """(min range, max range, lateral limit, camera height, tdbg, max height) float32."""
    return np.array([params.min_range_m, params.max_range_m, params.lateral_limit_m,
                     params.camera_height_m, params.tdbg_m, params.max_height_m], np.float32)


def _reference_points_in_roi(depth_m: np.ndarray, rays: geometry.GroundRays,
                             params: DetectorParams) -> RoiPoints:
    """:func:`points_in_roi` in numpy: the ROI of :func:`geometry.roi_mask` on the image."""
    rays = rays.table()
    z = depth_m.reshape(-1)
    valid = z > 0.0
    gx = z * rays[0]
    keep = valid & (gx >= np.float32(params.min_range_m))
    keep &= gx <= np.float32(params.max_range_m)
    gy = z * rays[1]
    keep &= np.abs(gy) <= np.float32(params.lateral_limit_m)
    gz = z * rays[2]
    gz += np.float32(params.camera_height_m)
    keep &= gz >= np.float32(params.tdbg_m)
    keep &= gz <= np.float32(params.max_height_m)
    pix = np.flatnonzero(keep)
    cols = np.empty((3, pix.size), dtype=np.float32)   # (M, 3) points with contiguous columns
    for axis, values in enumerate((gx, gy, gz)):
        np.take(values, pix, out=cols[axis])
    labels = np.where(valid, LABEL_OUTSIDE_ROI, LABEL_NO_RETURN).astype(np.uint8)
    labels = labels.reshape(depth_m.shape)
    labels.reshape(-1)[pix] = LABEL_GROUND
    pixel_voxel = np.full(depth_m.shape, -1, dtype=np.int32)
    return RoiPoints(cols.T, pix, labels, pixel_voxel, params.voxel_size_m)


def _compiled_points_in_roi(depth_m: np.ndarray, rays: geometry.GroundRays,
                            params: DetectorParams) -> RoiPoints:
    """:func:`points_in_roi` by :func:`._compiled.voxel.project_roi`, its buffers reused."""
    proj = jit_voxel.project_roi(depth_m, (rays.ru, rays.rv, rays.rot), roi_bounds(params),
                                 params.voxel_size_m, reuse=True)
    keyed = proj.keys is not None and proj.keys.size
    return RoiPoints(proj.points, proj.pixel_index, proj.labels, proj.pixel_voxel,
                     params.voxel_size_m, proj if keyed else None)


#: Back-project a depth image (0 = no return) through its :class:`geometry.GroundRays` and
#: keep the region of interest: :class:`RoiPoints`.
points_in_roi = jit.choose(_reference_points_in_roi, _compiled_points_in_roi)


def voxel_grid(roi: RoiPoints) -> VoxelGrid:
    """Return the voxel grid of the frame's points; fills ``roi.pixel_voxel``."""
    if roi.keyed is not None:
        return VoxelGrid(*jit_voxel.voxelise(roi.keyed))
    grid = voxel_downsample(roi.points, roi.voxel_size_m)
    roi.pixel_voxel.reshape(-1)[roi.pixel_index] = grid.point_voxel
    return grid


def _reference_label_pixels(labels: np.ndarray, pixel_voxel: np.ndarray,
                            is_obstacle: np.ndarray) -> None:
    """In place: labels (H, W) uint8 of voxel pixels become LABEL_OBSTACLE or LABEL_GROUND."""
    voxel_of = pixel_voxel.reshape(-1)
    pixels = np.flatnonzero(voxel_of >= 0)
    labels.reshape(-1)[pixels] = np.where(is_obstacle[voxel_of[pixels]], LABEL_OBSTACLE,
                                          LABEL_GROUND).astype(np.uint8)


_label_pixels = jit.choose(_reference_label_pixels, jit_voxel.label_pixels)


def pixel_labels(roi: RoiPoints, grid: VoxelGrid, is_obstacle: np.ndarray,
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Return (labels, pixel_voxel) with the voxels' decision ``is_obstacle`` (V,) written in."""
    _label_pixels(roi.labels, roi.pixel_voxel, is_obstacle)
    return roi.labels, roi.pixel_voxel
