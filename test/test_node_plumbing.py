"""How the node meets a ROS system: namespace, QoS pairings, endpoints, diagnostics names.

The first tests run the node once as a process through DDS (loopback, a domain of its own),
in the namespace ``/x`` with ``params/corridor.yaml`` and fusion on, as a robot starts it:
depth frames and their CameraInfo come best effort (sensor data), odometry best effort then
reliable; a display that joins late subscribes to the grids reliable + transient local, as
RViz's map display does. The last tests build the node in-process (two namespaces, the launch
file's settings, RVL frames).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
import ros_env
import yaml
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import OccupancyGrid, Odometry
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter, parameter_dict_from_yaml_file, parameter_value_to_python
from rclpy.qos import (DurabilityPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)
from rvl_encoder import rvl_message
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from obstacle_detection.pipeline.params import table_4_2
from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info
from obstacle_detection.ros.node import DetectorNode
from obstacle_detection.ros.parameters import (ALL_PARAMS, PARAMS_FILE_KEY, params_file_problems,
                                               read_params_file)
from obstacle_detection.sim.scenes import SceneFrame, render_scene

#: Starts processes or a DDS graph: deselect with -m "not integration" (README, tests).
pytestmark = pytest.mark.integration

REPO = ros_env.REPO_ROOT
CORRIDOR_YAML = REPO / 'params' / 'corridor.yaml'
NAMESPACE = '/x'
NODE = f'{NAMESPACE}/obstacle_detector'
#: What the process gets besides the params file (the file's values must survive them).
OVERRIDES = {'fuse': True, 'fused_size_m': 6.0, 'publish_ground': False,
             'publish_overlay': False}
START_TIMEOUT_S = 90.0
REPLY_TIMEOUT_S = 30.0
RELIABLE = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
BEST_EFFORT = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)


def _yaml_values(path: Path) -> dict[str, Any]:
    parsed = parameter_dict_from_yaml_file(str(path), target_nodes=[PARAMS_FILE_KEY])
    return {name: parameter_value_to_python(msg.value) for name, msg in parsed.items()}


@pytest.fixture(scope='module')
def scene() -> SceneFrame:
    params = table_4_2()
    return render_scene('corridor', seed=3, height_m=params.camera_height_m,
                        pitch_rad=params.camera_pitch_rad, roll_rad=params.camera_roll_rad)


def _camera_info(frame: SceneFrame, stamp: Time = Time()) -> CameraInfo:
    height, width = frame.depth_mm.shape
    return intrinsics_to_camera_info(frame.intrinsics, width, height, stamp=stamp,
                                     frame_id='depth_optical')


class Graph(ros_env.NodeProcess):
    """The node process in /x, and a probe node that plays camera, odometry and display."""

    def __init__(self, tmp: Path, scene: SceneFrame) -> None:
        super().__init__(tmp, __name__, 'plumbing_probe')
        self.scene = scene
        self.info_pub = self.node.create_publisher(
            CameraInfo, f'{NAMESPACE}/depth/camera_info', qos_profile_sensor_data)
        self.depth_pub = self.node.create_publisher(Image, f'{NAMESPACE}/depth/image_raw',
                                                    qos_profile_sensor_data)
        for key, msg_type in (('points', PointCloud2), ('costmap', OccupancyGrid),
                              ('fused_costmap', OccupancyGrid)):
            self.by_stamp(key, msg_type, f'{NAMESPACE}/obstacles/{key}', RELIABLE)
        self.reports: list[Any] = []
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      lambda msg: self.reports.extend(msg.status), RELIABLE)
        self.get_client = self.node.create_client(GetParameters, f'{NODE}/get_parameters')
        self.set_client = self.node.create_client(SetParameters, f'{NODE}/set_parameters')
        args = ['--ros-args', '-r', f'__ns:={NAMESPACE}', '--params-file', str(CORRIDOR_YAML)]
        for name, value in OVERRIDES.items():
            args += ['-p', f'{name}:={str(value).lower()}']
        self.start(args)

    def call(self, client: Any, request: Any) -> Any:
        return super().call(client, request, REPLY_TIMEOUT_S)

    def frame(self, before: Callable[[Time], None] | None = None,
              keys: tuple[str, ...] = ('points', 'costmap')) -> dict[str, Any]:
        """Send the scene's depth and CameraInfo (best effort); return its outputs.

        ``before(stamp)`` runs first (e.g. odometry at the frame's stamp). Retried: a best
        effort frame may be lost.
        """
        for _ in range(4):
            stamp = self.next_stamp()
            if before is not None:
                before(stamp)
                self.spin_until(lambda: False, 0.3)
            self.info_pub.publish(_camera_info(self.scene, stamp))
            image = array_to_image(self.scene.depth_mm, stamp=stamp, frame_id='depth_optical')
            self.depth_pub.publish(image)
            key = ros_env.stamp_key(stamp)
            if self.spin_until(lambda: all(key in self.received[k] for k in keys),
                               REPLY_TIMEOUT_S):
                return {k: self.received[k][key] for k in keys}
        pytest.fail('no output for a frame:\n' + self.log())


@pytest.fixture(scope='module')
def graph(tmp_path_factory: pytest.TempPathFactory, scene: SceneFrame) -> Iterator[Graph]:
    """Start the node; keep the first /diagnostics report it sends before any frame."""
    tmp = tmp_path_factory.mktemp('plumbing')
    harness = Graph(tmp, scene)
    try:
        assert harness.spin_until(lambda: 'ready:' in harness.log(), START_TIMEOUT_S), \
            harness.log()
        assert harness.spin_until(lambda: bool(harness.reports), REPLY_TIMEOUT_S), \
            harness.log()
        harness.first_report = harness.reports[0]
        assert harness.spin_until(lambda: harness.depth_pub.get_subscription_count() > 0,
                                  START_TIMEOUT_S), harness.log()
        assert harness.spin_until(lambda: harness.info_pub.get_subscription_count() > 0,
                                  START_TIMEOUT_S), harness.log()
        yield harness
    finally:
        harness.close()   # writes tmp/detector.log for a post-mortem


def test_a_namespace_keeps_every_value_of_the_params_file(graph: Graph) -> None:
    names = [spec.name for spec in ALL_PARAMS]
    expected = _yaml_values(CORRIDOR_YAML) | OVERRIDES

    reply = graph.call(graph.get_client, GetParameters.Request(names=names))

    running = dict(zip(names, map(parameter_value_to_python, reply.values)))
    assert set(expected) == set(names)          # the file sets every parameter
    assert running == expected
    assert 'does not name this node' not in graph.log()


def test_best_effort_and_reliable_odometry_both_move_the_fused_costmap(graph: Graph) -> None:
    half = OVERRIDES['fused_size_m'] / 2
    origins = []
    # steps within the fused grid's odometry jump limit (0.5 m a frame)
    for reliability, x_m in ((ReliabilityPolicy.BEST_EFFORT, 0.25),
                             (ReliabilityPolicy.RELIABLE, 0.5)):
        odom_pub = graph.node.create_publisher(
            Odometry, f'{NAMESPACE}/odom', QoSProfile(depth=10, reliability=reliability))
        assert graph.spin_until(lambda: odom_pub.get_subscription_count() > 0,
                                REPLY_TIMEOUT_S), f'{reliability} odometry did not connect'

        def odometry(stamp: Time, odom_pub: Any = odom_pub, x_m: float = x_m) -> None:
            msg = Odometry()
            msg.header.stamp = stamp
            msg.header.frame_id = 'odom'
            msg.pose.pose.position.x = x_m
            msg.pose.pose.orientation.w = 1.0
            odom_pub.publish(msg)

        for _ in range(3):   # on a busy machine the frame may reach the node before it
            out = graph.frame(odometry, ('points', 'fused_costmap'))
            if out['fused_costmap'].info.origin.position.x == pytest.approx(x_m - half):
                break
        origins.append(out['fused_costmap'].info.origin.position.x)
        graph.node.destroy_publisher(odom_pub)

    assert origins == pytest.approx([0.25 - half, 0.5 - half])


def test_a_display_that_joins_late_gets_the_last_grids(graph: Graph) -> None:
    graph.frame(keys=('points', 'costmap', 'fused_costmap'))
    last = {key: max(graph.received[key]) for key in ('costmap', 'fused_costmap')}
    late: dict[str, Any] = {}
    for key in last:   # RViz's map display: reliable, transient local, depth 1
        graph.node.create_subscription(OccupancyGrid, f'{NAMESPACE}/obstacles/{key}',
                                       lambda msg, key=key: late.setdefault(key, msg), LATCHED)

    assert graph.spin_until(lambda: len(late) == len(last), REPLY_TIMEOUT_S), late.keys()
    assert {key: ros_env.stamp_key(msg.header.stamp) for key, msg in late.items()} == last


def test_only_what_is_switched_on_is_advertised_or_subscribed(graph: Graph) -> None:
    def publishers(topic: str) -> list[Any]:
        return graph.node.get_publishers_info_by_topic(f'{NAMESPACE}/{topic}')

    def subscriptions(topic: str) -> list[Any]:
        return graph.node.get_subscriptions_info_by_topic(f'{NAMESPACE}/{topic}')

    assert publishers('obstacles/ground_points') == [] == publishers('obstacles/overlay')
    for topic in ('obstacles/costmap', 'obstacles/fused_costmap'):
        (grid,) = publishers(topic)
        assert grid.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL, topic
        assert grid.qos_profile.reliability == ReliabilityPolicy.RELIABLE, topic
    (cloud,) = publishers('obstacles/points')
    assert cloud.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    (odom,) = subscriptions('odom')
    assert odom.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
    (info,) = subscriptions('depth/camera_info')
    assert info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT


def test_a_switch_cannot_change_at_run_time_and_says_why(graph: Graph) -> None:
    request = SetParameters.Request(parameters=[
        Parameter('publish_ground', value=True).to_parameter_msg()])

    result = graph.call(graph.set_client, request).results[0]

    assert not result.successful
    assert result.reason == 'Trying to set a read-only parameter: publish_ground.'
    assert graph.node.get_publishers_info_by_topic(f'{NAMESPACE}/obstacles/ground_points') == []


def test_diagnostics_are_named_after_the_node_and_say_what_before_a_frame(
        graph: Graph) -> None:
    first = graph.first_report
    # diagnostic_updater's name: the node's name (its namespace with diagnostic_updater.use_fqn)
    assert first.name == 'obstacle_detector: depth obstacle detection'
    assert first.hardware_id == f'{NAMESPACE}/depth/image_raw'   # no frame yet
    graph.frame()
    start = len(graph.reports)
    assert graph.spin_until(lambda: len(graph.reports) > start, REPLY_TIMEOUT_S)
    assert graph.reports[-1].hardware_id == f'{NAMESPACE}/depth/image_raw'   # stays put


# -- in-process nodes ---------------------------------------------------------------------
@pytest.mark.parametrize('order', [('obstacle_detector', '/**/obstacle_detector', '/**'),
                                   ('/**', '/**/obstacle_detector', 'obstacle_detector'),
                                   ('/**/obstacle_detector', 'obstacle_detector', '/**')])
def test_the_tools_read_a_params_file_as_rclpy_gives_it_to_the_node(
        local_context: rclpy.Context, tmp_path: Path, order: tuple[str, ...]) -> None:
    values = {'obstacle_detector': {'median_kernel': 7},
              '/**/obstacle_detector': {'median_kernel': 9, 'max_range_m': 2.5},
              '/**': {'median_kernel': 5, 'max_range_m': 3.0, 'lateral_limit_m': 1.0}}
    path = tmp_path / 'p.yaml'
    path.write_text(yaml.safe_dump({key: {'ros__parameters': values[key]} for key in order},
                                   sort_keys=False))
    node = rclpy.create_node('obstacle_detector', context=local_context,
                             cli_args=['--ros-args', '--params-file', str(path)],
                             automatically_declare_parameters_from_overrides=True)
    try:
        read = read_params_file(path)
        assert read == {name: node.get_parameter(name).value for name in read}
    finally:
        node.destroy_node()


def test_two_nodes_report_under_two_names(local_context: rclpy.Context,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    nodes = [DetectorNode(context=local_context, namespace=ns,
                          cli_args=['--ros-args', '--params-file', str(CORRIDOR_YAML),
                                    '-p', 'diagnostic_updater.use_fqn:=true'])
             for ns in ('front', 'rear')]
    reports: list[Any] = []
    try:
        for node in nodes:
            sent = ros_env.sent(node, '/diagnostics', monkeypatch)
            node.publish_diagnostics()
            reports += [status for msg in sent for status in msg.status]
        assert [(r.name, r.hardware_id) for r in reports] == [
            ('/front/obstacle_detector: depth obstacle detection', '/front/depth/image_raw'),
            ('/rear/obstacle_detector: depth obstacle detection', '/rear/depth/image_raw')]
    finally:
        for node in nodes:
            node.close()
            node.destroy_node()


def test_the_launch_files_settings_keep_the_file_and_pass_use_sim_time(
        local_context: rclpy.Context, tmp_path: Path) -> None:
    """As launch_ros starts the node: its dict of parameters becomes a '/**' params file."""
    from test_launch_and_nav2 import _launch_module
    from test_mount_source import StandInBuffer

    settings = _launch_module().node_settings(
        {'namespace': 'x', 'use_sim_time': 'true', 'params_file': str(CORRIDOR_YAML)}, '/s')
    files = []
    for i, parameters in enumerate(settings['parameters']):
        if isinstance(parameters, dict):
            path = tmp_path / f'launch_params_{i}.yaml'
            path.write_text(yaml.safe_dump({'/**': {'ros__parameters': parameters}}))
            parameters = str(path)
        files += ['--params-file', parameters]
    # use_tf (the launch default) needs tf2, which a robot's ROS 2 has: a stand-in here
    node = DetectorNode(context=local_context, namespace=settings['namespace'],
                        cli_args=['--ros-args', *files], tf_buffer=StandInBuffer(None))
    try:
        fqn = node.get_fully_qualified_name()
        assert fqn == NODE
        assert node.get_parameter('use_sim_time').value is True
        # the file's values, but the mount from TF: the launch file's use_tf default
        file_values = _yaml_values(CORRIDOR_YAML) | {'use_tf': True}
        assert {name: node.get_parameter(name).value for name in file_values} == file_values
        assert [p for f in files[1::2] for p in params_file_problems(f, fqn)] == []
    finally:
        node.close()
        node.destroy_node()


def test_rvl_frames_give_the_raw_frames_outputs_and_a_broken_one_is_skipped(
        local_context: rclpy.Context, scene: SceneFrame,
        monkeypatch: pytest.MonkeyPatch) -> None:
    node = DetectorNode(context=local_context, cli_args=[
        '--ros-args', '--params-file', str(CORRIDOR_YAML),
        '-p', 'depth_transport:=compressedDepth'])
    try:
        grids = ros_env.sent(node, '/obstacles/costmap', monkeypatch)
        ros_env.deliver(node, '/depth/camera_info', _camera_info(scene))
        assert node.handle_frame(array_to_image(scene.depth_mm, stamp=Time(),
                                                frame_id='depth_optical'))
        assert node.handle_frame(rvl_message(scene.depth_mm, Time(), 'depth_optical'))
        assert len(grids) == 2 and grids[0].data == grids[1].data
        assert np.count_nonzero(np.asarray(grids[1].data) == 100) > 100

        broken = rvl_message(scene.depth_mm, Time(), 'depth_optical')
        broken.data = bytes(broken.data)[:-100]
        assert not node.handle_frame(broken)
        assert sum(node.stats.take(reader='log').skipped.values()) == 1 and len(grids) == 2
    finally:
        node.close()
        node.destroy_node()


def test_help_lists_every_topic_the_node_can_use(tmp_path: Path) -> None:
    """Every create_publisher / create_subscription topic of node.py, its outputs, the odometry."""
    import ast

    tree = ast.parse((REPO / 'obstacle_detection' / 'ros' / 'node.py').read_text())
    topics = {call.args[1].value for call in ast.walk(tree)
              if isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
              and call.func.attr in ('create_publisher', 'create_subscription')
              and len(call.args) >= 2 and isinstance(call.args[1], ast.Constant)}
    from obstacle_detection.ros.node import DEPTH_TRANSPORTS, OUTPUTS

    topics |= {topic for _, topic in DEPTH_TRANSPORTS.values()} | {'odom'}
    topics |= {topic for _, topic, _ in OUTPUTS.values()}
    assert {'/diagnostics', 'obstacles/fused_costmap', 'depth/camera_info'} <= topics

    done = ros_env.run_detector(tmp_path, '--help', salt=__name__ + ':help')

    assert done.returncode == 0, done.stderr
    listed = {line.split()[1] for line in done.stdout.splitlines()
              if line.startswith(('  in ', '  out '))}
    assert topics <= listed, topics - listed
