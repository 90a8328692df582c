"""Tests of the parameter checks the node and the tools share (ros_params)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from obstacle_detection.pipeline.params import DetectorParams
from obstacle_detection.ros import RosInputError
from obstacle_detection.ros.parameters import (
    check_params_file,
    detector_params_from_ros,
    params_file_problems,
    pipeline_params_to_ros,
    read_params_file,
)


def _values(**changes: Any) -> dict[str, Any]:
    values = pipeline_params_to_ros(DetectorParams())
    values.update(changes)
    return values


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


def test_a_typo_is_ignored_by_the_tools_as_by_the_node(tmp_path: Path) -> None:
    # One behaviour for node and tools: a name the node does not declare is ignored with a
    # did-you-mean warning (params_file_problems), as ROS ignores undeclared overrides: a
    # robot's params file shared by many nodes under "/**:" must not stop this one.
    path = tmp_path / 'p.yaml'
    path.write_text('/**/obstacle_detector:\n  ros__parameters:\n    max_rnge_m: 3.0\n'
                    '    median_kernel: 5\n')

    assert read_params_file(path) == {'median_kernel': 5}
    assert params_file_problems(path) == [
        f"{path}: unknown parameter 'max_rnge_m' is ignored (did you mean 'max_range_m'?); "
        '`detector --help` lists the parameters']


def test_an_integer_for_a_float_says_how_to_write_it(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/**/obstacle_detector:\n  ros__parameters:\n    max_range_m: 3\n')

    with pytest.raises(RosInputError, match=r"'max_range_m' must be a float, got 3: write 3\.0"):
        read_params_file(path)


def test_the_node_checks_an_integer_for_a_float_as_the_tools_do(tmp_path: Path) -> None:
    # the node's start-up check (ros.node.main) and the tools' reading say the same line
    path = tmp_path / 'p.yaml'
    path.write_text('obstacle_detector:\n  ros__parameters:\n    max_range_m: 3\n')
    with pytest.raises(RosInputError) as node_side:
        check_params_file(path)
    with pytest.raises(RosInputError) as tool_side:
        read_params_file(path)
    assert str(node_side.value) == str(tool_side.value) == (
        f"{path}: parameter 'max_range_m' must be a float, got 3: write 3.0")
