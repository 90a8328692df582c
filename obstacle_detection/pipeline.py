"""The whole per-frame pipeline of the seed (chapter 4) behind one call.

``Detector(params).process(depth, intrinsics)`` runs: decode -> crop -> K x K median ->
back-projection and camera mount with the region of interest -> voxel grid -> k-NN -> normals ->
slope test -> validation -> costmap, and returns a :class:`DetectionResult`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import geometry, jit_knn, jit_median, jit_voxel
from .costmap import Costmap, build_costmap
from .depth import crop_borders, decode_depth, median_filter
from .normals import estimate_normals, nearest_neighbours, slope_obstacles, validate_obstacles
from .params import SEED_TABLE_4_1, DetectorParams, Intrinsics
from .voxel import voxel_downsample

LABEL_NO_RETURN = 0    #: no depth (0, NaN, out of sensor range, cropped)
LABEL_OUTSIDE_ROI = 1  #: a 3-D point outside the region of interest
LABEL_GROUND = 2       #: in a voxel that passed the slope test (traversable)
LABEL_OBSTACLE = 3     #: in a voxel that is a validated obstacle

STAGES = ('decode', 'crop', 'median', 'back_project', 'voxel', 'knn', 'normals',
          'slope', 'validation', 'costmap', 'labels')


@dataclass(frozen=True)
class DetectionResult:
    """Everything one frame produced. Points are in the ground frame [m], float32.

    obstacle_points (M, 3), ground_points (G, 3): voxel centroids labelled obstacle / ground.
    labels (H, W) uint8: LABEL_* per pixel. costmap: the ground-plane grid.
    timings_ms: per stage (STAGES order) and 'total' [ms].
    voxel_points (V, 3); voxel_normals (V, 3) unit; voxel_slope_obstacle (V,) bool, the slope
    test (and the optional height rule, ``max_ground_height_m``) before validation;
    voxel_is_obstacle (V,) bool after validation; voxel_neighbours (V, k) int64, the k-NN query
    that served the normals and the validation (k = max(N, N1 + 1) clipped to V, nearest first,
    the voxel itself first); pixel_voxel (H, W) int32, the voxel of each pixel or -1;
    depth_m (H, W) float32, the filtered depth the points came from.
    """

    obstacle_points: np.ndarray
    ground_points: np.ndarray
    labels: np.ndarray
    costmap: Costmap
    timings_ms: dict[str, float]
    voxel_points: np.ndarray
    voxel_normals: np.ndarray
    voxel_slope_obstacle: np.ndarray
    voxel_is_obstacle: np.ndarray
    voxel_neighbours: np.ndarray
    pixel_voxel: np.ndarray
    depth_m: np.ndarray
    intrinsics: Intrinsics = field(default=SEED_TABLE_4_1)


class _Clock:
    """Accumulates per-stage wall times [ms]."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self._start = self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.times[stage] = (now - self._last) * 1e3
        self._last = now

    def finish(self) -> dict[str, float]:
        self.times['total'] = (time.perf_counter() - self._start) * 1e3
        return self.times


class Detector:
    """Runs the pipeline with one :class:`DetectorParams`; holds no per-frame state."""

    def __init__(self, params: DetectorParams | None = None) -> None:
        self.params = params if params is not None else DetectorParams()
        self._ray_key: tuple | None = None
        self._ray_cache: np.ndarray | None = None

    def warm_up(self) -> float:
        """Compile (or load from numba's disk cache) the optional JIT kernels; return seconds.

        The median kernel is prepared for this detector's K. Without numba it does nothing.
        Call it before the first frame (the node does at start-up) so no frame pays for it.
        """
        start = time.perf_counter()
        jit_median.warm_up(self.params.median_kernel)
        jit_knn.warm_up()
        jit_voxel.warm_up()
        return time.perf_counter() - start

    def _rays(self, shape: tuple[int, int], intr: Intrinsics) -> np.ndarray:
        """Ground-frame pixel rays, computed once per image size and intrinsics."""
        key = (shape, intr)
        if key != self._ray_key or self._ray_cache is None:
            self._ray_cache = geometry.ground_rays(shape, intr, self.params)
            self._ray_key = key
        return self._ray_cache

    def process(self, depth: np.ndarray, intrinsics: Intrinsics | None = None, *,
                depth_scale: float | None = None) -> DetectionResult:
        """Detect obstacles in one depth frame.

        depth: (H, W) uint16 [mm] (or uint16 in 1/depth_scale m) or float32/float64 [m];
        0, NaN and inf are "no return". intrinsics: the frame's pinhole model; None uses the
        seed's Table 4.1 fallback. Raises ``DepthFormatError`` (a ValueError) for a wrong
        dtype or shape. A frame with no valid point gives an empty result (no obstacle, an
        all-unknown costmap), not an error.
        """
        p = self.params
        intr = intrinsics if intrinsics is not None else SEED_TABLE_4_1
        clock = _Clock()
        depth_m = decode_depth(depth, depth_scale=depth_scale)
        clock.lap('decode')
        if p.crop_top_px or p.crop_bottom_px or p.crop_left_px or p.crop_right_px:
            depth_m = crop_borders(depth_m, p.crop_top_px, p.crop_bottom_px,
                                   p.crop_left_px, p.crop_right_px)
        clock.lap('crop')
        if p.median_kernel > 1:
            depth_m = median_filter(depth_m, p.median_kernel)
        clock.lap('median')

        rays = self._rays(depth_m.shape, intr)
        compiled = jit_voxel.enabled()
        if compiled:   # same points, voxels and labels as the numpy path below
            proj = jit_voxel.project_roi(depth_m, rays, p, reuse=True)
            clock.lap('back_project')
            grid = jit_voxel.voxelise(proj)
        else:
            pts, pix_roi, valid = geometry.ground_points_in_roi(depth_m, rays, p)
            clock.lap('back_project')
            grid = voxel_downsample(pts, p.voxel_size_m)
        centroids = grid.centroids
        clock.lap('voxel')
        k = max(p.normal_neighbours, p.validation_neighbours + 1)
        neighbours = nearest_neighbours(centroids, k)
        clock.lap('knn')
        n_cols = min(p.normal_neighbours, neighbours.shape[1])
        normals = estimate_normals(centroids, neighbours[:, :n_cols])
        clock.lap('normals')
        steep = slope_obstacles(normals, p.cos_max_slope)
        if p.max_ground_height_m > 0.0:
            steep |= centroids[:, 2] > np.float32(p.max_ground_height_m)
        clock.lap('slope')
        is_obstacle = validate_obstacles(steep, neighbours, p.validation_neighbours)
        clock.lap('validation')
        obstacle_points = centroids[is_obstacle]
        ground_points = centroids[~is_obstacle]
        costmap = build_costmap(obstacle_points, ground_points, p)
        clock.lap('costmap')

        if compiled:
            labels, pixel_voxel = proj.labels, proj.pixel_voxel
            jit_voxel.label_pixels(labels, pixel_voxel, is_obstacle)
        else:
            shape = depth_m.shape
            labels = np.zeros(shape, dtype=np.uint8)
            flat_labels = labels.reshape(-1)
            flat_labels[valid] = LABEL_OUTSIDE_ROI
            flat_labels[pix_roi] = np.where(is_obstacle[grid.point_voxel], LABEL_OBSTACLE,
                                            LABEL_GROUND).astype(np.uint8)
            pixel_voxel = np.full(shape, -1, dtype=np.int32)
            pixel_voxel.reshape(-1)[pix_roi] = grid.point_voxel
        clock.lap('labels')
        return DetectionResult(
            obstacle_points=obstacle_points, ground_points=ground_points, labels=labels,
            costmap=costmap, timings_ms=clock.finish(), voxel_points=centroids,
            voxel_normals=normals, voxel_slope_obstacle=steep, voxel_is_obstacle=is_obstacle,
            voxel_neighbours=neighbours, pixel_voxel=pixel_voxel, depth_m=depth_m, intrinsics=intr)
