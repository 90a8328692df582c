"""Tests of the parameter checks the node and the tools share (ros_params)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from obstacle_detection.pipeline.params import DetectorParams
from obstacle_detection.ros import RosInputError
from obstacle_detection.ros.parameters import (
    FRAME_VOXELS_BOUND,
    MAX_COSTMAP_CELLS,
    MAX_NEIGHBOUR_ENTRIES,
    budget_problem,
    detector_params_from_ros,
    params_file_reason,
    pipeline_params_to_ros,
    read_params_file,
)


def _values(**changes: Any) -> dict[str, Any]:
    values = pipeline_params_to_ros(DetectorParams())
    values.update(changes)
    return values


def test_the_defaults_are_within_every_limit() -> None:
    assert budget_problem(_values()) is None
    assert budget_problem(_values(stats_period_s=0.0)) is None       # 0 = statistics off


@pytest.mark.parametrize('changes, message', [
    ({'max_slope_deg': 90.0}, 'max_slope_deg=90.0 out of range: must be in (0, 90) [deg]'),
    ({'camera_roll_deg': -90.0},
     'camera_roll_deg=-90.0 out of range: must be in (-90, 90) [deg]'),
    ({'voxel_x_m': 0.0}, 'voxel_x_m=0.0 out of range: must be in [0.001, 1]'),
])
def test_refusals_name_the_parameter_as_the_user_wrote_it(changes: dict[str, Any],
                                                          message: str) -> None:
    with pytest.raises(ValueError) as caught:
        detector_params_from_ros(_values(**changes))
    assert str(caught.value) == message
    assert '_rad' not in str(caught.value)


def test_costmap_cells_are_limited_on_the_combination() -> None:
    # 50 m x 50 m at 5 mm: 10^8 cells; each value alone is within its range.
    problem = budget_problem(_values(costmap_length_m=50.0, costmap_width_m=50.0,
                                     costmap_resolution_m=0.005))
    assert problem is not None and '100,000,000 cells' in problem
    side = 2000 * 0.01   # exactly the limit: 2000 x 2000 cells of 1 cm
    assert 2000 * 2000 == MAX_COSTMAP_CELLS
    assert budget_problem(_values(costmap_length_m=side, costmap_width_m=side,
                                  costmap_resolution_m=0.01)) is None


def test_neighbour_work_is_limited_by_neighbours_times_voxels() -> None:
    many = _values(normal_neighbours=400, validation_neighbours=400)
    problem = budget_problem(many)
    assert problem is not None and '401 neighbours' in problem
    # The same neighbour count over 10 cm voxels: 2 x 4 x 1.5 m / 1e-3 m^3 = 12,000 cells.
    coarse = dict(many, voxel_x_m=0.1, voxel_y_m=0.1, voxel_z_m=0.1)
    assert 401 * 12_000 <= MAX_NEIGHBOUR_ENTRIES and budget_problem(coarse) is None
    k_max = MAX_NEIGHBOUR_ENTRIES // FRAME_VOXELS_BOUND      # 64 at the default voxels
    assert budget_problem(_values(normal_neighbours=k_max,
                                  validation_neighbours=k_max - 1)) is None
    assert budget_problem(_values(normal_neighbours=k_max + 1)) is not None


def test_millimetre_voxels_over_a_long_range_are_refused() -> None:
    problem = budget_problem(_values(voxel_x_m=0.001, voxel_y_m=0.001, voxel_z_m=0.001,
                                     max_range_m=20.0))
    assert problem is not None and 'voxel cells' in problem


def test_a_log_line_every_microsecond_is_refused() -> None:
    problem = budget_problem(_values(stats_period_s=1e-6))
    assert problem is not None and 'stats_period_s=1e-06' in problem


@pytest.mark.parametrize('key', ['/**/obstacle_detector', 'obstacle_detector', '/**'])
def test_the_tools_read_a_section_that_names_the_node(tmp_path: Path, key: str) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text(f'{key}:\n  ros__parameters:\n    median_kernel: 5\n'
                    '    use_sim_time: true\n')

    assert read_params_file(path) == {'median_kernel': 5}    # rclpy's use_sim_time: skipped


def test_sections_apply_in_file_order_as_rclpy_applies_them(tmp_path: Path) -> None:
    # rclpy 7.1 (Jazzy) gives a node every section naming it in file order, the later value
    # replacing the earlier, wildcard or not (test_node_plumbing checks it against a node)
    path = tmp_path / 'p.yaml'
    path.write_text('obstacle_detector:\n  ros__parameters:\n    median_kernel: 7\n'
                    '/**:\n  ros__parameters:\n    median_kernel: 5\n    max_range_m: 3.0\n')

    assert read_params_file(path) == {'median_kernel': 5, 'max_range_m': 3.0}


def test_a_file_for_another_node_is_refused_by_the_tools(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/robot/obstacle_detector:\n  ros__parameters:\n    median_kernel: 5\n')

    with pytest.raises(RosInputError, match='no section naming the node'):
        read_params_file(path)


def test_every_kind_of_section_applies_in_file_order(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/**:\n  ros__parameters:\n    median_kernel: 5\n    max_range_m: 3.0\n'
                    '    lateral_limit_m: 1.0\n'
                    '/**/obstacle_detector:\n  ros__parameters:\n    median_kernel: 9\n'
                    '    max_range_m: 2.5\n'
                    'obstacle_detector:\n  ros__parameters:\n    median_kernel: 7\n')

    assert read_params_file(path) == {'median_kernel': 7, 'max_range_m': 2.5,
                                      'lateral_limit_m': 1.0}


def test_a_typo_is_refused_by_the_tools_with_the_nearest_name(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/**/obstacle_detector:\n  ros__parameters:\n    max_rnge_m: 3.0\n')

    with pytest.raises(RosInputError, match="'max_rnge_m' .*did you mean 'max_range_m'"):
        read_params_file(path)


def test_an_integer_for_a_float_says_how_to_write_it(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/**/obstacle_detector:\n  ros__parameters:\n    max_range_m: 3\n')

    with pytest.raises(RosInputError, match=r"'max_range_m' must be a float, got 3: write 3\.0"):
        read_params_file(path)


def test_a_refused_start_names_the_file_and_the_value(tmp_path: Path) -> None:
    good, bad = tmp_path / 'good.yaml', tmp_path / 'bad.yaml'
    good.write_text('/**/obstacle_detector:\n  ros__parameters:\n    max_range_m: 3.0\n'
                    '    no_such_thing: 1\n')   # unknown names are warned about, not the cause
    bad.write_text('/**/obstacle_detector:\n  ros__parameters:\n    max_range_m: 0.0\n')

    assert params_file_reason([str(good)]) is None
    reason = params_file_reason([str(good), str(bad)])
    assert reason == f'{bad}: max_range_m=0.0 out of range: must be in (0, 20]'
