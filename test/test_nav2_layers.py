"""The Nav2 layer port of test/nav2_layers.py on tiny geometry whose answer is known.

Grids of 1 m x 1 m at 0.1 m cells, voxels of 0.1 m from z = 0 (cell (i, j, k) spans
[0.1 i, 0.1 i + 0.1) in x, and so on), a sensor at the centre of a cell: each test says which
cells and voxels a ray or a mark must touch.
"""

from __future__ import annotations

from pathlib import Path

import nav2_layers as nav2
import numpy as np
import pytest

RES = 0.1
#: The sensor: the centre of cell (0, 5), voxel 5.
SENSOR = np.array([0.05, 0.55, 0.55])


def _costmap(**layer: object) -> tuple[nav2.CostmapConfig, nav2.LayerConfig]:
    source = nav2.SourceConfig(
        name='cloud', topic='/cloud', sensor_frame='', marking=True, clearing=True,
        min_obstacle_height=-1.0, max_obstacle_height=3.0, obstacle_max_range=5.0,
        obstacle_min_range=0.0, raytrace_max_range=5.0, raytrace_min_range=0.0,
        observation_persistence=0.0, expected_update_rate=0.0, data_type='PointCloud2')
    settings = dict(z_voxels=10, origin_z=0.0, z_resolution=RES, max_obstacle_height=0.95,
                    min_obstacle_height=-1.0, footprint_clearing_enabled=False)
    settings.update(layer)
    config = nav2.LayerConfig(name='voxel_layer', plugin=nav2.VOXEL_PLUGIN, sources=(source,),
                              **settings)
    costmap = nav2.CostmapConfig(
        global_frame='odom', robot_base_frame='base', rolling_window=False, width_m=1.0,
        height_m=1.0, resolution_m=RES, robot_radius_m=0.1, track_unknown_space=False,
        update_frequency_hz=5.0, layers=(config,))
    return costmap, config


def _observation(points: list[tuple[float, float, float]], config: nav2.LayerConfig,
                 origin: np.ndarray = SENSOR) -> nav2.Observation:
    """Points given in the global frame, seen from ``origin``."""
    return nav2.buffer_cloud(np.array(points, dtype=np.float64), np.eye(3), np.zeros(3),
                             config.sources[0], sensor_origin=origin)


def _voxel_layer(**layer: object) -> nav2.VoxelLayer:
    costmap, config = _costmap(**layer)
    return nav2.VoxelLayer(config, costmap)


def _column(x: float, y: float, zs: list[float]) -> list[tuple[float, float, float]]:
    return [(x, y, z) for z in zs]


def _bresenham_reference(x0: int, y0: int, x1: int, y1: int, steps: int) -> list[tuple]:
    """Costmap2D::bresenham2D as written upstream, one cell at a time (the slow reference)."""
    dx, dy = x1 - x0, y1 - y0
    sx, sy = (1 if dx > 0 else -1), (1 if dy > 0 else -1)
    if abs(dx) >= abs(dy):
        da, db, step_a, step_b = abs(dx), abs(dy), (sx, 0), (0, sy)
    else:
        da, db, step_a, step_b = abs(dy), abs(dx), (0, sy), (sx, 0)
    error, x, y, cells = da // 2, x0, y0, []
    for _ in range(min(steps, da)):
        cells.append((x, y))
        x, y = x + step_a[0], y + step_a[1]
        error += db
        if error >= da:
            x, y = x + step_b[0], y + step_b[1]
            error -= da
    cells.append((x, y))
    return cells


# ------------------------------------------------------------------------------------------
# Bresenham


def test_bresenham_walks_a_shallow_line_cell_by_cell() -> None:
    rays, cells = nav2.bresenham_cells(np.array([[0, 0]]), np.array([[3, 1]]), np.array([3]))

    assert sorted(map(tuple, cells.tolist())) == [(0, 0), (1, 0), (2, 1), (3, 1)]
    assert set(rays.tolist()) == {0}


def test_bresenham_of_many_rays_matches_the_one_cell_at_a_time_reference() -> None:
    rng = np.random.default_rng(7)
    start = rng.integers(0, 40, size=(300, 2))
    end = rng.integers(0, 40, size=(300, 2))
    steps = np.minimum(rng.integers(0, 60, size=300), np.abs(end - start).max(axis=1))

    rays, cells = nav2.bresenham_cells(start, end - start, steps)

    for i in range(300):
        got = sorted(map(tuple, cells[rays == i].tolist()))
        want = sorted(_bresenham_reference(*start[i], *end[i], int(steps[i])))
        assert got == want, i


def _bresenham3d_reference(start: np.ndarray, delta: np.ndarray, steps: int) -> list[tuple]:
    """VoxelGrid::bresenham3D as written upstream, one cell at a time (the slow reference)."""
    size = [abs(int(d)) for d in delta]
    sign = [1 if d > 0 else -1 for d in delta]
    a = 0 if size[0] >= max(size[1], size[2]) else (1 if size[1] >= size[2] else 2)
    others = [k for k in range(3) if k != a]
    error = {k: size[a] // 2 for k in others}
    pos, cells = [int(v) for v in start], []
    for _ in range(min(steps, size[a])):
        cells.append(tuple(pos))
        pos[a] += sign[a]
        for k in others:
            error[k] += size[k]
            if error[k] >= size[a]:
                pos[k] += sign[k]
                error[k] -= size[a]
    cells.append(tuple(pos))
    return cells


def test_bresenham_in_3d_matches_the_one_cell_at_a_time_reference() -> None:
    rng = np.random.default_rng(8)
    start = rng.integers(0, 16, size=(300, 3))
    delta = rng.integers(0, 16, size=(300, 3)) - start
    steps = np.minimum(rng.integers(0, 20, size=300), np.abs(delta).max(axis=1))

    rays, cells = nav2.bresenham_cells(start, delta, steps)

    for i in range(300):
        got = sorted(map(tuple, cells[rays == i].tolist()))
        assert got == sorted(_bresenham3d_reference(start[i], delta[i], int(steps[i]))), i


def test_bresenham_in_3d_follows_the_dominant_axis() -> None:
    _, cells = nav2.bresenham_cells(np.array([[0, 0, 5]]), np.array([[0, 0, -4]]),
                                    np.array([4]))

    assert sorted(map(tuple, cells.tolist())) == [(0, 0, z) for z in range(1, 6)]


# ------------------------------------------------------------------------------------------
# Observation buffer and marking


def test_observation_buffer_keeps_the_source_height_band_only() -> None:
    _, config = _costmap()
    source = config.sources[0]
    points = np.array([[0.5, 0.5, -1.5], [0.5, 0.5, 0.2], [0.5, 0.5, 3.5]])

    obs = nav2.buffer_cloud(points, np.eye(3), np.array([1.0, 2.0, 0.0]), source)

    np.testing.assert_allclose(obs.points, [[1.5, 2.5, 0.2]])
    np.testing.assert_allclose(obs.origin, [1.0, 2.0, 0.0])


def test_a_mark_sets_one_voxel_and_makes_its_cell_lethal() -> None:
    layer = _voxel_layer()

    layer.mark(_observation([(0.55, 0.35, 0.25)], layer.layer))

    assert np.argwhere(layer.marked_voxels()).tolist() == [[3, 5, 2]]   # (y, x, z)
    assert np.argwhere(layer.costmap == nav2.LETHAL_OBSTACLE).tolist() == [[3, 5]]


def test_marks_above_the_layer_height_are_dropped_and_below_the_grid_go_to_voxel_0() -> None:
    layer = _voxel_layer()

    layer.mark(_observation([(0.55, 0.35, 0.99), (0.25, 0.35, -0.4)], layer.layer))

    assert np.argwhere(layer.marked_voxels()).tolist() == [[3, 2, 0]]


def test_mark_threshold_needs_more_marked_voxels_in_a_column() -> None:
    layer = _voxel_layer(mark_threshold=1)

    layer.mark(_observation([(0.55, 0.35, 0.25)], layer.layer))
    once = layer.costmap[3, 5]
    layer.mark(_observation([(0.55, 0.35, 0.45)], layer.layer))

    assert (once, layer.costmap[3, 5]) == (nav2.FREE_SPACE, nav2.LETHAL_OBSTACLE)


# ------------------------------------------------------------------------------------------
# 3-D clearing against 2-D clearing


def test_a_3d_ray_clears_exactly_the_voxels_it_crosses() -> None:
    layer = _voxel_layer()
    layer.mark(_observation(_column(0.55, 0.55, [0.05, 0.25, 0.55, 0.85]), layer.layer))

    # a level ray at z = 0.55 to x = 0.95: its end moves 0.2 m back, to cell 7
    layer.raytrace_freespace(_observation([(0.95, 0.55, 0.55)], layer.layer))

    assert np.flatnonzero(layer.marked_voxels()[5, 5]).tolist() == [0, 2, 8]
    assert layer.costmap[5, 5] == nav2.LETHAL_OBSTACLE


def test_a_cell_is_freed_when_its_last_marked_voxel_is_cleared() -> None:
    layer = _voxel_layer()
    layer.mark(_observation([(0.55, 0.55, 0.55)], layer.layer))

    layer.raytrace_freespace(_observation([(0.95, 0.55, 0.55)], layer.layer))

    assert not layer.marked_voxels().any()
    assert layer.costmap[5, 5] == nav2.FREE_SPACE


def test_a_ray_stops_two_cells_short_of_its_end_point() -> None:
    layer = _voxel_layer()
    layer.mark(_observation([(0.85, 0.55, 0.55)], layer.layer))

    layer.raytrace_freespace(_observation([(0.95, 0.55, 0.55)], layer.layer))

    assert layer.costmap[5, 8] == nav2.LETHAL_OBSTACLE


def test_a_ray_over_a_low_box_keeps_it_in_3d_and_erases_it_in_2d() -> None:
    costmap, config = _costmap()
    voxel = nav2.VoxelLayer(config, costmap)
    flat = nav2.ObstacleLayer(config, costmap)
    box = _column(0.55, 0.55, [0.05, 0.15])
    ray_over = [(0.95, 0.55, 0.55)]
    for layer in (voxel, flat):
        layer.mark(_observation(box, config))
        layer.raytrace_freespace(_observation(ray_over, config))

    assert voxel.costmap[5, 5] == nav2.LETHAL_OBSTACLE
    assert flat.costmap[5, 5] == nav2.FREE_SPACE


def test_rays_above_the_grid_are_cut_at_its_top_and_still_clear_below() -> None:
    layer = _voxel_layer()
    zs = [0.05 + 0.1 * k for k in range(10)]
    layer.mark(_observation([p for i in range(1, 9) for p in _column(0.05 + 0.1 * i, 0.55, zs)],
                            layer.layer))

    # rising from z = 0.55 to 1.95 over x 0.05 -> 0.95: shortened by 0.2 m it would end at
    # x = 0.83 (cell 8); cut at the grid's top (0.95 - 0.01 m) it ends at x = 0.301 (cell 3)
    layer.raytrace_freespace(_observation([(0.95, 0.55, 1.95)], layer.layer))

    full = layer.marked_voxels()[5].sum(axis=1)      # marked voxels per column x
    assert (full[1:4] < 10).all()
    assert full[4:9].tolist() == [10] * 5


def test_a_cleared_column_with_many_unknown_voxels_is_no_information() -> None:
    layer = _voxel_layer(unknown_threshold=0)
    layer.mark(_observation([(0.55, 0.55, 0.55)], layer.layer))

    layer.raytrace_freespace(_observation([(0.95, 0.55, 0.55)], layer.layer))

    assert layer.costmap[5, 5] == nav2.NO_INFORMATION


# ------------------------------------------------------------------------------------------
# Rolling window and combination


def test_the_rolling_window_keeps_marks_in_place_and_forgets_what_leaves_it() -> None:
    costmap, config = _costmap()
    costmap = nav2.CostmapConfig(**{**costmap.__dict__, 'rolling_window': True})
    layer = nav2.VoxelLayer(config, costmap)
    layer.update((0.5, 0.5, 0.0), [_observation([(0.75, 0.55, 0.25)], config,
                                                 np.array([0.5, 0.5, 0.5]))], [])
    origin = layer.origin_xy_m
    marked = np.argwhere(layer.costmap == nav2.LETHAL_OBSTACLE).tolist()

    layer.update((0.8, 0.5, 0.0), [], [])      # three cells to +x: the mark moves to -x
    moved = np.argwhere(layer.costmap == nav2.LETHAL_OBSTACLE).tolist()
    layer.update((1.4, 0.5, 0.0), [], [])

    assert origin == pytest.approx((0.0, 0.0))   # int((0.5 - 0.475) / 0.1) = 0 cells
    assert [[row, col - 3] for row, col in marked] == moved
    assert not (layer.costmap == nav2.LETHAL_OBSTACLE).any()
    assert not layer.marked_voxels().any()


def test_the_master_grid_keeps_free_where_the_layer_has_no_information() -> None:
    costmap, config = _costmap()
    layer = nav2.VoxelLayer(config, costmap)
    layer.costmap[0, 0] = nav2.NO_INFORMATION
    layer.costmap[1, 1] = nav2.LETHAL_OBSTACLE

    master = nav2.LayeredCostmap(costmap, [layer]).update((0.5, 0.5, 0.0), {})

    assert master[0, 0] == nav2.FREE_SPACE and master[1, 1] == nav2.LETHAL_OBSTACLE


def test_footprint_clearing_frees_the_robots_own_cells() -> None:
    costmap, config = _costmap(footprint_clearing_enabled=True)
    layer = nav2.VoxelLayer(config, costmap)
    layer.costmap[:] = nav2.LETHAL_OBSTACLE

    layer.update((0.5, 0.5, 0.0), [], [])

    assert np.argwhere(layer.costmap == nav2.FREE_SPACE).tolist() == [[4, 4], [4, 5], [5, 4],
                                                                      [5, 5]]


# ------------------------------------------------------------------------------------------
# Reading a Nav2 params file


def _write(tmp_path: Path, layer_extra: str = '', source_extra: str = '') -> Path:
    path = tmp_path / 'nav2.yaml'
    path.write_text(f"""
local_costmap:
  local_costmap:
    ros__parameters:
      global_frame: odom
      robot_base_frame: base_footprint
      rolling_window: true
      width: 3
      height: 3
      resolution: 0.05
      plugins: ["voxel_layer"]
      voxel_layer:
        plugin: "nav2_costmap_2d::VoxelLayer"
        z_voxels: 8{layer_extra}
        observation_sources: cloud
        cloud:
          topic: /points
          data_type: "PointCloud2"{source_extra}
""", encoding='utf-8')
    return path


def test_read_costmap_takes_nav2s_defaults_for_what_is_not_given(tmp_path: Path) -> None:
    config = nav2.read_costmap(_write(tmp_path))
    layer = config.layers[0]

    assert (layer.z_voxels, layer.z_resolution, layer.max_obstacle_height) == (8, 0.2, 2.0)
    source = layer.sources[0]
    assert (source.topic, source.max_obstacle_height, source.raytrace_max_range) == (
        '/points', 0.0, 3.0)


@pytest.mark.parametrize(('layer_extra', 'source_extra', 'message'), [
    ('\n        z_resolutoin: 0.1', '', "'z_resolutoin' is not a parameter"),
    ('', '\n          raytrace_range: 3.0', "'raytrace_range' is not a parameter"),
    ('\n        origin_z: 0', '', 'origin_z=0 must be a float'),
])
def test_read_costmap_refuses_what_nav2_would_not_read(tmp_path: Path, layer_extra: str,
                                                        source_extra: str, message: str) -> None:
    with pytest.raises(nav2.Nav2ConfigError, match=message):
        nav2.read_costmap(_write(tmp_path, layer_extra, source_extra))


def test_the_shipped_example_uses_only_names_nav2_jazzy_reads() -> None:
    config = nav2.read_costmap(Path(__file__).resolve().parents[1] / 'params'
                               / 'nav2_costmap.yaml')

    assert [layer.plugin for layer in config.layers] == [nav2.VOXEL_PLUGIN]
    assert {s.topic for s in config.layers[0].sources} == {'/obstacles/marking_points',
                                                          '/obstacles/clearing_points'}
