"""Clearing evidence: every surface the camera saw, as rays from the camera (no rclpy).

A costmap forgets an obstacle only when it sees through the space the obstacle held. Nav2's
VoxelLayer (and the SpatioTemporalVoxelLayer) raytrace in 3-D from the cloud's frame origin to
each point of a clearing cloud and free the voxels the ray crosses. The obstacle cloud cannot
serve: its points lie on obstacles, and the ground cloud's rays start on the floor (the ground
frame's origin) and end on the floor, so they never cross the space where a person stood. This
stage gives rays that do: the filtered depth image subsampled by a pixel stride, back-projected
into the camera's own optical frame (origin at the camera), every surface kept (walls, floor,
objects behind where an obstacle was).

Range: a surface farther than ``range_m`` from the camera is moved onto that range along its
ray: the space up to it was seen free, and a costmap needs no farther rays (nor their noise).
"""

from __future__ import annotations

import numpy as np

from .geometry import pixel_rays
from .params import Intrinsics


def clearing_points(depth_m: np.ndarray, intrinsics: Intrinsics, *, stride_px: int,
                    range_m: float) -> np.ndarray:
    """Return the surfaces seen in a depth frame, subsampled, as clearing ray ends.

    depth_m: (H, W) float32 depth [m] (the detector's filtered depth, ``DetectionResult
    .depth_m``); 0, NaN and inf are "no return" and give no point. intrinsics: its pinhole
    model [px]. stride_px: every ``stride_px``-th row and column is kept (>= 1). range_m: the
    largest distance from the camera [m] (> 0); a farther surface gives the point at this
    distance on its ray.

    Returns (N, 3) float32 points in the camera optical frame (x right, y down, z forward)
    [m], rows in image order.
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
    ru, rv = ru[::stride_px], rv[::stride_px]
    sub = depth[::stride_px, ::stride_px]
    with np.errstate(invalid='ignore'):
        rows, cols = np.nonzero(np.isfinite(sub) & (sub > 0.0))
    z = sub[rows, cols].astype(np.float32)
    x_per_z, y_per_z = ru[cols], rv[rows]
    # distance to the camera: depth times the ray's length per metre of depth
    distance = z * np.sqrt(np.float32(1.0) + x_per_z * x_per_z + y_per_z * y_per_z)
    z = z * np.minimum(np.float32(1.0), np.float32(range_m) / distance)
    return np.stack((x_per_z * z, y_per_z * z, z), axis=1).astype(np.float32, copy=False)
