"""Clearing evidence: every surface the camera saw, as rays from the camera (no rclpy).

A costmap forgets an obstacle only when it sees through the space the obstacle held. Nav2's
VoxelLayer raytraces in 3-D from the cloud's frame origin to each point of a clearing cloud and
frees the voxels on the way. The obstacle cloud cannot serve: its points lie on obstacles; nor
the ground cloud: its rays start on the floor (the ground frame's origin) and end on the floor,
so they never cross the space where a person stood. This stage gives rays that do: the
filtered depth image subsampled by a pixel stride, back-projected into the camera's own optical
frame (origin at the camera), every surface kept (walls, floor, objects behind where an
obstacle was).

Range: a surface farther than ``range_m`` from the camera gives the point at that distance on
its ray: the space up to it was seen free, and a costmap needs no farther rays (nor their
noise).

The edges of the field of view: Nav2 draws each ray between the cells of its two ends
(``VoxelGrid::raytraceLine`` truncates both to whole cells), so its line may run up to a cell
beside the true ray. Inside the image, neighbouring rays cover for it; along the image's left
and right borders nothing does, and a cell seen only at the edge of the view is never cleared
(measured with a person leaving at the side: 2 to 3 cells left lethal). The outermost valid
pixel of each kept row therefore also gives points at ``BORDER_FRACTIONS`` of its ray: the space
there was seen free (the surface lies farther), and ends in other cells give lines on both
sides of the true ray.
"""

from __future__ import annotations

import numpy as np

from .geometry import pixel_rays
from .params import Intrinsics

#: Points added along the rays of the outermost valid pixels of each row, as fractions of the
#: ray's length to its surface (or to the range).
BORDER_FRACTIONS = (0.55, 0.7, 0.85)


def clearing_points(depth_m: np.ndarray, intrinsics: Intrinsics, *, stride_px: int,
                    range_m: float) -> np.ndarray:
    """Return the surfaces seen in a depth frame, subsampled, as clearing ray ends.

    depth_m: (H, W) float32 depth [m] (the detector's filtered depth, ``DetectionResult
    .depth_m``); 0, NaN and inf are "no return" and give no point. intrinsics: its pinhole
    model [px]. stride_px: every ``stride_px``-th row and column is kept, and the last row and
    column (>= 1). range_m: the largest distance from the camera [m] (> 0); a farther surface
    gives the point at this distance on its ray. The outermost valid pixel of each kept row
    also gives points at ``BORDER_FRACTIONS`` of its ray (see the module's docstring).

    Returns (N, 3) float32 points in the camera optical frame (x right, y down, z forward)
    [m]: the kept pixels in image order, then the border points.
    """
    if isinstance(stride_px, bool) or not isinstance(stride_px, (int, np.integer)) \
            or stride_px < 1:
        raise ValueError(f'stride_px={stride_px!r} must be an int >= 1')
    if not np.isfinite(range_m) or range_m <= 0.0:
        raise ValueError(f'range_m={range_m!r} must be a finite number > 0')
    depth = np.asarray(depth_m)
    if depth.ndim != 2:
        raise ValueError(f'depth_m must be a 2-D image, got shape {depth.shape}')
    ru, rv = pixel_rays(depth.shape, intrinsics)
    height, width = depth.shape
    rows = _with_last(np.arange(0, height, stride_px), height)
    cols = _with_last(np.arange(0, width, stride_px), width)
    band = depth[rows]                                   # (R, W): the kept rows, all columns
    with np.errstate(invalid='ignore'):
        valid = np.isfinite(band) & (band > 0.0)
    kept_r, kept_c = np.nonzero(valid[:, cols])
    points = [_points(band[kept_r, cols[kept_c]], ru[cols[kept_c]], rv[rows[kept_r]],
                      range_m)]
    has = valid.any(axis=1)
    first = np.argmax(valid, axis=1)[has]
    last = width - 1 - np.argmax(valid[:, ::-1], axis=1)[has]
    edge_r = np.concatenate((np.flatnonzero(has), np.flatnonzero(has)))
    edge_c = np.concatenate((first, last))
    edge = _points(band[edge_r, edge_c], ru[edge_c], rv[rows[edge_r]], range_m)
    points += [edge * np.float32(fraction) for fraction in BORDER_FRACTIONS]
    return np.concatenate(points).astype(np.float32, copy=False)


def _points(z: np.ndarray, x_per_z: np.ndarray, y_per_z: np.ndarray,
            range_m: float) -> np.ndarray:
    """(N, 3) float32 optical-frame points of depths z [m] on rays (x/z, y/z), within range."""
    z = z.astype(np.float32)
    # distance to the camera: depth times the ray's length per metre of depth
    distance = z * np.sqrt(np.float32(1.0) + x_per_z * x_per_z + y_per_z * y_per_z)
    z = z * np.minimum(np.float32(1.0), np.float32(range_m) / distance)
    return np.stack((x_per_z * z, y_per_z * z, z), axis=1)


def _with_last(index: np.ndarray, size: int) -> np.ndarray:
    """Return ``index`` (ascending, from 0) with ``size - 1`` appended when it lacks it."""
    return index if index[-1] == size - 1 else np.append(index, size - 1)
