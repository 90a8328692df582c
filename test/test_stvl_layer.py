"""The STVL port's rules (test/stvl_layer.py) on small inputs, and the shipped STVL example."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import nav2_layers as nav2
import numpy as np
import pytest
import ros_env
import stvl_layer as stvl
import yaml

STVL_YAML = ros_env.REPO_ROOT / 'params' / 'nav2_stvl.yaml'
IDENTITY = (np.eye(3), np.zeros(3))
#: the optical frame (z forward, x right, y down) of a level camera 0.6 m up, in base/odom
OPTICAL = (np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
           np.array([0.0, 0.0, 0.6]))


def _write(tmp_path: Path, edit: dict) -> Path:
    """Write the shipped file with ``edit`` (dotted key under stvl_layer -> value)."""
    data = yaml.safe_load(STVL_YAML.read_text(encoding='utf-8'))
    layer = data['local_costmap']['local_costmap']['ros__parameters']['stvl_layer']
    for dotted, value in edit.items():
        *path, key = dotted.split('.')
        node = layer
        for part in path:
            node = node[part]
        if value is None:
            del node[key]
        else:
            node[key] = value
    out = tmp_path / 'stvl.yaml'
    out.write_text(yaml.safe_dump(data), encoding='utf-8')
    return out


def _costmap(tmp_path: Path, edit: dict | None = None) -> stvl.STVLCostmap:
    return stvl.STVLCostmap(stvl.read_stvl_costmap(_write(tmp_path, edit or {})))


def _update(costmap: stvl.STVLCostmap, points: np.ndarray, now_s: float) -> np.ndarray:
    """One frame's clouds (obstacles in odom = base, the frustum's pose) and an update."""
    costmap.buffer('detector_obstacles', points, IDENTITY, now_s, now_s)
    costmap.buffer('detector_frustum', np.zeros((0, 3)), OPTICAL, now_s, now_s)
    return costmap.update((0.0, 0.0, 0.0), now_s)


def _lethal_at(costmap: stvl.STVLCostmap, master: np.ndarray, x: float, y: float) -> bool:
    mx, my, inside = costmap.layers[0].world_to_map(x, y)
    assert inside
    return bool(master[my, mx] == nav2.LETHAL_OBSTACLE)


def test_the_shipped_example_reads_as_the_plugin_declares_it() -> None:
    config = stvl.read_stvl_costmap(STVL_YAML)
    (layer,) = config.layers
    sources = {s.topic: s for s in layer.sources}

    assert layer.plugin == stvl.STVL_PLUGIN
    assert sources['/obstacles/points'].marking and not sources['/obstacles/points'].clearing
    frustum = sources['/obstacles/clearing_points']
    assert frustum.clearing and not frustum.marking and frustum.sensor_frame == ''
    assert frustum.expected_update_rate == 0.0 and frustum.observation_persistence == 0.0
    assert layer.voxel_decay > 0.0 and layer.decay_model == stvl.LINEAR


@pytest.mark.parametrize(('edit', 'message'), [
    ({'origin_z': 0.0}, "'origin_z' is not a parameter"),
    ({'unknown_threshold': 15}, "'unknown_threshold' is not a parameter"),
    ({'voxel_decay': 15}, 'voxel_decay=15 must be a float'),
    ({'detector_frustum.decay_acceleration': 1000}, 'decay_acceleration=1000 must be a float'),
    ({'detector_obstacles.obstacle_max_range': 3.2}, "'obstacle_max_range' is not a param"),
    ({'detector_frustum.observation_persistence': 0.5}, 'clearing-only source never clears'),
    ({'detector_frustum.model_type': 1}, 'only the depth camera frustum'),
    ({'detector_obstacles.filter': 'voxel'}, 'passthrough or none are ported'),
])
def test_a_key_the_plugin_reads_differently_is_refused(tmp_path: Path, edit: dict,
                                                       message: str) -> None:
    with pytest.raises(nav2.Nav2ConfigError, match=message):
        stvl.read_stvl_costmap(_write(tmp_path, edit))


def test_the_frustum_sides_are_wider_than_the_fov_angle_says() -> None:
    v, h = 1.0, 1.2
    frustum = stvl.DepthCameraFrustum(v, h, 0.5, 3.0)
    side = math.tan(h / 2) / math.cos(v / 2)          # x / z of the side planes
    near, far = (d * math.cos(v / 2) * math.cos(h / 2) for d in (0.5, 3.0))
    z = 1.0

    inside = frustum.is_inside(np.array([
        [(side - 1e-3) * z, 0.0, z], [0.0, (math.tan(v / 2) - 1e-3) * z, z],
        [0.0, 0.0, near + 1e-3], [0.0, 0.0, far - 1e-3]]))
    outside = frustum.is_inside(np.array([
        [(side + 1e-3) * z, 0.0, z], [0.0, (math.tan(v / 2) + 1e-3) * z, z],
        [0.0, 0.0, near - 1e-3], [0.0, 0.0, far + 1e-3], [0.0, 0.0, -1.0]]))

    assert inside.all()
    assert not outside.any()


def test_a_mark_reaches_the_costmap_one_update_later(tmp_path: Path) -> None:
    costmap = _costmap(tmp_path)
    box = np.array([[1.02, 0.32, 0.2]])     # inside a cell and its voxel column

    first = _update(costmap, box, 0.0)
    second = _update(costmap, np.zeros((0, 3)), 0.2)

    assert not _lethal_at(costmap, first, 1.02, 0.32)    # marks come after the costmap is made
    assert _lethal_at(costmap, second, 1.02, 0.32)


def test_voxel_decay_minus_one_drops_a_voxel_before_it_is_ever_shown(tmp_path: Path) -> None:
    costmap = _costmap(tmp_path, {'voxel_decay': -1.0})
    box = np.array([[1.02, 0.32, 0.2]])     # inside a cell and its voxel column

    shown = [_update(costmap, box, k * 0.2) for k in range(4)]

    assert not any(_lethal_at(costmap, m, 1.02, 0.32) for m in shown)


def test_out_of_the_frustum_a_voxel_lives_voxel_decay_seconds(tmp_path: Path) -> None:
    costmap = _costmap(tmp_path, {'voxel_decay': 1.0})
    behind = np.array([[-1.02, 0.32, 0.2]])             # behind the camera

    _update(costmap, behind, 0.0)
    kept = _update(costmap, np.zeros((0, 3)), 0.9)
    gone = _update(costmap, np.zeros((0, 3)), 1.1)

    assert _lethal_at(costmap, kept, -1.02, 0.32)
    assert not _lethal_at(costmap, gone, -1.02, 0.32)


def test_in_the_frustum_a_voxel_not_seen_again_decays_faster(tmp_path: Path) -> None:
    costmap = _costmap(tmp_path)                        # voxel_decay 15 s, acceleration 1000
    ahead = np.array([[1.22, 0.02, 0.3]])

    _update(costmap, ahead, 0.0)
    shown = _update(costmap, np.zeros((0, 3)), 0.2)     # dt 0.2 s: 15 - 0.2 - 1.33 > 0
    gone = _update(costmap, np.zeros((0, 3)), 0.4)      # its time moved back 1.33 s: gone

    assert _lethal_at(costmap, shown, 1.22, 0.02)
    assert not _lethal_at(costmap, gone, 1.22, 0.02)


def test_a_clearing_only_source_with_persistence_never_clears() -> None:
    config = stvl.read_stvl_costmap(STVL_YAML)
    layer = config.layers[0]
    sources = tuple(dataclasses.replace(s, observation_persistence=0.5) if s.clearing else s
                    for s in layer.sources)
    persistent = stvl.STVLCostmap(dataclasses.replace(
        config, layers=(dataclasses.replace(layer, sources=sources),)))
    shipped = stvl.STVLCostmap(config)
    ahead = np.array([[1.22, 0.02, 0.3]])
    now = 1000.0                                        # a clock far from 0, as a node's

    for costmap in (persistent, shipped):
        _update(costmap, ahead, now)
        _update(costmap, np.zeros((0, 3)), now + 0.2)
    kept = _update(persistent, np.zeros((0, 3)), now + 0.4)
    gone = _update(shipped, np.zeros((0, 3)), now + 0.4)

    assert _lethal_at(persistent, kept, 1.22, 0.02)
    assert not _lethal_at(shipped, gone, 1.22, 0.02)


def test_a_clearing_only_source_with_an_expected_rate_is_never_current(tmp_path: Path) -> None:
    costmap = _costmap(tmp_path, {'detector_frustum.expected_update_rate': 0.5})
    steady = _costmap(tmp_path)
    box = np.array([[1.02, 0.32, 0.2]])     # inside a cell and its voxel column

    for k in range(5):
        _update(costmap, box, 0.2 * k)
        _update(steady, box, 0.2 * k)

    assert not costmap.current
    assert steady.current


def test_marking_heights_and_range_filter_the_cloud(tmp_path: Path) -> None:
    costmap = _costmap(tmp_path)
    points = np.array([[1.02, 0.02, 1.5],    # above max_obstacle_height 1.4
                       [1.02, 0.52, -0.8],   # a drop's lower floor: kept
                       [3.02, 1.52, 0.2]])   # 3.39 m from base_footprint > obstacle_range

    _update(costmap, points, 0.0)
    master = _update(costmap, np.zeros((0, 3)), 1.0 / 30)

    assert not _lethal_at(costmap, master, 1.02, 0.02)
    assert _lethal_at(costmap, master, 1.02, 0.52)
    assert not _lethal_at(costmap, master, 3.02, 1.52)



def test_a_mark_takes_each_coordinate_s_own_sign_as_2_5_5_does(tmp_path: Path) -> None:
    # grid operator() in 2.5.5 (release/jazzy/spatio_temporal_voxel_layer/2.5.5-1,
    # src/spatio_temporal_voxel_grid.cpp): "double z = *iter_z < 0 ? *iter_z - _voxel_size";
    # the ros2 branch's head (403d9ed) tests *iter_y there instead, Jazzy does not ship it
    costmap = _costmap(tmp_path)
    points = np.array([[1.02, 0.32, 0.07],     # voxel 0.05-0.10, centre 0.075
                       [1.02, -0.32, 0.07],    # y < 0 leaves z alone: centre 0.075
                       [1.22, 0.32, -0.03]])   # below the floor: voxel -0.05-0, centre -0.025

    _update(costmap, points, 0.0)

    centres = costmap.layers[0].grid.centres()
    by_xy = {(round(x, 3), round(y, 3)): round(z, 3) for x, y, z in centres}
    assert by_xy == {(1.025, 0.325): 0.075, (1.025, -0.325): 0.075, (1.225, 0.325): -0.025}
