"""The shipped collision_monitor example keeps the detector's drops (Nav2 Jazzy, ported).

A port of what nav2_collision_monitor (navigation2 ``jazzy``) reads and does with a
pointcloud source, written from its source:

- the names and types each part declares: the node (``collision_monitor_node.cpp``,
  ``CollisionMonitor::getParameters``), a source (``source.cpp``,
  ``Source::getCommonParameters``), a pointcloud source (``pointcloud.cpp``,
  ``PointCloud::getParameters``), a polygon (``polygon.cpp``,
  ``Polygon::getCommonParameters`` and ``Polygon::getParameters``; ``circle.cpp``,
  ``Circle::getParameters``). A name none of them declares does nothing; an int given
  where a double is declared stops the node;
- ``PointCloud::getData``: a point nearer than ``min_range`` to the cloud frame's origin
  is skipped, the rest go into ``base_frame_id`` and are kept when their height there lies in
  ``[min_height, max_height]``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import nav2_layers as nav2
import numpy as np
import pytest
import ros_env
import yaml

from message_helpers import pointcloud2_to_points
from obstacle_detection.cli import bag_processor
from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info
from obstacle_detection.ros.frame_gate import CameraState
from obstacle_detection.sim.scenes import render_scene
from builtin_interfaces.msg import Time

REPO = ros_env.REPO_ROOT
MONITOR_YAML = REPO / 'params' / 'nav2_collision_monitor.yaml'
CORRIDOR = REPO / 'params' / 'corridor.yaml'

#: CollisionMonitor::getParameters (None: declared without a default, type given apart).
NODE_KEYS: dict[str, Any] = {
    'use_realtime_priority': False, 'cmd_vel_in_topic': 'cmd_vel_smoothed',
    'cmd_vel_out_topic': 'cmd_vel', 'state_topic': '', 'base_frame_id': 'base_footprint',
    'odom_frame_id': 'odom', 'transform_tolerance': 0.1, 'source_timeout': 2.0,
    'base_shift_correction': True, 'stop_pub_timeout': 1.0, 'polygons': [],
    'observation_sources': [], 'use_sim_time': False,
}
#: Source::getCommonParameters (source_timeout defaults to the node's) and
#: PointCloud::getParameters.
POINTCLOUD_KEYS: dict[str, Any] = {
    'type': 'scan', 'topic': 'scan', 'enabled': True, 'source_timeout': 2.0,
    'min_height': 0.05, 'max_height': 0.5, 'min_range': 0.0, 'use_global_height': False,
}
#: Polygon::getCommonParameters / getParameters and Circle::getParameters; the keys an
#: action type reads (slowdown_ratio: slowdown; linear/angular_limit: limit;
#: time_before_collision, simulation_time_step: approach).
POLYGON_KEYS: dict[str, Any] = {
    'type': '', 'action_type': '', 'enabled': True, 'min_points': 4, 'max_points': 0,
    'visualize': False, 'polygon_pub_topic': '', 'polygon_subscribe_transient_local': False,
    'polygon_sub_topic': '', 'footprint_topic': '', 'sources_names': [], 'points': '',
}
ACTION_KEYS: dict[str, dict[str, Any]] = {
    'stop': {}, 'none': {}, 'slowdown': {'slowdown_ratio': 0.5},
    'limit': {'linear_limit': 0.5, 'angular_limit': 0.5},
    'approach': {'time_before_collision': 2.0, 'simulation_time_step': 0.1},
}


def read_monitor(path: Path) -> dict[str, Any]:
    """Return ``collision_monitor: ros__parameters``, every name checked as Nav2 reads it."""
    values = yaml.safe_load(path.read_text(encoding='utf-8'))['collision_monitor'][
        'ros__parameters']
    polygons, sources = list(values['polygons']), list(values['observation_sources'])
    nav2._checked({k: v for k, v in values.items() if k not in polygons + sources}, NODE_KEYS,
                  'collision_monitor')
    for name in polygons:
        polygon = values[name]
        if polygon.get('type') not in ('polygon', 'circle'):
            raise nav2.Nav2ConfigError(f'{name}: type {polygon.get("type")!r} is not ported')
        action = polygon.get('action_type')
        if action not in ACTION_KEYS:
            raise nav2.Nav2ConfigError(f'{name}: action_type {action!r} is not one Nav2 knows')
        keys = dict(POLYGON_KEYS, **ACTION_KEYS[action])
        if polygon['type'] == 'circle':
            keys.pop('points')
            keys['radius'] = 0.0
        nav2._checked(polygon, keys, name)
        if 'points' not in polygon and 'radius' not in polygon and action != 'approach' \
                and 'polygon_sub_topic' not in polygon:
            raise nav2.Nav2ConfigError(f'{name}: neither points nor polygon_sub_topic')
    for name in sources:
        source = values[name]
        if source.get('type') != 'pointcloud':
            raise nav2.Nav2ConfigError(f'{name}: type {source.get("type")!r} is not ported')
        nav2._checked(source, POINTCLOUD_KEYS, name)
    return values


def pointcloud_data(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
                    source: dict[str, Any]) -> np.ndarray:
    """PointCloud::getData: (K, 2) x, y in base_frame_id of the points the source keeps.

    points (N, 3) in the cloud frame; (rotation, translation): that frame in base_frame_id.
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    settings = dict(POINTCLOUD_KEYS, **source)
    if settings['use_global_height']:
        raise ValueError('use_global_height reads a "height" field the detector does not send')
    p = p[~(np.linalg.norm(p, axis=1) < settings['min_range'])]
    base = p @ np.asarray(rotation, np.float64).T + np.asarray(translation, np.float64)
    keep = (base[:, 2] >= settings['min_height']) & (base[:, 2] <= settings['max_height'])
    return base[keep, :2]


def _node_cloud(scene: str) -> tuple[np.ndarray, np.ndarray, str]:
    """(obstacles/points (N, 3), the drop points it should hold (D, 3), the cloud's frame)."""
    values = bag_processor.node_param_values(CORRIDOR)
    config = bag_processor.config_from_values(values, str(CORRIDOR))
    frame = render_scene(scene, seed=0)
    height, width = frame.depth_mm.shape
    stamp = Time(sec=1)
    camera = CameraState.from_camera_info(intrinsics_to_camera_info(
        frame.intrinsics, width, height, stamp=stamp, frame_id='camera_depth_optical_frame'))
    image = array_to_image(frame.depth_mm, stamp=stamp, frame_id='camera_depth_optical_frame')
    messages, result, reason, _ = bag_processor.process_frame(
        image, [camera], config, with_ground=False, with_overlay=False)
    assert messages is not None, reason
    cloud = messages['obstacles']
    # every drop point is sent on obstacles/points, those at the edges of the view included
    # (only the VoxelLayer's obstacles/marking_points leaves those out: clearing.nav2_clouds)
    return pointcloud2_to_points(cloud), result.drop_points, cloud.header.frame_id


def test_the_shipped_monitor_reads_as_nav2_declares_it() -> None:
    values = read_monitor(MONITOR_YAML)
    (source,) = [values[name] for name in values['observation_sources']]

    assert source['topic'] == '/obstacles/points'
    assert values['base_frame_id'] == bag_processor.node_param_values(CORRIDOR)[
        'cloud_frame_id']


@pytest.mark.parametrize(('edit', 'message'), [
    ({'detector_obstacles.min_height': -1}, 'min_height=-1 must be a float'),
    ({'detector_obstacles.min_z': -1.0}, "'min_z' is not a parameter"),
    ({'PolygonStop.slowdown_ratio': 0.3}, "'slowdown_ratio' is not a parameter"),
    ({'source_timout': 1.0}, "'source_timout' is not a parameter"),
])
def test_a_key_nav2_reads_differently_is_refused(tmp_path: Path, edit: dict,
                                                 message: str) -> None:
    data = yaml.safe_load(MONITOR_YAML.read_text(encoding='utf-8'))
    values = data['collision_monitor']['ros__parameters']
    for dotted, value in edit.items():
        *path, key = dotted.split('.')
        node = values
        for part in path:
            node = node[part]
        node[key] = value
    path = tmp_path / 'monitor.yaml'
    path.write_text(yaml.safe_dump(data), encoding='utf-8')

    with pytest.raises(nav2.Nav2ConfigError, match=message):
        read_monitor(path)


@pytest.mark.parametrize('scene', ['step_down', 'dock_edge'])
def test_drop_points_survive_the_shipped_source_and_not_the_default(scene: str) -> None:
    values = read_monitor(MONITOR_YAML)
    source = values['detector_obstacles']
    default = {k: v for k, v in source.items() if k not in ('min_height', 'max_height')}
    points, drops, frame = _node_cloud(scene)
    identity = (np.eye(3), np.zeros(3))       # the cloud is in base_frame_id already
    in_cloud = (np.abs(points[:, None, :] - drops[None, :, :]).max(axis=2) < 1e-6).any(axis=1)

    assert frame == values['base_frame_id']
    assert drops.shape[0] > 100 and in_cloud.sum() >= drops.shape[0]   # published
    drop = points[in_cloud | (points[:, 2] < 0.0)]            # the edge and the floor below

    assert pointcloud_data(points, *identity, source).shape[0] == points.shape[0]
    assert pointcloud_data(drop, *identity, source).shape[0] == drop.shape[0]
    assert pointcloud_data(drop, *identity, default).shape[0] == 0
