"""A port of Nav2 Jazzy's ObstacleLayer and VoxelLayer, to play Nav2 in tests (test code only).

Written from reading navigation2's ``jazzy`` branch (github.com/ros-navigation/navigation2);
each rule names the upstream file and function it follows. What is ported:

- the parameters the layers declare, with their defaults, and the costmap's own
  (``ObstacleLayer::onInitialize``, ``VoxelLayer::onInitialize``,
  ``Costmap2DROS::Costmap2DROS``): :func:`read_costmap` refuses a name Nav2 would not read;
- the ObservationBuffer: the sensor origin, the height filter (``bufferCloud``) and
  ``observation_persistence: 0`` (only the newest cloud, ``purgeStaleObservations``);
- the rolling window (``Costmap2D::updateOrigin``, ``VoxelLayer::updateOrigin``);
- the VoxelLayer's 3-D marking and clearing (``VoxelLayer::updateBounds``,
  ``VoxelLayer::raytraceFreespace``) on the bit-column voxel grid of ``nav2_voxel_grid``
  (``VoxelGrid::markVoxelInMap``, ``clearVoxelLineInMap``, ``raytraceLine``,
  ``bresenham3D``, ``ClearVoxelInMap``);
- the ObstacleLayer's marking and 2-D clearing (``ObstacleLayer::updateBounds``,
  ``ObstacleLayer::raytraceFreespace``, ``Costmap2D::raytraceLine``, ``bresenham2D``);
- the footprint clearing and the Max combination into the master grid
  (``ObstacleLayer::updateCosts``, ``CostmapLayer::updateWithMax``,
  ``LayeredCostmap::updateMap``).

Not ported: TF (the caller gives each cloud's transform into the global frame), the
inflation layer (the tests score lethal cells), ``isCurrent`` timing, LaserScan sources. The
whole window is combined at every update, where Nav2 combines the touched bounds; with one
obstacle layer over a reset master the result is the same.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

#: nav2_costmap_2d/include/nav2_costmap_2d/cost_values.hpp
FREE_SPACE = 0
LETHAL_OBSTACLE = 254
NO_INFORMATION = 255
#: voxel_layer.cpp: ``#define VOXEL_BITS 16``
VOXEL_BITS = 16
#: VoxelGrid::resize / reset: a column of 16 unknown voxels (low bits set, high bits clear)
UNKNOWN_COLUMN = np.uint32(0x0000FFFF)

#: Parameters of an observation source and their defaults (ObstacleLayer::onInitialize).
SOURCE_DEFAULTS: dict[str, Any] = {
    'topic': None, 'sensor_frame': '', 'observation_persistence': 0.0,
    'expected_update_rate': 0.0, 'data_type': 'LaserScan', 'min_obstacle_height': 0.0,
    'max_obstacle_height': 0.0, 'inf_is_valid': False, 'marking': True, 'clearing': False,
    'obstacle_max_range': 2.5, 'obstacle_min_range': 0.0, 'raytrace_max_range': 3.0,
    'raytrace_min_range': 0.0,
}
#: Parameters of an ObstacleLayer (ObstacleLayer::onInitialize) and their defaults.
OBSTACLE_LAYER_DEFAULTS: dict[str, Any] = {
    'plugin': None, 'enabled': True, 'footprint_clearing_enabled': True,
    'min_obstacle_height': 0.0, 'max_obstacle_height': 2.0, 'combination_method': 1,
    'observation_sources': '',
}
#: A VoxelLayer adds these (VoxelLayer::onInitialize).
VOXEL_LAYER_DEFAULTS: dict[str, Any] = {
    **OBSTACLE_LAYER_DEFAULTS, 'z_voxels': 10, 'origin_z': 0.0, 'z_resolution': 0.2,
    'unknown_threshold': 15, 'mark_threshold': 0, 'publish_voxel_map': False,
}
#: InflationLayer::onInitialize.
INFLATION_LAYER_KEYS = frozenset({'plugin', 'enabled', 'cost_scaling_factor',
                                  'inflation_radius', 'inflate_unknown',
                                  'inflate_around_unknown'})
#: Costmap2DROS's own parameters (costmap_2d_ros.cpp, declare_parameter).
COSTMAP_KEYS = frozenset({
    'always_send_full_costmap', 'filters', 'footprint', 'footprint_padding', 'global_frame',
    'height', 'initial_transform_timeout', 'lethal_cost_threshold', 'map_topic', 'map_vis_z',
    'observation_sources', 'origin_x', 'origin_y', 'plugins', 'publish_frequency',
    'resolution', 'robot_base_frame', 'robot_radius', 'rolling_window', 'track_unknown_space',
    'transform_tolerance', 'trinary_costmap', 'unknown_cost_value', 'update_frequency',
    'use_maximum', 'width', 'use_sim_time'})
OBSTACLE_PLUGIN = 'nav2_costmap_2d::ObstacleLayer'
VOXEL_PLUGIN = 'nav2_costmap_2d::VoxelLayer'
INFLATION_PLUGIN = 'nav2_costmap_2d::InflationLayer'


class Nav2ConfigError(ValueError):
    """A costmap configuration Nav2 would read differently from what it says."""


@dataclass(frozen=True)
class SourceConfig:
    """One observation source of an obstacle or voxel layer (names as in Nav2)."""

    name: str
    topic: str
    sensor_frame: str
    marking: bool
    clearing: bool
    min_obstacle_height: float
    max_obstacle_height: float
    obstacle_max_range: float
    obstacle_min_range: float
    raytrace_max_range: float
    raytrace_min_range: float
    observation_persistence: float
    expected_update_rate: float
    data_type: str
    inf_is_valid: bool = False


@dataclass(frozen=True)
class LayerConfig:
    """An ObstacleLayer or VoxelLayer (the voxel fields are the VoxelLayer's defaults else)."""

    name: str
    plugin: str
    sources: tuple[SourceConfig, ...]
    enabled: bool = True
    footprint_clearing_enabled: bool = True
    min_obstacle_height: float = 0.0
    max_obstacle_height: float = 2.0
    combination_method: int = 1
    z_voxels: int = 10
    origin_z: float = 0.0
    z_resolution: float = 0.2
    unknown_threshold: int = 15
    mark_threshold: int = 0
    publish_voxel_map: bool = False


@dataclass(frozen=True)
class CostmapConfig:
    """The costmap's own parameters and its obstacle/voxel layers, in plugin order."""

    global_frame: str
    robot_base_frame: str
    rolling_window: bool
    width_m: float
    height_m: float
    resolution_m: float
    robot_radius_m: float
    track_unknown_space: bool
    update_frequency_hz: float
    layers: tuple[LayerConfig, ...]
    values: dict[str, Any] = field(default_factory=dict)


def _checked(values: Mapping[str, Any], defaults: Mapping[str, Any], where: str,
             extra: frozenset[str] = frozenset()) -> dict[str, Any]:
    """Return ``defaults`` updated by ``values``; Nav2ConfigError for a name Nav2 never reads.

    A default of None marks a name without a usable default (``topic`` defaults to the source
    name in Nav2, ``plugin`` must be given); the type of a value must be the default's (Nav2
    refuses an int for a double parameter).
    """
    out = dict(defaults)
    for key, value in values.items():
        if key not in defaults and key not in extra:
            raise Nav2ConfigError(f'{where}: {key!r} is not a parameter Nav2 Jazzy reads')
        default = defaults.get(key)
        if default is not None and type(value) is not type(default):
            raise Nav2ConfigError(f'{where}: {key}={value!r} must be a '
                                  f'{type(default).__name__}, as Nav2 declares it')
        out[key] = value
    return out


def read_costmap(path: str | Path, section: str = 'local_costmap') -> CostmapConfig:
    """Read ``<section>: <section>: ros__parameters`` of a Nav2 params file.

    Every name must be one Nav2 Jazzy declares for the costmap, its obstacle/voxel layers and
    their sources (see the module's constants), so a misspelt key fails here as it would
    silently do nothing in Nav2.
    """
    data = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    values = data[section][section]['ros__parameters']
    plugins = list(values['plugins'])
    layers = []
    for name in plugins:
        layer = values[name]
        plugin = layer.get('plugin')
        if plugin == INFLATION_PLUGIN:
            unknown = set(layer) - INFLATION_LAYER_KEYS
            if unknown:
                raise Nav2ConfigError(f'{name}: {sorted(unknown)} not read by Nav2 Jazzy')
            continue
        if plugin not in (OBSTACLE_PLUGIN, VOXEL_PLUGIN):
            raise Nav2ConfigError(f'{name}: plugin {plugin!r} is not ported here')
        names = str(layer.get('observation_sources', '')).split()
        defaults = VOXEL_LAYER_DEFAULTS if plugin == VOXEL_PLUGIN else OBSTACLE_LAYER_DEFAULTS
        settings = _checked(layer, defaults, name, extra=frozenset(names))
        sources = []
        for source in names:
            got = _checked(layer[source], SOURCE_DEFAULTS, f'{name}.{source}')
            got['topic'] = got['topic'] or source
            sources.append(SourceConfig(name=source, **got))
        for key in ('observation_sources', 'plugin', *names):
            settings.pop(key)
        if plugin == OBSTACLE_PLUGIN:
            for key in set(VOXEL_LAYER_DEFAULTS) - set(OBSTACLE_LAYER_DEFAULTS):
                settings.pop(key, None)
        layers.append(LayerConfig(name=name, plugin=plugin, sources=tuple(sources),
                                  **settings))
    return costmap_config(values, plugins, layers, section)


def costmap_config(values: Mapping[str, Any], plugins: list[str], layers: list[Any],
                   section: str) -> CostmapConfig:
    """Return the CostmapConfig of a section's ``values`` and layers; refuse keys Nav2 ignores."""
    unknown = set(values) - COSTMAP_KEYS - set(plugins)
    if unknown:
        raise Nav2ConfigError(f'{section}: {sorted(unknown)} not read by Nav2 Jazzy')
    return CostmapConfig(
        global_frame=str(values['global_frame']),
        robot_base_frame=str(values['robot_base_frame']),
        rolling_window=bool(values['rolling_window']), width_m=float(values['width']),
        height_m=float(values['height']), resolution_m=float(values['resolution']),
        robot_radius_m=float(values.get('robot_radius', 0.1)),
        track_unknown_space=bool(values.get('track_unknown_space', False)),
        update_frequency_hz=float(values.get('update_frequency', 5.0)),
        layers=tuple(layers), values=dict(values))


# ------------------------------------------------------------------------------------------
# Observations


@dataclass(frozen=True)
class Observation:
    """A cloud in the global frame as a layer reads it (nav2_costmap_2d/observation.hpp).

    origin (3,) float64: the sensor origin in the global frame [m]; points (N, 3) float64,
    global frame [m], already within the source's heights; source: its settings.
    """

    origin: np.ndarray
    points: np.ndarray
    source: SourceConfig


def buffer_cloud(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
                 source: SourceConfig, sensor_origin: np.ndarray | None = None) -> Observation:
    """ObservationBuffer::bufferCloud: the cloud in the global frame, filtered by height.

    points (N, 3) in the cloud's frame [m]; rotation (3, 3), translation (3,): the cloud frame
    in the global frame. sensor_origin: the global position of ``sensor_frame``'s origin when
    the source names one; None takes the cloud frame's origin (``sensor_frame: ''``).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    # tf2's PointCloud2 transform writes float32 coordinates
    world = (pts @ np.asarray(rotation, np.float64).T
             + np.asarray(translation, np.float64)).astype(np.float32).astype(np.float64)
    origin = np.asarray(translation if sensor_origin is None else sensor_origin, np.float64)
    z = world[:, 2]
    keep = (z <= source.max_obstacle_height) & (z >= source.min_obstacle_height)
    return Observation(origin=origin.copy(), points=world[keep], source=source)


# ------------------------------------------------------------------------------------------
# Bresenham walks


def line_cells(start: np.ndarray, delta: np.ndarray, steps: np.ndarray,
               shape: tuple[int, ...]) -> np.ndarray:
    """Return the cells (M, D) visited by the walks of :func:`bresenham_cells` (repeats kept).

    Rays with the same start, end and steps walk the same cells: each walk is done once.
    shape: the grid's size per axis (start and start + delta lie inside it).
    """
    start = np.asarray(start, np.int64)
    end = start + np.asarray(delta, np.int64)
    steps = np.asarray(steps, np.int64)
    cells = int(np.prod(shape))
    key = (np.ravel_multi_index(start.T, shape) * cells
           + np.ravel_multi_index(end.T, shape)) * (int(steps.max(initial=0)) + 1) + steps
    _, first = np.unique(key, return_index=True)
    _, visited = bresenham_cells(start[first], end[first] - start[first], steps[first])
    return visited


def bresenham_cells(start: np.ndarray, delta: np.ndarray, steps: np.ndarray,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Cells visited by Nav2's integer Bresenham walks, many rays at once.

    costmap_2d.hpp ``Costmap2D::bresenham2D`` and voxel_grid.hpp ``VoxelGrid::bresenham3D``:
    the dominant axis is the first of x, y (, z) with the largest |delta| (upstream's ``>=``
    tests); every error term starts at |delta_a| / 2 (integer division); the walk applies
    the action, steps along the dominant axis, adds |delta_b| to each error and steps b when
    its error reaches |delta_a|; ``steps`` times; then applies the action once more at the
    cell it reached. A zero delta steps nowhere (upstream's sign(0) = -1 is never used).

    start (N, D) int: first cells; delta (N, D) int: end cell - start cell; steps (N,) int:
    ``min(max_length, |delta_a|)``. Returns (ray (M,) int64, cell (M, D) int64).
    """
    start = np.asarray(start, dtype=np.int64)
    delta = np.asarray(delta, dtype=np.int64)
    steps = np.asarray(steps, dtype=np.int64)
    n, dims = start.shape
    if n == 0:
        return np.zeros(0, np.int64), np.zeros((0, dims), np.int64)
    size = np.abs(delta)
    step = np.where(delta > 0, 1, -1)
    dominant = np.argmax(size, axis=1)
    size_a = size[np.arange(n), dominant]
    # after i steps, axis b has moved floor((|delta_a| // 2 + i |delta_b|) / |delta_a|) times
    # (its error starts at |delta_a| // 2, gains |delta_b| a step, loses |delta_a| a move);
    # the cells are those after 0 .. steps steps
    rays = np.repeat(np.arange(n), steps + 1)
    first = np.cumsum(steps + 1) - (steps + 1)
    i = np.arange(rays.size) - first[rays]
    a = np.maximum(size_a, 1)[rays]
    moves = (size_a[rays, None] // 2 + i[:, None] * size[rays]) // a[:, None]
    moves[np.arange(rays.size), dominant[rays]] = i
    cells = start[rays] + step[rays] * moves
    return rays, cells


# ------------------------------------------------------------------------------------------
# Layers


def _moved(grid: np.ndarray, cell_ox: int, cell_oy: int, fill: Any) -> np.ndarray:
    """Costmap2D::updateOrigin's copy: the overlap of old and new window, the rest ``fill``.

    grid (ny, nx); cell_ox, cell_oy: the new origin in old cells.
    """
    ny, nx = grid.shape
    out = np.full_like(grid, fill)
    x0, x1 = min(max(cell_ox, 0), nx), min(max(cell_ox + nx, 0), nx)
    y0, y1 = min(max(cell_oy, 0), ny), min(max(cell_oy + ny, 0), ny)
    out[y0 - cell_oy:y1 - cell_oy, x0 - cell_ox:x1 - cell_ox] = grid[y0:y1, x0:x1]
    return out


def _popcount16(values: np.ndarray) -> np.ndarray:
    """Count the set bits of the low 16 bits of each value."""
    v = np.asarray(values, dtype=np.uint32) & np.uint32(0xFFFF)
    return np.unpackbits(v.astype('<u2').view(np.uint8).reshape(-1, 2), axis=1).sum(
        axis=1).reshape(np.shape(values))


def footprint_polygon(radius_m: float) -> np.ndarray:
    """footprint.cpp ``makeFootprintFromRadius``: 16 points on the circle, (16, 2) [m]."""
    angles = np.arange(16) * 2.0 * math.pi / 16
    return np.stack([np.cos(angles) * radius_m, np.sin(angles) * radius_m], axis=1)


class ObstacleLayer:
    """ObstacleLayer (2-D) state: its costmap, window origin, marking and 2-D clearing.

    costmap (ny, nx) uint8 Nav2 costs, row iy = y; origin_xy_m: the window's corner [m].
    """

    def __init__(self, layer: LayerConfig, costmap: CostmapConfig) -> None:
        self.layer = layer
        self.resolution_m = costmap.resolution_m
        # Costmap2DROS: size in cells = (unsigned)(width / resolution)
        self.size_x = int(costmap.width_m / costmap.resolution_m)
        self.size_y = int(costmap.height_m / costmap.resolution_m)
        self.rolling = costmap.rolling_window
        # ObstacleLayer::onInitialize: unknown space tracked -> NO_INFORMATION, else FREE
        self.default_value = NO_INFORMATION if costmap.track_unknown_space else FREE_SPACE
        self.costmap = np.full((self.size_y, self.size_x), self.default_value, np.uint8)
        self.origin_xy_m = (0.0, 0.0)
        self.footprint = footprint_polygon(costmap.robot_radius_m)

    # -- geometry (costmap_2d.cpp)
    @property
    def size_in_metres(self) -> tuple[float, float]:
        """Costmap2D::getSizeInMetersX/Y: (size - 1 + 0.5) * resolution."""
        return ((self.size_x - 0.5) * self.resolution_m, (self.size_y - 0.5) * self.resolution_m)

    def world_to_map(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                    np.ndarray]:
        """Costmap2D::worldToMap: (mx, my, inside); truncation as static_cast<unsigned>."""
        fx = (np.asarray(x, np.float64) - self.origin_xy_m[0]) / self.resolution_m
        fy = (np.asarray(y, np.float64) - self.origin_xy_m[1]) / self.resolution_m
        inside = (fx >= 0) & (fy >= 0) & (fx < self.size_x) & (fy < self.size_y)
        mx = np.where(inside, fx, 0).astype(np.int64)
        my = np.where(inside, fy, 0).astype(np.int64)
        inside &= (mx < self.size_x) & (my < self.size_y)
        return mx, my, inside

    def cell_distance(self, metres: float) -> int:
        """Costmap2D::cellDistance: ceil(distance / resolution), at least 0."""
        return int(max(0.0, math.ceil(metres / self.resolution_m)))

    def update_origin(self, new_x: float, new_y: float) -> tuple[int, int]:
        """Costmap2D::updateOrigin: move the window by whole cells, keep the overlap."""
        cell_ox = int((new_x - self.origin_xy_m[0]) / self.resolution_m)   # toward zero
        cell_oy = int((new_y - self.origin_xy_m[1]) / self.resolution_m)
        self.costmap = _moved(self.costmap, cell_ox, cell_oy, self.default_value)
        self.origin_xy_m = (self.origin_xy_m[0] + cell_ox * self.resolution_m,
                            self.origin_xy_m[1] + cell_oy * self.resolution_m)
        return cell_ox, cell_oy

    # -- one costmap update
    def update(self, robot_pose: tuple[float, float, float], marking: list[Observation],
               clearing: list[Observation]) -> None:
        """ObstacleLayer::updateBounds then updateCosts' footprint clearing.

        robot_pose: (x [m], y [m], yaw [rad]) of robot_base_frame in the global frame.
        """
        x, y, yaw = robot_pose
        if self.rolling:
            size_x_m, size_y_m = self.size_in_metres
            self.update_origin(x - size_x_m / 2, y - size_y_m / 2)
        if not self.layer.enabled:
            return
        for obs in clearing:      # raytrace freespace first, then mark (updateBounds)
            self.raytrace_freespace(obs)
        for obs in marking:
            self.mark(obs)
        if self.layer.footprint_clearing_enabled:
            self.clear_footprint(robot_pose)

    def mark(self, obs: Observation) -> None:
        """ObstacleLayer::updateBounds, marking: heights, world and cell ranges -> LETHAL."""
        ox, oy = obs.origin[0], obs.origin[1]
        x0, y0, origin_inside = self.world_to_map(ox, oy)
        if not origin_inside:
            return      # "Sensor origin is out of map bounds"
        p = obs.points
        keep = (p[:, 2] >= self.layer.min_obstacle_height) & \
            (p[:, 2] <= self.layer.max_obstacle_height)
        mx, my, inside = self.world_to_map(p[:, 0], p[:, 1])
        keep &= inside
        world_sq = (p[:, 0] - ox) ** 2 + (p[:, 1] - oy) ** 2
        src = obs.source
        keep &= (world_sq <= src.obstacle_max_range ** 2) & \
            (world_sq >= src.obstacle_min_range ** 2)
        cells = np.hypot(mx - x0, my - y0).astype(np.int64)   # (unsigned) hypot in cells
        keep &= (cells <= self.cell_distance(src.obstacle_max_range)) & \
            (cells >= self.cell_distance(src.obstacle_min_range))
        self.costmap[my[keep], mx[keep]] = LETHAL_OBSTACLE

    def raytrace_freespace(self, obs: Observation) -> None:
        """ObstacleLayer::raytraceFreespace: 2-D rays from the origin, ends clipped to the map."""
        ox, oy = float(obs.origin[0]), float(obs.origin[1])
        x0, y0, inside = self.world_to_map(ox, oy)
        if not inside or obs.points.shape[0] == 0:
            return
        res = self.resolution_m
        origin_x, origin_y = self.origin_xy_m
        end_x, end_y = origin_x + self.size_x * res, origin_y + self.size_y * res
        wx, wy = obs.points[:, 0].copy(), obs.points[:, 1].copy()
        a, b = wx - ox, wy - oy
        with np.errstate(divide='ignore', invalid='ignore'):
            low = wx < origin_x
            t = (origin_x - ox) / a
            wx, wy = np.where(low, origin_x, wx), np.where(low, oy + b * t, wy)
            low = wy < origin_y
            t = (origin_y - oy) / b
            wx, wy = np.where(low, ox + a * t, wx), np.where(low, origin_y, wy)
            high = wx > end_x
            t = (end_x - ox) / a
            wx, wy = np.where(high, end_x - .001, wx), np.where(high, oy + b * t, wy)
            high = wy > end_y
            t = (end_y - oy) / b
            wx, wy = np.where(high, ox + a * t, wx), np.where(high, end_y - .001, wy)
        x1, y1, ok = self.world_to_map(wx, wy)
        x1, y1 = x1[ok], y1[ok]
        src = obs.source
        max_cells = self.cell_distance(src.raytrace_max_range)
        min_cells = self.cell_distance(src.raytrace_min_range)
        # Costmap2D::raytraceLine
        dx_full, dy_full = x1 - int(x0), y1 - int(y0)
        dist = np.hypot(dx_full, dy_full)
        go = ~(dist < min_cells)
        with np.errstate(divide='ignore', invalid='ignore'):
            sx = np.where(dist > 0, x0 + dx_full / dist * min_cells, x0).astype(np.int64)
            sy = np.where(dist > 0, y0 + dy_full / dist * min_cells, y0).astype(np.int64)
            scale = np.where(dist == 0.0, 1.0, np.minimum(1.0, max_cells / dist))
        delta = np.stack([x1 - sx, y1 - sy], axis=1)
        size_a = np.abs(delta).max(axis=1)
        steps = np.minimum((scale * size_a).astype(np.int64), size_a)
        start = np.stack([sx, sy], axis=1)
        cells = line_cells(start[go], delta[go], steps[go], (self.size_x, self.size_y))
        self.costmap[cells[:, 1], cells[:, 0]] = FREE_SPACE     # MarkCell(FREE_SPACE)

    def clear_footprint(self, robot_pose: tuple[float, float, float]) -> None:
        """ObstacleLayer::updateCosts: the robot's footprint polygon set FREE_SPACE.

        Upstream rasterises the polygon (Costmap2D::convexFillCells); here the cells whose
        centre lies inside it (the same cells but for the outline's).
        """
        x, y, yaw = robot_pose
        c, s = math.cos(yaw), math.sin(yaw)
        poly = self.footprint @ np.array([[c, s], [-s, c]]) + (x, y)
        cx = self.origin_xy_m[0] + (np.arange(self.size_x) + 0.5) * self.resolution_m
        cy = self.origin_xy_m[1] + (np.arange(self.size_y) + 0.5) * self.resolution_m
        gx, gy = np.meshgrid(cx, cy)
        inside = np.ones(gx.shape, dtype=bool)
        for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0)):
            inside &= (bx - ax) * (gy - ay) - (by - ay) * (gx - ax) >= 0.0   # left of each edge
        self.costmap[inside] = FREE_SPACE


class VoxelLayer(ObstacleLayer):
    """VoxelLayer: the ObstacleLayer's costmap plus a column of 16 voxel bits per cell.

    voxels (ny, nx) uint32: bit z (low half) and bit z + 16 (high half) of voxel z: both set =
    marked, low only = unknown, neither = free (voxel_grid.hpp ``getVoxel``).
    """

    def __init__(self, layer: LayerConfig, costmap: CostmapConfig) -> None:
        super().__init__(layer, costmap)
        if not 1 <= layer.z_voxels <= VOXEL_BITS:
            raise Nav2ConfigError(f'{layer.name}: z_voxels={layer.z_voxels} must be 1..16 '
                                  '(VoxelGrid supports 16)')
        self.size_z = layer.z_voxels
        self.voxels = np.full((self.size_y, self.size_x), UNKNOWN_COLUMN, np.uint32)
        # VoxelLayer::onInitialize: the unused high voxels stay unknown, so they are allowed
        self.unknown_threshold = layer.unknown_threshold + (VOXEL_BITS - self.size_z)

    def update_origin(self, new_x: float, new_y: float) -> tuple[int, int]:
        """VoxelLayer::updateOrigin: costmap and voxel columns move together."""
        cell_ox, cell_oy = super().update_origin(new_x, new_y)
        self.voxels = _moved(self.voxels, cell_ox, cell_oy, UNKNOWN_COLUMN)
        return cell_ox, cell_oy

    @property
    def top_z_m(self) -> float:
        """origin_z + getSizeInMetersZ(): (size_z - 1 + 0.5) * z_resolution above origin_z."""
        return self.layer.origin_z + (self.size_z - 0.5) * self.layer.z_resolution

    def marked_voxels(self) -> np.ndarray:
        """(ny, nx, size_z) bool: the marked voxels (both bits set)."""
        z = np.arange(self.size_z, dtype=np.uint32)
        low = (self.voxels[..., None] >> z) & 1
        high = (self.voxels[..., None] >> (z + 16)) & 1
        return (low & high).astype(bool)

    def mark(self, obs: Observation) -> None:
        """VoxelLayer::updateBounds, marking: heights, 3-D range, voxel -> LETHAL cell.

        Points below origin_z are marked in the lowest voxel (worldToMap3D at origin_z); a
        column with more than mark_threshold marked voxels makes its cell LETHAL
        (VoxelGrid::markVoxelInMap).
        """
        lay, src, p = self.layer, obs.source, obs.points
        keep = (p[:, 2] >= lay.min_obstacle_height) & (p[:, 2] <= lay.max_obstacle_height)
        sq = ((p - obs.origin) ** 2).sum(axis=1)
        keep &= (sq < src.obstacle_max_range ** 2) & ~(sq < src.obstacle_min_range ** 2)
        z = np.maximum(p[:, 2], lay.origin_z)
        mx, my, inside = self.world_to_map(p[:, 0], p[:, 1])
        fz = (z - lay.origin_z) / lay.z_resolution
        mz = fz.astype(np.int64)
        keep &= inside & (mz < self.size_z)
        mx, my, mz = mx[keep], my[keep], mz[keep]
        bits = (np.uint32(1) << mz.astype(np.uint32)) * np.uint32(0x10001)
        np.bitwise_or.at(self.voxels, (my, mx), bits)
        marked = _popcount16(self.voxels[my, mx] >> np.uint32(16))
        hit = marked > lay.mark_threshold
        self.costmap[my[hit], mx[hit]] = LETHAL_OBSTACLE

    def raytrace_freespace(self, obs: Observation) -> None:
        """VoxelLayer::raytraceFreespace: 3-D rays from the sensor, ends pulled in and clipped.

        Each end moves 2 cells (2 * resolution) towards the sensor, then onto the grid's
        boundary (the top at origin_z + getSizeInMetersZ() - 0.01, the bottom at origin_z, the
        window's sides), then VoxelGrid::clearVoxelLineInMap clears every voxel of the 3-D
        Bresenham line in grid coordinates (z in z_resolution) and sets each column it
        touches FREE (or NO_INFORMATION: too many unknown voxels left) once no more than
        mark_threshold of its voxels are marked (ClearVoxelInMap).
        """
        lay, res = self.layer, self.resolution_m
        ox, oy, oz = (float(v) for v in obs.origin)
        origin_x, origin_y = self.origin_xy_m
        size_x_m, size_y_m = self.size_in_metres
        end_x, end_y, end_z = origin_x + size_x_m, origin_y + size_y_m, self.top_z_m
        sensor = self._grid_float(np.array([[ox, oy, oz]]))
        if sensor is None or obs.points.shape[0] == 0:
            return      # "Sensor origin ... is out of map bounds": no raytrace
        sensor_cell = sensor[0][0]
        p = obs.points
        with np.errstate(divide='ignore', invalid='ignore'):
            distance = np.sqrt(((p - obs.origin) ** 2).sum(axis=1))
            scaling = np.maximum(np.minimum(1.0, (distance - 2 * res) / distance), 0.0)
            w = scaling[:, None] * (p - obs.origin) + obs.origin
            a, b, c = (w - obs.origin).T
            t = np.ones(p.shape[0])
            outside = np.zeros(p.shape[0], dtype=bool)
            above = w[:, 2] > end_z
            below = ~above & (w[:, 2] < lay.origin_z)
            t = np.where(above, np.maximum(0.0, np.minimum(t, (end_z - 0.01 - oz) / c)), t)
            t = np.where(below, np.minimum(t, (lay.origin_z - oz) / c), t)
            outside |= above | below
            for mask, limit, origin, comp in ((w[:, 0] < origin_x, origin_x, ox, a),
                                              (w[:, 1] < origin_y, origin_y, oy, b),
                                              (w[:, 0] > end_x, end_x, ox, a),
                                              (w[:, 1] > end_y, end_y, oy, b)):
                t = np.where(mask, np.minimum(t, (limit - origin) / comp), t)
                outside |= mask
            eps = 1e-5
            t = np.where(outside & (t > 0), t - eps, np.where(outside & (t < 0), t + eps, t))
            w = obs.origin + np.stack([a, b, c], axis=1) * t[:, None]
        ends = self._grid_float(w)
        if ends is None:
            return
        src = obs.source
        self._clear_lines(sensor_cell, ends[0][ends[1]],
                          self.cell_distance(src.raytrace_max_range),
                          self.cell_distance(src.raytrace_min_range))

    def _grid_float(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """VoxelLayer::worldToMap3DFloat for (N, 3) points: (grid coords, inside); None if none."""
        lay = self.layer
        g = np.stack([(w[:, 0] - self.origin_xy_m[0]) / self.resolution_m,
                      (w[:, 1] - self.origin_xy_m[1]) / self.resolution_m,
                      (w[:, 2] - lay.origin_z) / lay.z_resolution], axis=1)
        inside = (g >= 0).all(axis=1) & (g[:, 0] < self.size_x) & (g[:, 1] < self.size_y) & \
            (g[:, 2] < self.size_z)
        if not inside.any():
            return None
        return g, inside

    def _clear_lines(self, start: np.ndarray, ends: np.ndarray, max_cells: int,
                     min_cells: int) -> None:
        """VoxelGrid::clearVoxelLineInMap + raytraceLine with ClearVoxelInMap, for many ends.

        start (3,), ends (N, 3): grid coordinates (floats). The 2-D cost of a touched column
        depends only on its bits after its last clear (bits are only cleared here), so the
        columns are updated once, after every line.
        """
        if ends.shape[0] == 0:
            return
        x0 = np.broadcast_to(start, ends.shape)
        dist = np.sqrt(((x0 - ends) ** 2).sum(axis=1))
        go = ~(dist.astype(np.int64) < min_cells)         # (unsigned)(dist) < min_length
        with np.errstate(divide='ignore', invalid='ignore'):
            scale = np.where(dist > 0, np.minimum(1.0, max_cells / dist), 1.0)
            first = np.where((dist > 0)[:, None],
                             x0 + (ends - x0) / dist[:, None] * min_cells, x0)
        start_cell = first.astype(np.int64)                # int() of non-negative values
        delta = ends.astype(np.int64) - start_cell
        size_a = np.abs(delta).max(axis=1)
        steps = np.minimum((scale * size_a).astype(np.int64), size_a)
        cells = line_cells(start_cell[go], delta[go], steps[go],
                           (self.size_x, self.size_y, self.size_z))
        cleared = np.zeros((self.size_y, self.size_x, VOXEL_BITS), dtype=bool)
        cleared[cells[:, 1], cells[:, 0], cells[:, 2]] = True
        weights = (np.uint32(1) << np.arange(VOXEL_BITS, dtype=np.uint32))
        mask = (cleared.astype(np.uint32) * weights).sum(axis=2, dtype=np.uint32)
        touched = cleared.any(axis=2)
        self.voxels &= ~(mask * np.uint32(0x10001))
        col = self.voxels[touched]
        marked = _popcount16(col >> np.uint32(16))
        unknown = _popcount16((col >> np.uint32(16)) ^ col)
        cost = self.costmap[touched]
        free_enough = marked <= self.layer.mark_threshold
        cost = np.where(free_enough & (unknown <= self.unknown_threshold), FREE_SPACE,
                        np.where(free_enough, NO_INFORMATION, cost)).astype(np.uint8)
        self.costmap[touched] = cost


def make_layer(layer: LayerConfig, costmap: CostmapConfig) -> ObstacleLayer:
    """Return the port of a layer config's plugin (ObstacleLayer or VoxelLayer)."""
    return VoxelLayer(layer, costmap) if layer.plugin == VOXEL_PLUGIN \
        else ObstacleLayer(layer, costmap)


def combine(master: np.ndarray, cost: np.ndarray, combination_method: int) -> None:
    """Write a layer's costs into the master grid in place, as its updateCosts does.

    1: CostmapLayer::updateWithMax (a known cost over an unknown or lower one); 0:
    updateWithOverwrite (every cell); anything else leaves the master alone ("default: break").
    """
    if combination_method == 1:
        take = (cost != NO_INFORMATION) & ((master == NO_INFORMATION) | (master < cost))
    elif combination_method == 0:
        take = np.ones(cost.shape, bool)
    else:
        return
    master[take] = cost[take]


class LayeredCostmap:
    """The master grid over the ported layers (LayeredCostmap::updateMap, Max combination)."""

    def __init__(self, config: CostmapConfig, layers: list[ObstacleLayer]) -> None:
        for layer in layers:
            if layer.layer.combination_method != 1:
                raise Nav2ConfigError(f'{layer.layer.name}: only combination_method 1 (Max) '
                                      'is ported')
        self.config = config
        self.layers = layers
        self.default_value = NO_INFORMATION if config.track_unknown_space else FREE_SPACE
        self.master = np.full_like(layers[0].costmap, self.default_value)

    def update(self, robot_pose: tuple[float, float, float],
               observations: Mapping[str, Observation]) -> np.ndarray:
        """One update: each layer takes the newest observation of each of its sources.

        observations: source name -> its newest Observation (``observation_persistence: 0``
        keeps only the newest, ObservationBuffer::purgeStaleObservations). Returns the master
        grid (ny, nx) uint8, row iy = y, window origin as the layers'.
        """
        for layer in self.layers:
            sources = [s for s in layer.layer.sources if s.name in observations]
            layer.update(robot_pose,
                         [observations[s.name] for s in sources if s.marking],
                         [observations[s.name] for s in sources if s.clearing])
        # resetMap to the default, then CostmapLayer::updateWithMax of each layer
        master = np.full_like(self.layers[0].costmap, self.default_value)
        for layer in self.layers:
            combine(master, layer.costmap, layer.layer.combination_method)
        self.master = master
        return master

    @property
    def origin_xy_m(self) -> tuple[float, float]:
        """The window's corner [m] (all layers move alike)."""
        return self.layers[0].origin_xy_m
