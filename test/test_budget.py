"""The frame budget (docs/budget.md): heavy combinations of in-range values are refused.

Issue 31's sets, each value within its own range, are refused with one line naming the
parameters, the estimate and the limits: by the node (at start-up and on a set request, through
DDS, its resident memory read from /proc), by bag_process (params file), evaluate and sweep
(params file, ``--set``); the shipped presets and params files stay accepted.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import ros_env
import yaml

from obstacle_detection.pipeline import params as pipeline_params
from obstacle_detection.pipeline.params import PRESETS, DetectorParams, frame_budget
from obstacle_detection.ros.config import build_config
from obstacle_detection.ros.parameters import ALL_PARAMS, PARAMS_FILE_KEY, read_params_file

REPO = ros_env.REPO_ROOT

#: Issue 31's table: each set alone takes a node down (or near); every value is in its range.
ISSUE_SETS = {
    'costmap': {'costmap_length_m': 50.0, 'costmap_width_m': 50.0,
                'costmap_resolution_m': 0.005},
    'neighbours': {'normal_neighbours': 400, 'validation_neighbours': 400},
    'voxels': {'normal_neighbours': 400, 'validation_neighbours': 400, 'voxel_x_m': 0.001,
               'voxel_y_m': 0.001, 'voxel_z_m': 0.001, 'max_range_m': 20.0},
}
#: The parameters each refusal names (the terms making up most of its estimate).
NAMED = {'costmap': ('costmap_length_m=50.0', 'costmap_width_m=50.0',
                     'costmap_resolution_m=0.005', '100,000,000 costmap cells'),
         'neighbours': ('normal_neighbours=400', 'validation_neighbours=400'),
         'voxels': ('voxel_x_m=0.001', 'voxel_y_m=0.001', 'voxel_z_m=0.001')}


def _node_values(**changes: Any) -> dict[str, Any]:
    values = {spec.name: spec.default for spec in ALL_PARAMS}
    values.update(changes)
    return values


def _assert_refusal_line(text: str, case: str) -> None:
    assert '\n' not in text.strip()
    for part in NAMED[case]:
        assert part in text, (part, text)
    limits = (f'above the limits of {pipeline_params.MAX_FRAME_MS:g} ms and '
              f'{pipeline_params.MAX_FRAME_MIB:g} MiB a frame')
    assert limits in text and 'would make a frame take about' in text


@pytest.mark.parametrize('case', ISSUE_SETS)
def test_the_issue_sets_are_refused_with_the_parameters_the_estimate_and_the_limits(
        case: str) -> None:
    with pytest.raises(ValueError) as caught:
        build_config(_node_values(**ISSUE_SETS[case]))
    _assert_refusal_line(str(caught.value), case)
    # each value alone is within its range: the dataclass takes the same set
    DetectorParams(**{name: value for name, value in ISSUE_SETS[case].items()})


def test_the_estimate_grows_with_each_term_and_the_limit_falls_between() -> None:
    base = DetectorParams()
    small = frame_budget(base)
    assert small.ms < pipeline_params.MAX_FRAME_MS and small.problem() is None
    # each term alone pushes the estimate past a limit, from the defaults
    for changes in ({'costmap_length_m': 50.0, 'costmap_width_m': 50.0,
                     'costmap_resolution_m': 0.01},
                    {'normal_neighbours': 400},
                    {'voxel_x_m': 0.002, 'voxel_y_m': 0.002, 'voxel_z_m': 0.002}):
        big = frame_budget(base.replace(**changes))
        assert big.ms > small.ms and big.problem() is not None, changes
    fused = frame_budget(base, fused_size_m=40.0, fused_resolution_m=0.02)
    assert fused.problem() is not None and 'fused_size_m=40.0' in fused.problem()
    assert frame_budget(base, fused_size_m=4.0, fused_resolution_m=0.05).problem() is None
    many_rays = frame_budget(base, clearing_stride_px=1)
    assert many_rays.mib > frame_budget(base, clearing_stride_px=4).mib


def test_the_parameter_docs_state_the_limits_in_force() -> None:
    doc = (REPO / 'docs' / 'parameters.md').read_text(encoding='utf-8')
    width, height = pipeline_params.BUDGET_FRAME_SIZE
    assert (f'a {width} x {height} frame estimated at most {pipeline_params.MAX_FRAME_MS:g} ms '
            f'and {pipeline_params.MAX_FRAME_MIB:g} MiB') in ' '.join(doc.split())


def _shipped_params_files() -> list[Path]:
    """Return the node's params files (params/nav2_costmap.yaml is Nav2's)."""
    return sorted(path for path in (REPO / 'params').glob('*.yaml')
                  if 'obstacle_detector' in path.read_text(encoding='utf-8'))


def test_the_presets_and_the_shipped_params_files_are_accepted() -> None:
    for name, preset in PRESETS.items():
        assert frame_budget(preset()).problem() is None, name
    assert _shipped_params_files()
    for path in _shipped_params_files():
        values = _node_values(**read_params_file(path))
        build_config(values)   # raises with the reason if refused
        for switch in ('fuse', 'publish_ground', 'publish_overlay'):   # a robot switches on
            build_config(dict(values, **{switch: True}))


def test_every_set_and_sweep_axis_the_docs_show_is_accepted_on_every_preset() -> None:
    from obstacle_detection.evaluation import runner as evaluation
    from obstacle_detection.evaluation import sweep as grid_search

    text = '\n'.join(path.read_text(encoding='utf-8')
                     for path in [REPO / 'README.md', *sorted((REPO / 'docs').glob('*.md'))])
    sets = [match.split('=', 1) for match in re.findall(r'--set (\w+=-?[0-9][0-9.e]*)', text)]
    axes = [grid_search.parse_axis(match)
            for match in re.findall(r'--[xy] (\w+=-?[0-9][-0-9.e,]*)', text)]
    assert sets and axes
    changes = [{key: value} for key, value in sets]
    changes += [{axis.name: value} for axis in axes for value in axis.values]
    for preset in PRESETS.values():
        for change in changes:
            params = evaluation.apply_overrides(preset(), change)
            assert frame_budget(params).problem() is None, change


def _params_file(tmp_path: Path, values: dict[str, Any]) -> Path:
    path = tmp_path / 'heavy.yaml'
    path.write_text(yaml.safe_dump({PARAMS_FILE_KEY: {'ros__parameters': values}}))
    return path


@pytest.mark.parametrize('case', ISSUE_SETS)
def test_bag_process_refuses_a_params_file_beyond_the_budget(
        tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    from obstacle_detection.tools import bag_process

    path = _params_file(tmp_path, ISSUE_SETS[case])
    (tmp_path / 'in').mkdir()
    code = bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--params-file',
                             str(path)])
    err = capsys.readouterr().err
    assert code == 1
    assert err.startswith(f'error: {path}: ')
    _assert_refusal_line(err, case)
    assert not (tmp_path / 'out').exists()


@pytest.mark.parametrize('case', ISSUE_SETS)
def test_evaluate_and_sweep_refuse_a_params_file_or_set_beyond_the_budget(
        tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    from obstacle_detection.tools import evaluate, sweep

    path = _params_file(tmp_path, ISSUE_SETS[case])
    sets = [arg for name, value in ISSUE_SETS[case].items()
            for arg in ('--set', f'{name}={value}')]
    common = ['--scene', 'corridor', '--max-frames', '1']
    for tool, axis in ((evaluate, []), (sweep, ['--x', 'theta_deg=20,30'])):
        assert tool.main([*common, *axis, '--params-file', str(path)]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f'error: {path}: ')
        _assert_refusal_line(err, case)
        assert tool.main([*common, *axis, *sets]) == 2
        err = capsys.readouterr().err
        assert 'error: argument --set: ' in err
        _assert_refusal_line(err, case)


def test_a_sweep_leaves_a_setting_beyond_the_budget_out_with_the_reason() -> None:
    from obstacle_detection.evaluation import runner as evaluation
    from obstacle_detection.evaluation import sweep as grid_search

    scenario = evaluation.Scenario('corridor', 'corridor', seeds=(0,))
    frames = list(evaluation.scenario_frames(scenario, size=(128, 106)))
    scored: list[int] = []

    def score(points: list[DetectorParams]) -> list[list[Any]]:
        scored.extend(p.normal_neighbours for p in points)
        return [evaluation.evaluate_frames(frames, p).frames for p in points]

    logged: list[str] = []
    result = grid_search.grid_sweep(score, DetectorParams(),
                                    grid_search.parse_axis('N=10,400'), None, log=logged.append)
    assert scored == [10]   # 400 never ran
    assert np.isnan(result.grids['overall'][0, 1]) and np.isfinite(result.grids['overall'][0, 0])
    (refused,) = [line for line in logged if 'invalid' in line]
    assert refused.startswith('N=400: invalid (normal_neighbours=400')
    assert 'above the limits of' in refused


# -- the node, through DDS ---------------------------------------------------------------------
def _rss_mib(pid: int, key: str = 'VmRSS') -> float:
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith(key + ':'):
            return int(line.split()[1]) / 1024.0
    raise KeyError(key)


class _Node(ros_env.NodeProcess):
    """The node as a process with the shipped defaults; the probe plays the camera."""

    def __init__(self, tmp: Path, args: list[str]) -> None:
        from nav_msgs.msg import OccupancyGrid
        from rcl_interfaces.srv import GetParameters, SetParametersAtomically
        from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
        from sensor_msgs.msg import CameraInfo, Image

        from obstacle_detection.sim.scenes import render_scene

        super().__init__(tmp, __name__, 'budget_probe')
        self.scene = render_scene('corridor', seed=1)
        self.info_pub = self.node.create_publisher(CameraInfo, 'depth/camera_info',
                                                   qos_profile_sensor_data)
        self.depth_pub = self.node.create_publisher(Image, 'depth/image_raw',
                                                    qos_profile_sensor_data)
        self.by_stamp('costmap', OccupancyGrid, 'obstacles/costmap',
                      QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
        self.set_client = self.node.create_client(
            SetParametersAtomically, 'obstacle_detector/set_parameters_atomically')
        self.get_client = self.node.create_client(GetParameters,
                                                  'obstacle_detector/get_parameters')
        self.start(args)

    def frame(self) -> Any:
        """Send the scene's depth and CameraInfo; return the costmap that answers it."""
        from obstacle_detection.ros.conversions import array_to_image, \
            intrinsics_to_camera_info

        height, width = self.scene.depth_mm.shape
        for _ in range(4):   # best effort: a frame may be lost
            stamp = self.next_stamp()
            self.info_pub.publish(intrinsics_to_camera_info(
                self.scene.intrinsics, width, height, stamp=stamp, frame_id='depth_optical'))
            self.depth_pub.publish(array_to_image(self.scene.depth_mm, stamp=stamp,
                                                  frame_id='depth_optical'))
            key = ros_env.stamp_key(stamp)
            if self.spin_until(lambda: key in self.received['costmap'], 30.0):
                return self.received['costmap'][key]
        pytest.fail('no costmap for a frame:\n' + self.log())

    def set(self, values: dict[str, Any]) -> Any:
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.parameter import Parameter

        request = SetParametersAtomically.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()])
        return self.call(self.set_client, request).result

    def get(self, names: list[str]) -> list[Any]:
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        reply = self.call(self.get_client, GetParameters.Request(names=names))
        return [parameter_value_to_python(value) for value in reply.values]


@pytest.fixture(scope='module')
def node(tmp_path_factory: pytest.TempPathFactory) -> Any:
    tmp = tmp_path_factory.mktemp('budget')
    harness = _Node(tmp, ['--ros-args', '-p', 'stats_period_s:=0.0'])
    try:
        assert harness.spin_until(lambda: 'ready:' in harness.log(), 90.0), harness.log()
        assert harness.spin_until(lambda: harness.depth_pub.get_subscription_count() > 0,
                                  90.0), harness.log()
        yield harness
    finally:
        harness.close()


def test_the_node_refuses_each_issue_set_and_answers_the_next_frame_light(node: _Node) -> None:
    node.frame()
    for case, values in ISSUE_SETS.items():
        reply = node.set(values)
        assert not reply.successful, case
        _assert_refusal_line(reply.reason, case)
        assert node.get(list(values)) == [_node_values()[name] for name in values]  # none
        node.frame()
        assert _rss_mib(node.process.pid, 'VmHWM') < 1536.0, case   # peak of the process


def test_an_accepted_heavy_set_gives_its_memory_back_when_restored(node: _Node) -> None:
    # a large costmap within the budget (fusion is switched at start-up only)
    heavy = {'costmap_length_m': 15.0, 'costmap_width_m': 15.0, 'costmap_resolution_m': 0.01}
    assert frame_budget(DetectorParams(**heavy)).problem() is None
    node.frame()
    before = _rss_mib(node.process.pid)
    assert node.set(heavy).successful
    grid = node.frame()
    assert (grid.info.width, grid.info.height) == (1500, 1500)
    node.frame()
    assert node.set({name: _node_values()[name] for name in heavy}).successful
    grid = node.frame()
    assert (grid.info.width, grid.info.height) == (40, 80)
    assert _rss_mib(node.process.pid) < before + 200.0
    assert _rss_mib(node.process.pid, 'VmHWM') < 1536.0


def test_the_node_refuses_to_start_with_a_set_beyond_the_budget(tmp_path: Path) -> None:
    path = _params_file(tmp_path, ISSUE_SETS['costmap'])
    done = ros_env.run_detector(tmp_path, '--ros-args', '--params-file', str(path),
                                salt='budget_start')
    assert done.returncode == 1
    (line,) = [line for line in (done.stdout + done.stderr).splitlines()
               if 'invalid parameters' in line]
    _assert_refusal_line(line, 'costmap')

