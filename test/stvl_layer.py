"""A port of the SpatioTemporalVoxelLayer (STVL) 2.5.5, to play it in tests (test code only).

Jazzy ships spatio_temporal_voxel_layer 2.5.5 (ros/rosdistro ``jazzy/distribution.yaml``; the
source read is the release repository's tag ``release/jazzy/spatio_temporal_voxel_layer/
2.5.5-1``). Each rule names the upstream file and function it follows; the files are
``src/spatio_temporal_voxel_layer.cpp`` (layer), ``src/spatio_temporal_voxel_grid.cpp``
(grid), ``src/measurement_buffer.cpp`` (buffer) and
``src/frustum_models/depth_camera_frustum.cpp`` (frustum). What is ported:

- the parameters the layer and each source declare, with their defaults
  (layer ``SpatioTemporalVoxelLayer::onInitialize``): :func:`read_stvl_costmap` refuses a name
  the plugin never reads and a value whose type is not the declared one;
- the MeasurementBuffer: the frustum's pose from ``sensor_frame`` or the cloud's frame, a
  clearing-only source storing no points, the passthrough height filter in the global frame,
  ``observation_persistence: 0`` keeping the newest reading, ``clear_after_reading`` and
  ``UpdatedAtExpectedRate`` (buffer ``BufferROSCloud``, ``RemoveStaleObservations``,
  ``UpdatedAtExpectedRate``);
- the grid: marking voxels with the time now (grid ``operator()``, ``Mark``), the depth
  camera frustum (frustum ``ComputePlaneNormals``, ``TransformModel``, ``IsInside``), decay
  and its acceleration inside a frustum (grid ``ClearFrustums``,
  ``TemporalClearAndGenerateCostmap``, ``GetTemporalClearingDuration``,
  ``GetFrustumAcceleration``), the flattened column counts (grid
  ``PopulateCostmapAndPointcloud``);
- the layer's update: the rolling window, clearing and decay before marking, the costmap
  rebuilt from the columns counted *before* this update's marks (``updateBounds``,
  ``UpdateROSCostmap``: ``count >= mark_threshold`` is LETHAL), the footprint set FREE in the
  layer's own costmap only (``updateFootprint``, ``updateCosts``), and the Max combination.

The grid is OpenVDB upstream; here a sorted array of packed voxel indices and their mark
times (same semantics: a voxel is on with a time or off). Not ported: TF (the caller gives
poses), the voxel filter (``filter: voxel``), LaserScan sources, the 3-D lidar frustum,
mapping mode, services.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import nav2_layers as nav2
import numpy as np
import yaml

STVL_PLUGIN = 'spatio_temporal_voxel_layer/SpatioTemporalVoxelLayer'

#: layer onInitialize: declareParameter(name, default) of the layer. ``track_unknown_space``
#: defaults to the costmap's (layered_costmap_->isTrackingUnknown()).
LAYER_DEFAULTS: dict[str, Any] = {
    'plugin': None, 'observation_sources': '', 'transform_tolerance': 0.2, 'enabled': True,
    'publish_voxel_map': False, 'voxel_size': 0.05, 'combination_method': 1,
    'mark_threshold': 0, 'update_footprint_enabled': True, 'track_unknown_space': False,
    'decay_model': 0, 'voxel_decay': -1.0, 'mapping_mode': False, 'map_save_duration': 60.0,
}
#: layer onInitialize: declareParameter(source + "." + name, default) of each source.
SOURCE_DEFAULTS: dict[str, Any] = {
    'topic': '', 'sensor_frame': '', 'observation_persistence': 0.0,
    'expected_update_rate': 0.0, 'data_type': 'PointCloud2', 'min_obstacle_height': 0.0,
    'max_obstacle_height': 3.0, 'inf_is_valid': False, 'marking': True, 'clearing': False,
    'obstacle_range': 2.5, 'min_z': 0.0, 'max_z': 10.0, 'vertical_fov_angle': 0.7,
    'vertical_fov_padding': 0.0, 'horizontal_fov_angle': 1.04, 'decay_acceleration': 0.0,
    'filter': 'passthrough', 'voxel_min_points': 0, 'clear_after_reading': False,
    'enabled': True, 'model_type': 0,
}
#: grid GetTemporalClearingDuration: 0 linear, 1 exponential, anything else persistent
#: (GlobalDecayModel PERSISTENT = 2; the upstream examples write -1).
LINEAR, EXPONENTIAL = 0, 1
#: measurement_reading.h ModelType
DEPTH_CAMERA = 0


@dataclass(frozen=True)
class SourceConfig:
    """One observation source of the STVL (names as the plugin declares them)."""

    name: str
    topic: str
    sensor_frame: str
    observation_persistence: float
    expected_update_rate: float
    data_type: str
    min_obstacle_height: float
    max_obstacle_height: float
    inf_is_valid: bool
    marking: bool
    clearing: bool
    obstacle_range: float
    min_z: float
    max_z: float
    vertical_fov_angle: float
    vertical_fov_padding: float
    horizontal_fov_angle: float
    decay_acceleration: float
    filter: str
    voxel_min_points: int
    clear_after_reading: bool
    enabled: bool
    model_type: int


@dataclass(frozen=True)
class LayerConfig:
    """The STVL's own parameters and its sources."""

    name: str
    plugin: str
    sources: tuple[SourceConfig, ...]
    transform_tolerance: float
    enabled: bool
    publish_voxel_map: bool
    voxel_size: float
    combination_method: int
    mark_threshold: int
    update_footprint_enabled: bool
    track_unknown_space: bool
    decay_model: int
    voxel_decay: float
    mapping_mode: bool
    map_save_duration: float


def read_stvl_costmap(path: str | Path, section: str = 'local_costmap') -> nav2.CostmapConfig:
    """Read a Nav2 params file whose costmap has STVL layers (and an inflation layer).

    Every name must be one the plugin declares (layer onInitialize) or the costmap reads
    (nav2_layers.COSTMAP_KEYS), with the declared type: a misspelt key does nothing in Nav2,
    an int given for a double stops the plugin (rclcpp refuses the override's type).
    Nav2ConfigError names what is wrong. Settings the port does not follow are refused too:
    ``filter: voxel``, a 3-D lidar frustum, LaserScan, mapping mode.
    """
    data = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    values = data[section][section]['ros__parameters']
    plugins = list(values['plugins'])
    layers = []
    for name in plugins:
        layer = values[name]
        plugin = layer.get('plugin')
        if plugin == nav2.INFLATION_PLUGIN:
            unknown = set(layer) - nav2.INFLATION_LAYER_KEYS
            if unknown:
                raise nav2.Nav2ConfigError(f'{name}: {sorted(unknown)} not read by Nav2 Jazzy')
            continue
        if plugin != STVL_PLUGIN:
            raise nav2.Nav2ConfigError(f'{name}: plugin {plugin!r} is not ported here')
        names = str(layer.get('observation_sources', '')).split()
        defaults = dict(LAYER_DEFAULTS,
                        track_unknown_space=bool(values.get('track_unknown_space', False)))
        settings = nav2._checked(layer, defaults, name, extra=frozenset(names))
        sources = []
        for source in names:
            got = nav2._checked(layer[source], SOURCE_DEFAULTS, f'{name}.{source}')
            sources.append(_checked_source(SourceConfig(name=source, **got), name))
        for key in ('observation_sources', *names):
            settings.pop(key)
        config = LayerConfig(name=name, sources=tuple(sources), **settings)
        if config.mapping_mode:
            raise nav2.Nav2ConfigError(f'{name}: mapping_mode saves maps and never clears: '
                                       'not a navigation costmap')
        layers.append(config)
    return nav2.costmap_config(values, plugins, layers, section)


def _checked_source(source: SourceConfig, layer: str) -> SourceConfig:
    """Refuse a source whose settings the plugin reads differently from what they suggest."""
    where = f'{layer}.{source.name}'
    if not source.topic:
        raise nav2.Nav2ConfigError(f'{where}: topic is empty (the plugin subscribes to "")')
    if source.data_type != 'PointCloud2':
        raise nav2.Nav2ConfigError(f'{where}: data_type {source.data_type!r}: only PointCloud2 '
                                   'is ported')
    if source.filter not in ('passthrough', 'none'):
        raise nav2.Nav2ConfigError(f'{where}: filter {source.filter!r}: passthrough or none '
                                   'are ported (another string is "none" upstream)')
    if source.clearing and source.model_type != DEPTH_CAMERA:
        raise nav2.Nav2ConfigError(f'{where}: model_type {source.model_type}: only the depth '
                                   'camera frustum (0) is ported')
    if source.clearing and not source.marking and source.observation_persistence > 0.0:
        # a clearing-only reading keeps an empty cloud stamped 0 (BufferROSCloud), which
        # RemoveStaleObservations finds older than any persistence: no frustum, no clearing
        raise nav2.Nav2ConfigError(f'{where}: observation_persistence > 0 on a clearing-only '
                                   'source never clears (its readings are stamped 0)')
    return source


# ------------------------------------------------------------------------------------------
# Measurement buffer


@dataclass(frozen=True)
class Reading:
    """observation::MeasurementReading: a frustum pose and, for marking, the global cloud.

    origin (3,), rotation (3, 3): the pose of ``sensor_frame`` (else the cloud's frame) in the
    global frame; points (N, 3) float64 global frame [m] (empty for a clearing-only source);
    stamp_s: the cloud's stamp [s] (0 for a clearing-only source: its default cloud);
    source: its settings.
    """

    origin: np.ndarray
    rotation: np.ndarray
    points: np.ndarray
    stamp_s: float
    source: SourceConfig


class MeasurementBuffer:
    """buffer::MeasurementBuffer of one source (clock: the caller's ``now_s``)."""

    def __init__(self, source: SourceConfig, now_s: float = 0.0) -> None:
        self.source = source
        self.readings: list[Reading] = []       # newest first, as _observation_list
        self.last_updated_s = now_s             # _last_updated(clock->now())

    def buffer_cloud(self, points: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
                     stamp_s: float, now_s: float, sensor_pose: tuple[np.ndarray, np.ndarray]
                     | None = None) -> None:
        """BufferROSCloud: a new reading from a cloud.

        points (N, 3) in the cloud frame, which is at (rotation, translation) in the global
        frame; sensor_pose: the ``sensor_frame``'s pose when the source names one.
        """
        src = self.source
        frame_rot, frame_t = sensor_pose if sensor_pose is not None else (rotation, translation)
        if src.clearing and not src.marking:
            # "no need to buffer points": the reading keeps the pose and its default cloud
            # (MeasurementReading(): an empty PointCloud2, stamp 0), and _last_updated is not
            # refreshed (the return comes before it)
            self.readings.insert(0, Reading(np.asarray(frame_t, np.float64),
                                            np.asarray(frame_rot, np.float64),
                                            np.zeros((0, 3)), 0.0, src))
            return
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        # tf2::doTransform of a PointCloud2 writes float32 coordinates
        world = (pts @ np.asarray(rotation, np.float64).T
                 + np.asarray(translation, np.float64)).astype(np.float32).astype(np.float64)
        if src.filter == 'passthrough':
            # pcl::PassThrough on z within [min, max] (limits kept); NaNs removed
            z = world[:, 2]
            world = world[(z >= src.min_obstacle_height) & (z <= src.max_obstacle_height)]
        self.readings.insert(0, Reading(np.asarray(frame_t, np.float64),
                                        np.asarray(frame_rot, np.float64), world, stamp_s,
                                        src))
        self.last_updated_s = now_s
        self._remove_stale(now_s)

    def _remove_stale(self, now_s: float) -> None:
        """RemoveStaleObservations: persistence 0 keeps the newest; else those within it."""
        if not self.readings:
            return
        keep = self.source.observation_persistence
        if keep == 0.0:
            del self.readings[1:]
            return
        for i, reading in enumerate(self.readings):
            if now_s - reading.stamp_s > keep:
                del self.readings[i:]
                return

    def get_readings(self, now_s: float) -> list[Reading]:
        """GetReadings, then ObservationsResetAfterReading when clear_after_reading."""
        self._remove_stale(now_s)
        out = list(self.readings)
        if self.source.clear_after_reading:
            self.readings.clear()
        return out

    def updated_at_expected_rate(self, now_s: float) -> bool:
        """UpdatedAtExpectedRate: 0 always; else now - last update <= expected_update_rate."""
        rate = self.source.expected_update_rate
        return rate == 0.0 or now_s - self.last_updated_s <= rate


# ------------------------------------------------------------------------------------------
# Frustum


def _axis_angle(axis: int, angle: float) -> np.ndarray:
    """Eigen::AngleAxisd(angle, UnitX/UnitY) as a (3, 3) rotation."""
    c, s = math.cos(angle), math.sin(angle)
    if axis == 0:
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


class DepthCameraFrustum:
    """geometry::DepthCameraFrustum: six planes in the sensor frame (z forward), posed.

    vfov_rad, hfov_rad: vertical_fov_angle, horizontal_fov_angle; min_d, max_d: min_z, max_z
    (the corner rays' lengths: the near and far planes are flat, at z = d * cos(v/2) *
    cos(h/2)).
    """

    def __init__(self, vfov_rad: float, hfov_rad: float, min_d: float, max_d: float) -> None:
        self.valid = not (vfov_rad == 0 and hfov_rad == 0)    # "bogus values"
        self.normals = np.zeros((6, 3))
        self.points = np.zeros((6, 3))
        if not self.valid:
            return
        # ComputePlaneNormals: four corner rays, CCW, each at min_d and max_d
        z = np.array([0.0, 0.0, 1.0])
        rays = []
        for v_sign, h_sign in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
            rays.append(_axis_angle(0, v_sign * vfov_rad / 2.0)
                        @ _axis_angle(1, h_sign * hfov_rad / 2.0) @ z)
        pt = np.array([r * d for r in rays for d in (min_d, max_d)])    # pt_[0..7]

        def unit(v: np.ndarray) -> np.ndarray:
            return v / np.linalg.norm(v)

        v_01, v_13 = pt[1] - pt[0], pt[3] - pt[1]
        v_23, v_35 = pt[3] - pt[2], pt[5] - pt[3]
        v_45, v_57 = pt[5] - pt[4], pt[7] - pt[5]
        v_67, v_71 = pt[7] - pt[6], pt[1] - pt[7]
        far = unit(np.cross(v_57, v_71))
        self.normals = np.array([unit(np.cross(v_13, v_01)), unit(np.cross(v_35, v_23)),
                                 unit(np.cross(v_57, v_45)), unit(np.cross(v_71, v_67)),
                                 far, -far])
        self.points = np.array([pt[0], pt[2], pt[4], pt[6], pt[7], pt[2]])

    def posed(self, rotation: np.ndarray, position: np.ndarray) -> DepthCameraFrustum:
        """TransformModel: planes into the global frame by the sensor's pose (T = [R | p])."""
        out = DepthCameraFrustum(0.0, 0.0, 0.0, 0.0)
        out.valid = self.valid
        rot = np.asarray(rotation, np.float64)
        normals = self.normals @ rot.T
        out.normals = normals / np.linalg.norm(normals, axis=1, keepdims=True) \
            if self.valid else normals
        out.points = self.points @ rot.T + np.asarray(position, np.float64)
        return out

    def is_inside(self, points: np.ndarray) -> np.ndarray:
        """IsInside for (N, 3) points: outside once (p - plane point) . normal > 0 for a plane.

        Upstream normalises p - plane point first (the sign is the same; Eigen leaves a zero
        vector, a point on a plane's corner, as it is: 0, inside).
        """
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        if not self.valid:
            return np.zeros(pts.shape[0], bool)
        inside = np.ones(pts.shape[0], bool)
        for normal, point in zip(self.normals, self.points):
            inside &= ~(((pts - point) @ normal) > 0.0)
        return inside


# ------------------------------------------------------------------------------------------
# Voxel grid

_OFFSET = 1 << 20          # packed index: 21 bits per axis, signed by this offset


def _pack(index: np.ndarray) -> np.ndarray:
    i = index.astype(np.int64) + _OFFSET
    return (i[:, 0] << 42) | (i[:, 1] << 21) | i[:, 2]


def _unpack(keys: np.ndarray) -> np.ndarray:
    mask = (1 << 21) - 1
    return np.stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask],
                    axis=1) - _OFFSET


class SpatioTemporalVoxelGrid:
    """volume_grid::SpatioTemporalVoxelGrid: voxels on, each holding the time it was marked.

    keys (V,) int64 sorted packed (i, j, k) indices; times (V,) float64 [s].
    """

    def __init__(self, voxel_size: float, decay_model: int, voxel_decay: float) -> None:
        # the grid's constructor takes the voxel size as a float
        self.voxel_size = float(np.float32(voxel_size))
        self.decay_model = decay_model
        self.voxel_decay = voxel_decay
        self.keys = np.zeros(0, np.int64)
        self.times = np.zeros(0, np.float64)
        #: (x, y) voxel-centre columns -> count of voxels on (GetFlattenedCostmap)
        self.columns = np.zeros((0, 2)), np.zeros(0, np.int64)

    def centres(self) -> np.ndarray:
        """IndexToWorld: (V, 3) voxel centres [m] (index * size + size / 2)."""
        return _unpack(self.keys) * self.voxel_size + self.voxel_size / 2.0

    def clearing_duration(self, time_delta: np.ndarray) -> np.ndarray:
        """GetTemporalClearingDuration: decay - dt (linear), decay * e^-dt, else decay."""
        if self.decay_model == LINEAR:
            return self.voxel_decay - time_delta
        if self.decay_model == EXPONENTIAL:
            return self.voxel_decay * np.exp(-time_delta)
        return np.full_like(time_delta, self.voxel_decay)

    @staticmethod
    def frustum_acceleration(time_delta: np.ndarray, factor: float) -> np.ndarray:
        """GetFrustumAcceleration: 1/6 * decay_acceleration * dt^3."""
        return 1.0 / 6.0 * factor * time_delta ** 3

    def clear_frustums(self, readings: list[Reading], now_s: float) -> None:
        """ClearFrustums + TemporalClearAndGenerateCostmap at time now_s.

        Each voxel takes the first frustum it lies in: it goes when its decay duration less
        the acceleration is below 0, else its time moves back by the acceleration; a voxel
        in no frustum goes when its decay duration is below 0. The survivors are counted
        per (x, y) column. An empty grid returns at once (no columns).
        """
        self.columns = np.zeros((0, 2)), np.zeros(0, np.int64)
        if self.keys.size == 0:
            return
        frustums = []
        for r in readings:
            src = r.source
            if src.model_type != DEPTH_CAMERA:
                continue
            frustum = DepthCameraFrustum(src.vertical_fov_angle, src.horizontal_fov_angle,
                                         src.min_z, src.max_z).posed(r.rotation, r.origin)
            frustums.append((frustum, src.decay_acceleration))
        centres = self.centres()
        dt = now_s - self.times
        base = self.clearing_duration(dt)
        cleared = np.zeros(self.keys.size, bool)
        taken = np.zeros(self.keys.size, bool)
        for frustum, factor in frustums:
            inside = frustum.is_inside(centres) & ~taken
            taken |= inside
            accel = self.frustum_acceleration(dt, factor)
            gone = inside & (base - accel < 0.0)
            cleared |= gone
            stay = inside & ~gone
            self.times[stay] -= accel[stay]
        cleared |= ~taken & (base < 0.0)
        self.keys, self.times = self.keys[~cleared], self.times[~cleared]
        xy, counts = np.unique(centres[~cleared][:, :2], axis=0, return_counts=True)
        self.columns = xy, counts

    def mark(self, readings: list[Reading], now_s: float) -> None:
        """Mark / operator(): turn on with the time now the voxels of the marking points.

        A point counts within obstacle_range of its reading's origin (3-D), not within 1 cm.

        Index: a negative coordinate less one voxel size, over the voxel size, truncated
        toward zero (openvdb::Coord from a Vec3d).
        """
        vs = self.voxel_size
        for r in readings:
            if not r.source.marking or r.points.shape[0] == 0:
                continue
            p = r.points
            d2 = ((p - r.origin) ** 2).sum(axis=1).astype(np.float32)
            keep = ~((d2 > np.float32(r.source.obstacle_range ** 2)) | (d2 < 0.0001))
            p = p[keep]
            shifted = np.where(p < 0, p - vs, p)
            index = np.trunc(shifted / vs).astype(np.int64)
            new = np.unique(_pack(index))
            pos = np.searchsorted(self.keys, new)
            found = (pos < self.keys.size) & (self.keys[np.minimum(pos, self.keys.size - 1)]
                                              == new) if self.keys.size else \
                np.zeros(new.size, bool)
            self.times[pos[found]] = now_s
            keys = np.concatenate([self.keys, new[~found]])
            times = np.concatenate([self.times, np.full(int((~found).sum()), now_s)])
            order = np.argsort(keys, kind='stable')
            self.keys, self.times = keys[order], times[order]


# ------------------------------------------------------------------------------------------
# Layer


class SpatioTemporalVoxelLayer(nav2.ObstacleLayer):
    """spatio_temporal_voxel_layer::SpatioTemporalVoxelLayer: its costmap_, grid and buffers.

    costmap (ny, nx) uint8 Nav2 costs, row iy = y, rebuilt at every update from the grid.
    """

    def __init__(self, layer: LayerConfig, costmap: nav2.CostmapConfig) -> None:
        super().__init__(layer, costmap)     # size, resolution, rolling, footprint
        # onInitialize: the layer's own track_unknown_space picks default_value_
        self.default_value = nav2.NO_INFORMATION if layer.track_unknown_space \
            else nav2.FREE_SPACE
        self.costmap[:] = self.default_value
        self.grid = SpatioTemporalVoxelGrid(layer.voxel_size, layer.decay_model,
                                            layer.voxel_decay)
        self.buffers = {s.name: MeasurementBuffer(s) for s in layer.sources}
        self.current = True

    def update_stvl(self, robot_pose: tuple[float, float, float], now_s: float) -> None:
        """UpdateBounds then updateCosts' footprint, at time now_s (the node's clock)."""
        x, y, _ = robot_pose
        if not self.layer.enabled:
            return
        if self.rolling:
            size_x_m, size_y_m = self.size_in_metres
            self.update_origin(x - size_x_m / 2, y - size_y_m / 2)
        marking, clearing = [], []
        current = True
        for buffer in self.buffers.values():
            src = buffer.source
            if src.marking:
                current &= buffer.updated_at_expected_rate(now_s)
            if src.clearing:
                current &= buffer.updated_at_expected_rate(now_s)
        # GetMarkingObservations / GetClearingObservations, then ObservationsResetAfterReading
        for buffer in self.buffers.values():
            got = buffer.get_readings(now_s)
            if buffer.source.marking:
                marking.extend(got)
            if buffer.source.clearing:
                clearing.extend(got)
        self.current = current
        self.grid.clear_frustums(clearing, now_s)
        self.grid.mark(marking, now_s)
        # UpdateROSCostmap: resetMaps, then each column counted before this update's marks
        self.costmap[:] = self.default_value
        xy, counts = self.grid.columns
        if counts.size:
            mx, my, inside = self.world_to_map(xy[:, 0], xy[:, 1])
            hit = inside & (counts >= self.layer.mark_threshold)
            self.costmap[my[hit], mx[hit]] = nav2.LETHAL_OBSTACLE
        if self.layer.update_footprint_enabled:     # updateCosts: setConvexPolygonCost
            self.clear_footprint(robot_pose)


class STVLCostmap:
    """The master grid over STVL layers (LayeredCostmap::updateMap, Max or Overwrite)."""

    def __init__(self, config: nav2.CostmapConfig) -> None:
        self.config = config
        self.layers = [SpatioTemporalVoxelLayer(layer, config) for layer in config.layers]
        self.default_value = nav2.NO_INFORMATION if config.track_unknown_space \
            else nav2.FREE_SPACE
        self.master = np.full_like(self.layers[0].costmap, self.default_value)

    def buffer(self, source: str, points: np.ndarray, pose: tuple[np.ndarray, np.ndarray],
               stamp_s: float, now_s: float,
               sensor_pose: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Buffer a cloud that arrived on ``source`` (its frame's pose in the global frame).

        sensor_pose: the pose of the source's ``sensor_frame`` when it names one.
        """
        for layer in self.layers:
            if source in layer.buffers:
                layer.buffers[source].buffer_cloud(points, pose[0], pose[1], stamp_s, now_s,
                                                   sensor_pose)

    def update(self, robot_pose: tuple[float, float, float], now_s: float) -> np.ndarray:
        """One update; returns the master grid (ny, nx) uint8, window origin as the layers'."""
        master = np.full_like(self.layers[0].costmap, self.default_value)
        for layer in self.layers:
            layer.update_stvl(robot_pose, now_s)
            nav2.combine(master, layer.costmap, layer.layer.combination_method)
        self.master = master
        return master

    @property
    def origin_xy_m(self) -> tuple[float, float]:
        """The window's corner [m]."""
        return self.layers[0].origin_xy_m

    @property
    def current(self) -> bool:
        """Layer::isCurrent of every layer."""
        return all(layer.current for layer in self.layers)
