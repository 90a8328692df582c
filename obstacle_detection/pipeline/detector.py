"""The whole per-frame pipeline of the seed (chapter 4) behind one call: :class:`Detector`.

Stages (:data:`STAGES`) and what is not in the seed: ``docs/method.md``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..labels import LABEL_OBSTACLE
from . import clearing, geometry, jit, median, traversal, voxel
from . import costmap as costmap_stage   # a frame's local `costmap` is its grid
from .costmap import Costmap, build_costmap
from .depth import crop_borders, decode_depth, depth_lut, units_per_metre
from .floor import FloorFit, fit_floor, sample_rays
from .median import median_filter, median_of_codes
from .normals import estimate_normals, nearest_neighbours, slope_obstacles, validate_obstacles
from .params import SEED_TABLE_4_1, DetectorParams, Intrinsics

STAGES = ('decode', 'crop', 'median', 'smear', 'floor', 'back_project', 'voxel', 'knn',
          'normals', 'slope', 'traversal', 'drops', 'validation', 'costmap', 'labels')
#: The stages that are not the seed's (robot level and the floor fit).
NEW_STAGES = ('smear', 'floor', 'traversal', 'drops')


@dataclass(frozen=True)
class DetectionResult:
    """Everything one frame produced; points float32 [m]; voxel_*: per voxel centroid (V).

    pixel_voxel (H, W): each pixel's voxel or -1; depth_m: the filtered depth [m].
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
    floor: FloorFit | None = None
    voxel_height_m: np.ndarray | None = None
    drop_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    #: the frame's camera pose, which every output goes through (the default mount if none)
    pose: geometry.FramePose = field(default_factory=lambda: geometry.FramePose(DetectorParams()))


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
        self._ray_cache: geometry.GroundRays | None = None
        self._sub_rays: np.ndarray | None = None

    def warm_up(self) -> float:
        """Compile (or load from numba's disk cache) the JIT kernels; return the seconds.

        Runs these parameters on a made-up frame (a floor, a box), as uint16 and as metres,
        with a mount and region of interest that see both, so that every kernel a frame can
        reach runs (the kernels depend on the types, not the values); and the clearing cloud.
        """
        start = time.perf_counter()
        if jit.enabled():
            intr = Intrinsics(fx=365.0, fy=365.0, cx=256.0, cy=212.0)
            mounted = Detector(self.params.replace(
                camera_height_m=0.6, camera_pitch_rad=0.3, camera_roll_rad=0.0, min_range_m=0.0,
                max_range_m=2.0, lateral_limit_m=2.0, tdbg_m=-0.1, smar_m=0.8))
            x, y, z = geometry.ground_rays((424, 512), intr, mounted.params)
            depth = np.where(z < -0.05, -0.6 / np.minimum(z, -0.05), 0.0)   # the floor
            face = 0.8 / np.maximum(x, 1e-3)   # a box 0.3 m high, its face 0.8 m ahead
            box = (depth * x > 0.8) & (np.abs(face * y) < 0.3) & (0.6 + face * z < 0.3)
            depth = np.where(box, face, np.where(depth < 4.0, depth, 0.0)).reshape(424, 512)
            mm = np.round(depth * 1000.0).astype(np.uint16)
            mounted.process(mm, intr)
            mounted.process(mm.astype(np.float32) / np.float32(1000.0), intr)
            clearing.warm_up()   # the node's clearing cloud
            median.warm_up()     # K > 5, which these parameters may not reach
        return time.perf_counter() - start

    def _rays(self, shape: tuple[int, int], intr: Intrinsics) -> geometry.GroundRays:
        """Ground-frame pixel rays, computed once per image size and intrinsics."""
        key = (shape, intr)
        if key != self._ray_key or self._ray_cache is None:
            self._ray_cache = geometry.ray_model(shape, intr, self.params)
            self._sub_rays = sample_rays(self._ray_cache, shape)
            self._ray_key = key
        return self._ray_cache

    def process(self, depth: np.ndarray, intrinsics: Intrinsics | None = None, *,
                depth_scale: float | None = None) -> DetectionResult:
        """Detect obstacles in one (H, W) depth frame: uint16 (1/depth_scale m) or float [m].

        intrinsics: None uses the seed's Table 4.1. Raises ``DepthFormatError`` for bad input.
        """
        p = self.params
        intr = intrinsics if intrinsics is not None else SEED_TABLE_4_1
        clock = _Clock()
        depth_m = self._filtered_depth(depth, depth_scale, clock)
        rays, fit, run = self._frame_mount(depth_m, intr)
        pose = geometry.FramePose(p, run)   # the one transform of this frame's outputs
        clock.lap('floor')
        roi = voxel.points_in_roi(depth_m, rays, run)
        clock.lap('back_project')
        grid = voxel.voxel_grid(roi)
        centroids = grid.centroids
        clock.lap('voxel')
        k = max(p.normal_neighbours, p.validation_neighbours + 1)
        neighbours = nearest_neighbours(centroids, k)
        clock.lap('knn')
        n_cols = min(p.normal_neighbours, neighbours.shape[1])
        normals = estimate_normals(centroids, neighbours[:, :n_cols])
        clock.lap('normals')
        steep = slope_obstacles(normals, p.cos_max_slope)
        clock.lap('slope')
        candidates, heights, trav, drop_points, drop_pixels = self._robot_level(
            depth_m, rays, run, centroids, steep, clock)
        # robot level: surfaces above the robot support the validation of those just under it
        support = candidates if trav is None else candidates | trav.above_robot
        is_obstacle = validate_obstacles(support, neighbours, p.validation_neighbours)
        is_obstacle &= candidates
        if trav is not None:
            is_obstacle |= traversal.feet(centroids, candidates, is_obstacle, p.voxel_x_m,
                                          p.voxel_y_m, p.voxel_z_m)
            is_obstacle |= trav.ledge   # a band one cell wide, as a drop edge: not validated
            is_obstacle &= ~traversal.lone_voxels(centroids, p.voxel_x_m, p.voxel_y_m,
                                                  p.voxel_z_m)   # mixed pixels kept
            marked = np.flatnonzero(is_obstacle)
            halo = costmap_stage.halo_voxels(pose.ground_to_base(centroids[marked]),
                                             grid.counts[marked], p)
            is_obstacle[marked[halo & ~trav.ledge[marked]]] = False
        clock.lap('validation')
        obstacle_points = centroids[is_obstacle]
        if drop_points.shape[0]:
            obstacle_points = np.concatenate((obstacle_points, drop_points))
        ground_points = centroids[~is_obstacle]
        # outputs in the robot's base frame (the camera's x, y and yaw on the robot)
        obstacle_points = pose.ground_to_base(obstacle_points)
        ground_points = pose.ground_to_base(ground_points)
        costmap = build_costmap(obstacle_points, ground_points, p)
        clock.lap('costmap')

        labels, pixel_voxel = voxel.pixel_labels(roi, grid, is_obstacle)
        if drop_pixels.size:
            labels.reshape(-1)[drop_pixels] = LABEL_OBSTACLE
        clock.lap('labels')
        return DetectionResult(
            obstacle_points=obstacle_points, ground_points=ground_points, labels=labels,
            costmap=costmap, timings_ms=clock.finish(), voxel_points=centroids,
            voxel_normals=normals, voxel_slope_obstacle=candidates, voxel_is_obstacle=is_obstacle,
            voxel_neighbours=neighbours, pixel_voxel=pixel_voxel, depth_m=depth_m, intrinsics=intr,
            floor=fit, voxel_height_m=heights, drop_points=drop_points, pose=pose)

    def _filtered_depth(self, depth: np.ndarray, depth_scale: float | None,
                        clock: _Clock) -> np.ndarray:
        """Decode, crop, median-filter and (robot level) un-smear a frame: (H, W) float32 [m]."""
        p = self.params
        crop = (p.crop_top_px, p.crop_bottom_px, p.crop_left_px, p.crop_right_px)
        depth_m = decode_depth(depth, depth_scale=depth_scale)
        clock.lap('decode')
        # uint16 input (decoded: 2-D): the median runs on its codes (see median_of_codes)
        codes = depth if p.median_kernel > 1 and np.asarray(depth).dtype.kind == 'u' else None
        if any(crop):
            depth_m = crop_borders(depth_m, *crop)
            if codes is not None:
                codes = crop_borders(codes, *crop)
        clock.lap('crop')
        raw_m = depth_m
        if codes is not None:
            depth_m = median_of_codes(codes, p.median_kernel,
                                      depth_lut(units_per_metre(depth_scale)), p.compute_threads)
        elif p.median_kernel > 1:
            depth_m = median_filter(depth_m, p.median_kernel, p.compute_threads)
        clock.lap('median')
        if p.robot_level and p.median_kernel > 1:
            # raw depth looked up from uint16 codes in the table holds no NaN
            depth_m = traversal.drop_smeared(depth_m, raw_m, p.max_filter_shift,
                                              raw_no_nan=codes is not None)
            depth_m = traversal.unbias_holes(depth_m, raw_m, p.median_kernel)
        clock.lap('smear')
        return depth_m

    def _frame_mount(self, depth_m: np.ndarray, intr: Intrinsics,
                     ) -> tuple[geometry.GroundRays, FloorFit, DetectorParams]:
        """(rays, floor fit, parameters) of one frame: the fitted mount, the robot-level ROI."""
        p = self.params
        rays = self._rays(depth_m.shape, intr)
        fit = fit_floor(depth_m, self._sub_rays, p)
        frame_changes: dict = {}   # this frame's parameters: fitted mount, robot-level ROI
        if fit.refined:
            frame_changes.update(camera_height_m=fit.height_m, camera_pitch_rad=fit.pitch_rad,
                                 camera_roll_rad=fit.roll_rad)
        if p.robot_level and -p.drop_view_m < p.tdbg_m:
            frame_changes['tdbg_m'] = -p.drop_view_m
        run = p.with_frame_mount(**frame_changes) if frame_changes else p
        if fit.refined:   # the fitted mount's rays (no table: computed where they are read)
            rays = rays.for_mount(run)
        return rays, fit, run

    def _robot_level(self, depth_m: np.ndarray, rays: geometry.GroundRays,
                     run: DetectorParams, centroids: np.ndarray, steep: np.ndarray,
                     clock: _Clock) -> tuple[np.ndarray, ...]:
        """(obstacle candidates, heights, traversal or None, drop points, drop pixels)."""
        p = self.params
        if not p.robot_level:
            clock.lap('traversal')
            clock.lap('drops')
            return (steep, centroids[:, 2], None, np.zeros((0, 3), np.float32),
                    np.zeros(0, np.int64))
        trav = traversal.traversable_ground(centroids, steep, p)
        clock.lap('traversal')
        drop_points, drop_pixels = traversal.drop_edges(depth_m, rays, run.camera_height_m, p)
        clock.lap('drops')
        return trav.is_obstacle, trav.height_m, trav, drop_points, drop_pixels
