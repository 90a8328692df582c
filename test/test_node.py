"""The detector node through real rclpy and real DDS (loopback only).

The node runs once per module as a subprocess (``detector --ros-args --params-file
params/corridor.yaml``); a probe node in this process publishes synthetic corridor frames with
their CameraInfo and checks what comes back against ``Detector.process`` on the same frame. The
last tests build DetectorNode in-process, in a ROS domain of their own, to check the parameter
mapping and the error paths directly.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
import ros_env
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import OccupancyGrid
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterValue
from rcl_interfaces.srv import (
    GetParameters,
    ListParameters,
    SetParameters,
    SetParametersAtomically,
)
from rclpy.parameter import Parameter, parameter_dict_from_yaml_file, parameter_value_to_python
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
from std_msgs.msg import Float64, String

from obstacle_detection.labels import CELL_OCCUPIED, GT_OBSTACLE
from obstacle_detection.pipeline import jit as jit_support
from message_helpers import array_to_compressed_depth, pointcloud2_to_points
from obstacle_detection.ros.conversions import (
    array_to_image,
    intrinsics_to_camera_info,
)
from obstacle_detection.pipeline.geometry import mount_rotation
from obstacle_detection.ros import node as node_module
from obstacle_detection.ros.node import DetectorNode, FrameMailbox
from obstacle_detection.pipeline.params import PRESETS, Intrinsics, table_4_2, table_4_3
from obstacle_detection.pipeline.detector import DetectionResult, Detector
from obstacle_detection.ros.parameters import (
    ALL_PARAMS,
    PARAMS_FILE_KEY,
    detector_params_from_ros,
    params_file_problems,
)
from obstacle_detection.sim.render import SceneFrame
from obstacle_detection.sim.scenes import render_scene


REPO = ros_env.REPO_ROOT
OK, ERROR = DiagnosticStatus.OK, DiagnosticStatus.ERROR
CORRIDOR_YAML = REPO / 'params' / 'corridor.yaml'
NODE = '/obstacle_detector'
START_TIMEOUT_S = 60.0
REPLY_TIMEOUT_S = 20.0
RELIABLE = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
STATUS_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: A first numba compilation takes about a minute on a 2-core machine, longer when it is busy.
COMPILE_TIMEOUT_S = 300.0


def _yaml_values(path: Path) -> dict[str, Any]:
    """{name: python value} of a params file, parsed by rclpy as the node's rcl does."""
    parsed = parameter_dict_from_yaml_file(str(path), target_nodes=[PARAMS_FILE_KEY])
    return {name: parameter_value_to_python(msg.value) for name, msg in parsed.items()}


class NodeUnderTest(ros_env.NodeProcess):
    """The detector process (params/corridor.yaml, debug log) and a probe talking to it."""

    def __init__(self, tmp: Path, *, salt: str = '',
                 extra_env: dict[str, str] | None = None,
                 extra_args: tuple[str, ...] = ()) -> None:
        super().__init__(tmp, __name__ + salt, 'node_test_probe', extra_env=extra_env)
        self.depth_pub = self.node.create_publisher(Image, 'depth/image_raw', RELIABLE)
        self.info_pub = self.node.create_publisher(CameraInfo, 'depth/camera_info', RELIABLE)
        self.times_ms: list[float] = []
        self.statuses: list[str] = []
        self.outputs_subs = [self.by_stamp('obstacles', PointCloud2, 'obstacles/points', RELIABLE),
                             self.by_stamp('costmap', OccupancyGrid, 'obstacles/costmap',
                                           RELIABLE)]
        self.by_stamp('ground', PointCloud2, 'obstacles/ground_points', RELIABLE)
        self.by_stamp('overlay', Image, 'obstacles/overlay', RELIABLE)
        self.node.create_subscription(Float64, f'{NODE}/processing_time_ms',
                                      lambda msg: self.times_ms.append(msg.data), RELIABLE)
        self.node.create_subscription(String, f'{NODE}/status',
                                      lambda msg: self.statuses.append(msg.data), STATUS_QOS)
        self.set_client = self.node.create_client(SetParameters, f'{NODE}/set_parameters')
        self.atomic_client = self.node.create_client(SetParametersAtomically,
                                                     f'{NODE}/set_parameters_atomically')
        self.list_client = self.node.create_client(ListParameters, f'{NODE}/list_parameters')
        self.get_client = self.node.create_client(GetParameters, f'{NODE}/get_parameters')
        self.start([
            '--ros-args', '--params-file', str(CORRIDOR_YAML),
            '-p', 'reliable_input:=true', '-p', 'publish_ground:=true',
            '-p', 'publish_overlay:=true',
            '-p', 'stats_period_s:=1.0', '--log-level', 'obstacle_detector:=debug',
            *extra_args])

    def connected(self, publisher: Any) -> bool:
        """Whether the node subscribes to ``publisher`` and publishes the cloud and grid."""
        return (publisher.get_subscription_count() > 0
                and all(s.get_publisher_count() > 0 for s in self.outputs_subs))

    def wait_for_log(self, text: str, start: int, timeout: float = REPLY_TIMEOUT_S) -> bool:
        return super().wait_for_log(text, start, timeout)

    def send(self, image: Image, info: CameraInfo | None) -> Time:
        """Publish ``info`` (if any), let it arrive first, then ``image`` with a new stamp."""
        stamp = self.next_stamp()
        if info is not None:
            info.header.stamp = stamp
            self.info_pub.publish(info)
            self.spin_until(lambda: False, 0.2)
        image.header.stamp = stamp
        self.depth_pub.publish(image)
        return stamp

    def outputs(self, stamp: Time, keys: tuple[str, ...] = ('obstacles', 'costmap'),
                timeout: float = REPLY_TIMEOUT_S) -> dict[str, Any] | None:
        key = ros_env.stamp_key(stamp)
        got = self.spin_until(lambda: all(key in self.received[k] for k in keys), timeout)
        return {k: self.received[k][key] for k in keys} if got else None

    def call(self, client: Any, request: Any) -> Any:
        return super().call(client, request, REPLY_TIMEOUT_S)

    def set_parameter(self, name: str, value: Any) -> Any:
        request = SetParameters.Request(parameters=[Parameter(name, value=value)
                                                    .to_parameter_msg()])
        return self.call(self.set_client, request).results[0]

    def get_parameter(self, name: str) -> Any:
        reply = self.call(self.get_client, GetParameters.Request(names=[name]))
        return parameter_value_to_python(reply.values[0])


@pytest.fixture(scope='module')
def scene() -> SceneFrame:
    params = table_4_2()
    return render_scene('corridor', seed=3, height_m=params.camera_height_m,
                        pitch_rad=params.camera_pitch_rad, roll_rad=params.camera_roll_rad)


def _depth_image(frame: SceneFrame) -> Image:
    return array_to_image(frame.depth_mm, stamp=Time(), frame_id='depth_optical')


def _camera_info(frame: SceneFrame) -> CameraInfo:
    height, width = frame.depth_mm.shape
    return intrinsics_to_camera_info(frame.intrinsics, width, height, stamp=Time(),
                                     frame_id='depth_optical')


@pytest.fixture(scope='module')
def detector(tmp_path_factory: pytest.TempPathFactory,
             scene: SceneFrame) -> Iterator[NodeUnderTest]:
    """Start the node once; before any CameraInfo it gets one frame (and must skip it)."""
    harness = NodeUnderTest(tmp_path_factory.mktemp('node'))
    try:
        assert harness.wait_for_log('ready:', 0, START_TIMEOUT_S), harness.log()
        matched = harness.spin_until(
            lambda: (harness.connected(harness.depth_pub)
                     and harness.info_pub.get_subscription_count() > 0), START_TIMEOUT_S)
        assert matched, 'the probe and the node did not discover each other'
        start = len(harness.lines)
        harness.send(_depth_image(scene), None)
        harness.no_camera_info_logged = harness.wait_for_log('no CameraInfo received yet',
                                                             start)
        yield harness
    finally:
        harness.close()


@pytest.fixture(scope='module')
def corridor_params() -> Any:
    return detector_params_from_ros(_yaml_values(CORRIDOR_YAML))


def _sorted_rows(points: np.ndarray) -> np.ndarray:
    return points[np.lexsort(points.T[::-1])]


def _good_frame(detector: NodeUnderTest, scene: SceneFrame,
                keys: tuple[str, ...] = ('obstacles', 'costmap')) -> dict[str, Any]:
    """Send the scene frame with its CameraInfo (retried: the first may race) -> outputs."""
    for _ in range(3):
        out = detector.outputs(detector.send(_depth_image(scene), _camera_info(scene)), keys)
        if out is not None:
            return out
    pytest.fail('no output for a good frame:\n' + detector.log())


def _assert_matches(out: dict[str, Any], expected: DetectionResult) -> None:
    points = pointcloud2_to_points(out['obstacles'])
    assert points.shape == expected.obstacle_points.shape
    np.testing.assert_array_equal(_sorted_rows(points), _sorted_rows(expected.obstacle_points))
    grid = out['costmap']
    cells = np.asarray(grid.data, np.int8).reshape(grid.info.height, grid.info.width)
    np.testing.assert_array_equal(cells, expected.costmap.data)
    assert grid.info.origin.position.x == pytest.approx(expected.costmap.origin_xy_m[0])
    assert grid.info.origin.position.y == pytest.approx(expected.costmap.origin_xy_m[1])


def test_frame_before_any_camera_info_is_skipped_with_a_warning(
        detector: NodeUnderTest) -> None:
    assert detector.no_camera_info_logged, detector.log()


def test_node_sockets_bind_loopback_only(detector: NodeUnderTest) -> None:
    addresses = ros_env.udp_sockets_of(detector.process.pid)
    if addresses is None:
        pytest.skip('ss is not installed')
    assert addresses, 'no UDP socket found for the node process'
    assert all(a.startswith('127.0.0.1:') for a in addresses), addresses


def test_cloud_and_grid_match_the_pipeline(detector: NodeUnderTest, scene: SceneFrame,
                                           corridor_params: Any) -> None:
    expected = Detector(corridor_params).process(scene.depth_mm, scene.intrinsics)

    out = _good_frame(detector, scene, ('obstacles', 'costmap', 'ground', 'overlay'))

    _assert_matches(out, expected)
    assert out['obstacles'].header.frame_id == 'base_footprint'
    assert out['costmap'].header.frame_id == 'base_footprint'
    assert out['overlay'].header.frame_id == 'depth_optical'
    np.testing.assert_array_equal(_sorted_rows(pointcloud2_to_points(out['ground'])),
                                  _sorted_rows(expected.ground_points))


def test_status_says_ready_and_which_code_runs(detector: NodeUnderTest) -> None:
    assert detector.spin_until(lambda: bool(detector.statuses), REPLY_TIMEOUT_S)
    assert detector.statuses[-1].startswith('ready: ')


@pytest.mark.skipif(not jit_support.enabled(), reason='numba is not installed or switched off')
def test_a_warm_start_says_the_kernels_load_not_compile(detector: NodeUnderTest) -> None:
    # every start said "compile ... about 20-40 s" though the kernels load from the cache
    assert detector.wait_for_log('numba kernels loaded from the cache in', 0,
                                 START_TIMEOUT_S), detector.log()
    assert 'kernels compile' not in detector.log(), detector.log()


@pytest.mark.skipif(not jit_support.enabled(), reason='numba is not installed or switched off')
def test_cold_numba_cache_answers_at_once_then_switches_to_the_kernels(
        tmp_path: Path, scene: SceneFrame, corridor_params: Any) -> None:
    """An empty numba cache: frames are answered (numpy path) while the kernels compile."""
    expected = Detector(corridor_params).process(scene.depth_mm, scene.intrinsics)
    cold = NodeUnderTest(tmp_path, salt='cold',
                         extra_env={'NUMBA_CACHE_DIR': str(tmp_path / 'empty_numba_cache')})
    try:
        assert cold.spin_until(lambda: bool(cold.statuses), START_TIMEOUT_S), cold.log()
        assert cold.statuses[0].startswith('ready: numpy path while the numba kernels compile')
        assert cold.spin_until(lambda: cold.connected(cold.depth_pub), START_TIMEOUT_S)
        _assert_matches(_good_frame(cold, scene), expected)

        assert cold.spin_until(lambda: 'compiled' in cold.statuses[-1], COMPILE_TIMEOUT_S), (
            cold.statuses, cold.log())
        assert cold.statuses[-1] == 'ready: compiled numba kernels'
        # the log line is written beside the status: wait for it rather than race the file
        assert cold.wait_for_log('numba kernels compiled in', 0), \
            cold.log()
        _assert_matches(_good_frame(cold, scene), expected)
    finally:
        cold.close()
    assert list((tmp_path / 'empty_numba_cache').rglob('*.nbi'))   # the cache was filled
    # with every kernel the node imports: its next start says "load", not "compile"
    check = subprocess.run(
        [sys.executable, '-c', 'import obstacle_detection.ros.node; from obstacle_detection.'
         'pipeline import jit; print(jit.cache_filled())'], capture_output=True, text=True,
        env={**os.environ, 'NUMBA_CACHE_DIR': str(tmp_path / 'empty_numba_cache')}, check=True)
    assert check.stdout.strip() == 'True', check.stderr


def test_occupied_cells_are_where_the_boxes_and_walls_are(
        detector: NodeUnderTest, scene: SceneFrame) -> None:
    grid = _good_frame(detector, scene)['costmap']
    cells = np.asarray(grid.data, np.int8).reshape(grid.info.height, grid.info.width)
    truth = scene.points_ground[scene.labels == GT_OBSTACLE]
    col = np.floor((truth[:, 0] - grid.info.origin.position.x) / grid.info.resolution)
    row = np.floor((truth[:, 1] - grid.info.origin.position.y) / grid.info.resolution)
    inside = (col >= 0) & (col < grid.info.width) & (row >= 0) & (row < grid.info.height)
    near_truth = np.zeros(cells.shape, bool)
    for dr in (-1, 0, 1):  # a one-cell tolerance for voxel centroids on a cell border
        for dc in (-1, 0, 1):
            r = np.clip(row[inside].astype(int) + dr, 0, grid.info.height - 1)
            c = np.clip(col[inside].astype(int) + dc, 0, grid.info.width - 1)
            near_truth[r, c] = True
    occupied = cells == CELL_OCCUPIED
    assert occupied.sum() >= 10
    assert (occupied & near_truth).sum() >= 0.9 * occupied.sum()


def test_processing_time_is_published(detector: NodeUnderTest, scene: SceneFrame) -> None:
    _good_frame(detector, scene)
    assert detector.spin_until(lambda: len(detector.times_ms) > 0, REPLY_TIMEOUT_S)
    assert all(t > 0.0 for t in detector.times_ms)


def test_statistics_are_logged(detector: NodeUnderTest, scene: SceneFrame) -> None:
    _good_frame(detector, scene)
    assert detector.wait_for_log('frames processed in', 0), detector.log()


def test_a_burst_of_frames_is_not_queued(detector: NodeUnderTest, scene: SceneFrame) -> None:
    _good_frame(detector, scene)  # the node holds a good CameraInfo
    start = len(detector.lines)
    stamps = [detector.send(_depth_image(scene), None) for _ in range(5)]

    # The newest frame is always processed; older pending ones may be dropped, never queued.
    assert detector.outputs(stamps[-1]) is not None, detector.log(start)
    answered = sum(ros_env.stamp_key(s) in detector.received['obstacles'] for s in stamps)
    if answered < len(stamps):  # the stats log must account for the dropped frames
        assert detector.spin_until(lambda: re.search(r'[1-9]\d* dropped', detector.log(start)),
                                   REPLY_TIMEOUT_S), detector.log(start)


def _projection(fx: float, fy: float, cx: float, cy: float) -> list[float]:
    """Return a CameraInfo P (3 x 4, row-major) of these intrinsics [px]."""
    return [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]


def _bad_cases(scene: SceneFrame) -> list[tuple[str, Image, CameraInfo, str]]:
    good_info = _camera_info(scene)
    height, width = scene.depth_mm.shape
    rgb = array_to_image(np.zeros((height, width, 3), np.uint8), stamp=Time(),
                         frame_id='depth_optical')
    odd = _depth_image(scene)
    odd.data = bytes(odd.data)[:-1]
    small = array_to_image(scene.depth_mm[::2, ::2].copy(), stamp=Time(),
                           frame_id='depth_optical')
    zero_focal = _camera_info(scene)     # an uncalibrated camera: K and P all zero
    zero_focal.k, zero_focal.p = [0.0] * 9, [0.0] * 12
    nan = array_to_image(np.full((height, width), np.nan, np.float32), stamp=Time(),
                         frame_id='depth_optical')
    huge_focal = _camera_info(scene)
    huge_focal.p = _projection(1e300, 1e300, 256.0, 212.0)     # the intrinsics come from P
    tiny_focal = _camera_info(scene)
    tiny_focal.p = _projection(1e-300, 1e-300, 256.0, 212.0)
    no_size = _camera_info(scene)
    no_size.width = no_size.height = 0
    mm_as_metres = array_to_image(scene.depth_mm.astype(np.float32), stamp=Time(),
                                  frame_id='depth_optical')
    wrong_order = _depth_image(scene)
    wrong_order.is_bigendian = not wrong_order.is_bigendian
    return [
        ('unknown encoding', rgb, good_info, "unsupported depth encoding 'rgb8'"),
        ('odd byte count', odd, good_info, f'data has {2 * width * height - 1} bytes'),
        ('size differs from CameraInfo', small, good_info,
         f'image is {width // 2}x{height // 2} but CameraInfo is {width}x{height}'),
        ('zero focal length', _depth_image(scene), zero_focal,
         'focal lengths must be > 0'),
        ('all-NaN frame', nan, good_info, 'no valid depth pixel'),
        ('focal length 1e300', _depth_image(scene), huge_focal, 'CameraInfo fx=1e+300 px'),
        ('focal length 1e-300', _depth_image(scene), tiny_focal, 'CameraInfo fx=1e-300 px'),
        ('0 x 0 CameraInfo', _depth_image(scene), no_size, 'CameraInfo image size is 0x0'),
        ('millimetres as 32FC1', mm_as_metres, good_info,
         'it looks like millimetres sent as 32FC1 metres'),
        ('wrong byte-order flag', wrong_order, good_info, 'is_bigendian may be wrong'),
    ]


def test_bad_inputs_are_logged_and_survived(detector: NodeUnderTest, scene: SceneFrame,
                                            corridor_params: Any) -> None:
    expected = Detector(corridor_params).process(scene.depth_mm, scene.intrinsics)
    for name, image, info, message in _bad_cases(scene):
        start = len(detector.lines)
        stamp = detector.send(image, info)
        assert detector.wait_for_log(message, start), f'{name}: not logged\n{detector.log()}'
        assert ros_env.stamp_key(stamp) not in detector.received['obstacles'], name
        assert detector.process.poll() is None, f'{name}: the node died\n{detector.log()}'
        _assert_matches(_good_frame(detector, scene), expected)
    assert 'Traceback' not in detector.log()


def test_camera_info_is_matched_to_the_frame_by_stamp(
        detector: NodeUnderTest, scene: SceneFrame, corridor_params: Any) -> None:
    """Under load a frame is processed after newer CameraInfos came: it keeps its own."""
    own = detector.next_stamp()
    newer = Time(sec=own.sec + 1, nanosec=own.nanosec)
    between = Time(sec=own.sec, nanosec=own.nanosec + 500_000_000)
    detector.next_stamp()
    info = _camera_info(scene)
    info.header.stamp = own
    other = _camera_info(scene)
    other.p = _projection(300.0, 300.0, 250.0, 200.0)
    other.header.stamp = newer
    detector.info_pub.publish(info)
    detector.info_pub.publish(other)
    detector.spin_until(lambda: False, 0.3)

    image = _depth_image(scene)
    image.header.stamp = own
    detector.depth_pub.publish(image)
    out = detector.outputs(own)
    assert out is not None, detector.log()
    _assert_matches(out, Detector(corridor_params).process(scene.depth_mm, scene.intrinsics))

    start = len(detector.lines)
    image.header.stamp = between
    detector.depth_pub.publish(image)
    assert detector.wait_for_log('no CameraInfo within camera_info_tolerance_s', start)
    assert detector.outputs(between, timeout=1.0) is None

    image.header.stamp = newer
    detector.depth_pub.publish(image)
    out = detector.outputs(newer)
    assert out is not None, detector.log()
    _assert_matches(out, Detector(corridor_params).process(
        scene.depth_mm, Intrinsics(fx=300.0, fy=300.0, cx=250.0, cy=200.0)))
    _good_frame(detector, scene)   # back to the usual stream


def test_parameter_update_changes_the_next_result(detector: NodeUnderTest, scene: SceneFrame,
                                                  corridor_params: Any) -> None:
    result = detector.set_parameter('max_range_m', 1.3)
    try:
        assert result.successful, result.reason
        expected = Detector(corridor_params.replace(max_range_m=1.3)).process(
            scene.depth_mm, scene.intrinsics)
        out = _good_frame(detector, scene)
        _assert_matches(out, expected)
        assert pointcloud2_to_points(out['obstacles'])[:, 0].max() <= 1.3
    finally:
        assert detector.set_parameter('max_range_m', corridor_params.max_range_m).successful


def test_degree_parameter_reaches_the_pipeline_in_radians(
        detector: NodeUnderTest, scene: SceneFrame, corridor_params: Any) -> None:
    result = detector.set_parameter('max_slope_deg', 50.0)
    try:
        assert result.successful, result.reason
        expected = Detector(corridor_params.replace(max_slope_rad=math.radians(50.0))).process(
            scene.depth_mm, scene.intrinsics)
        _assert_matches(_good_frame(detector, scene), expected)
    finally:
        assert detector.set_parameter('max_slope_deg', 30.0).successful


@pytest.mark.parametrize('name', ['', 'no_such_parameter'])
def test_undeclared_parameters_are_refused_and_nothing_is_created(
        detector: NodeUnderTest, name: str) -> None:
    msg = Parameter(name, value=5).to_parameter_msg()

    single = detector.call(detector.set_client, SetParameters.Request(parameters=[msg]))
    atomic = detector.call(detector.atomic_client,
                           SetParametersAtomically.Request(parameters=[msg]))

    assert [r.successful for r in single.results] == [False]
    assert 'undeclared parameter' in single.results[0].reason
    assert not atomic.result.successful and 'undeclared parameter' in atomic.result.reason
    listed = detector.call(detector.list_client, ListParameters.Request()).result.names
    assert '' not in listed and 'no_such_parameter' not in listed
    assert {spec.name for spec in ALL_PARAMS} <= set(listed)


def test_a_malformed_parameter_type_is_refused_and_the_node_goes_on(
        detector: NodeUnderTest, scene: SceneFrame, corridor_params: Any) -> None:
    """An unknown type made rclpy's parameter service raise: no reply, or the node's end."""
    good = Parameter('max_slope_deg', value=20.0).to_parameter_msg()
    msg = ParameterMsg(name='median_kernel', value=ParameterValue(type=200, integer_value=5))

    single = detector.call(detector.set_client, SetParameters.Request(parameters=[good, msg]))
    atomic = detector.call(detector.atomic_client,
                           SetParametersAtomically.Request(parameters=[msg]))

    assert [r.successful for r in single.results] == [False, False]
    assert "unknown ParameterValue.type for [('median_kernel', 200)]" in single.results[1].reason
    assert not atomic.result.successful and 'median_kernel' in atomic.result.reason
    assert detector.process.poll() is None
    assert detector.get_parameter('max_slope_deg') == pytest.approx(30.0)   # nothing set
    out = _good_frame(detector, scene)   # the next frame is answered, as before
    _assert_matches(out, Detector(corridor_params).process(scene.depth_mm, scene.intrinsics))


def test_a_bad_value_is_refused_with_the_reason_in_the_users_names(
        detector: NodeUnderTest) -> None:
    slope = detector.set_parameter('max_slope_deg', 90.0)
    assert not slope.successful
    assert slope.reason == 'max_slope_deg=90.0 out of range: must be in (0, 90) [deg]'
    assert detector.get_parameter('max_slope_deg') == pytest.approx(30.0)


def test_even_median_kernel_is_refused_and_the_old_value_kept(
        detector: NodeUnderTest) -> None:
    result = detector.set_parameter('median_kernel', 4)

    assert not result.successful
    assert 'median_kernel=4 must be odd' in result.reason
    assert detector.get_parameter('median_kernel') == 5


def test_out_of_range_value_is_refused_by_the_descriptor(detector: NodeUnderTest) -> None:
    result = detector.set_parameter('max_slope_deg', 95.0)

    assert not result.successful
    assert detector.get_parameter('max_slope_deg') == 30.0


# -- in-process node, in a ROS domain of its own ----------------------------------------------
@pytest.fixture
def local_node(local_context: rclpy.Context) -> Iterator[DetectorNode]:
    node = DetectorNode(context=local_context,
                        cli_args=['--ros-args', '--params-file', str(CORRIDOR_YAML)])
    try:
        yield node
    finally:
        node.close()
        node.destroy_node()


@pytest.mark.parametrize(('file_name', 'preset'), [('corridor.yaml', PRESETS['corridor']),
                                                    ('seed_table_4_2.yaml', table_4_2),
                                                    ('seed_table_4_3.yaml', table_4_3),
                                                    ('corridor_video.yaml', table_4_3)])
def test_params_file_equals_its_preset(local_context: rclpy.Context, file_name: str,
                                       preset: Callable[[], Any]) -> None:
    path = REPO / 'params' / file_name
    values = _yaml_values(path)
    assert set(values) == {spec.name for spec in ALL_PARAMS}  # the file shows every parameter
    assert detector_params_from_ros(values) == preset()
    node = DetectorNode(context=local_context,
                        cli_args=['--ros-args', '--params-file', str(path)])
    try:
        assert node.config.detector.params == preset()
    finally:
        node.close()
        node.destroy_node()


def test_set_parameters_validates_without_side_effects(local_node: DetectorNode) -> None:
    before = local_node.config

    result = local_node.set_parameters([Parameter('median_kernel', value=4)])[0]

    assert not result.successful and 'median_kernel=4 must be odd' in result.reason
    assert local_node.get_parameter('median_kernel').value == 5
    assert local_node.config is before


def _tf_node(context: rclpy.Context, buffer: Any) -> DetectorNode:
    return DetectorNode(context=context, tf_buffer=buffer, cli_args=[
        '--ros-args', '--params-file', str(CORRIDOR_YAML), '-p', 'use_tf:=true'])


def _publish_frame(node: DetectorNode, frame: SceneFrame,
                   monkeypatch: pytest.MonkeyPatch) -> list[OccupancyGrid]:
    grids = ros_env.sent(node, '/obstacles/costmap', monkeypatch)
    ros_env.deliver(node, '/depth/camera_info', _camera_info(frame))
    assert node.handle_frame(_depth_image(frame))
    return grids


def _mount_reported(node: DetectorNode, monkeypatch: pytest.MonkeyPatch) -> str:
    """Return the camera mount the node's next /diagnostics report gives."""
    reports = ros_env.sent(node, '/diagnostics', monkeypatch)
    node.publish_diagnostics()
    return next(v.value for v in reports[0].status[0].values if v.key == 'mount')


def test_use_tf_takes_the_mount_from_the_transform(
        local_context: rclpy.Context, corridor_params: Any,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Take the mount from TF, and the outputs land in the base frame where it puts them.

    The parameters: 0.6 m, level, at the origin; TF: x 0.2, y 0.1, 0.8 m up, yaw 10 deg,
    20 deg down.
    """
    from test_mount_source import StandInBuffer, _rz, _transform

    frame = render_scene('corridor', seed=3, height_m=0.8, pitch_rad=math.radians(20.0))
    buffer = StandInBuffer(_transform(
        _rz(math.radians(10.0)) @ mount_rotation(math.radians(20.0), 0.0), (0.2, 0.1, 0.8)))
    node = _tf_node(local_context, buffer)
    try:
        grids = _publish_frame(node, frame, monkeypatch)
        expected = Detector(dataclasses.replace(
            corridor_params, camera_height_m=0.8, camera_pitch_rad=math.radians(20.0),
            camera_x_m=0.2, camera_y_m=0.1, camera_yaw_rad=math.radians(10.0))
        ).process(frame.depth_mm, frame.intrinsics)
        cells = np.asarray(grids[0].data, np.int8).reshape(expected.costmap.data.shape)
        np.testing.assert_array_equal(cells, expected.costmap.data)
        assert grids[0].info.origin.position.x == pytest.approx(0.2)
        assert buffer.calls == [('base_footprint', 'depth_optical')]
        assert _mount_reported(node, monkeypatch).startswith(
            'TF base_footprint <- depth_optical: x 0.200 m, y 0.100 m')
    finally:
        node.close()
        node.destroy_node()


def test_use_tf_drops_a_frame_without_a_transform_then_takes_a_late_transform(
        local_context: rclpy.Context, corridor_params: Any, monkeypatch: pytest.MonkeyPatch,
        capfd: pytest.CaptureFixture[str]) -> None:
    """No transform: the frame is dropped and said (never placed by the mount parameters)."""
    from test_mount_source import StandInBuffer, _transform

    frame = render_scene('corridor', seed=3, height_m=0.6)
    buffer = StandInBuffer(None)
    node = _tf_node(local_context, buffer)
    try:
        assert _mount_reported(node, monkeypatch) == \
            'TF base_footprint <- the depth image frame: no frame yet'
        grids = ros_env.sent(node, '/obstacles/costmap', monkeypatch)
        ros_env.deliver(node, '/depth/camera_info', _camera_info(frame))
        assert not node.handle_frame(_depth_image(frame))
        assert grids == []
        err = capfd.readouterr().err
        assert ("skipping depth frame: no transform base_footprint <- 'depth_optical' from TF "
                '(LookupError: ') in err
        assert 'not published with the mount parameters' in err
        reports = ros_env.sent(node, '/diagnostics', monkeypatch)
        node.publish_diagnostics()
        status = reports[0].status[0]
        assert 'skipped for bad input (tf 1)' in status.message
        assert _mount_reported(node, monkeypatch) == \
            'TF base_footprint <- depth_optical: none (frames dropped)'

        buffer.transform = _transform(mount_rotation(math.radians(10.0), 0.0), (0, 0, 0.7))
        grids = _publish_frame(node, frame, monkeypatch)
        tilted = Detector(dataclasses.replace(
            corridor_params, camera_height_m=0.7, camera_pitch_rad=math.radians(10.0))
        ).process(frame.depth_mm, frame.intrinsics)
        np.testing.assert_array_equal(
            np.asarray(grids[0].data, np.int8).reshape(tilted.costmap.data.shape),
            tilted.costmap.data)
        assert _mount_reported(node, monkeypatch).startswith(
            'TF base_footprint <- depth_optical: ')
    finally:
        node.close()
        node.destroy_node()


def test_use_tf_without_tf2_refuses_to_start(local_context: rclpy.Context,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """A robot that asks for TF gets TF or a clear refusal, never the parameters unseen."""
    monkeypatch.setitem(sys.modules, 'tf2_ros', None)   # not importable
    with pytest.raises(ValueError, match=r'use_tf is true but tf2_ros cannot be imported .*'
                                         r'set use_tf:=false'):
        DetectorNode(context=local_context, cli_args=[
            '--ros-args', '--params-file', str(CORRIDOR_YAML), '-p', 'use_tf:=true'])


def test_a_wrong_urdf_is_reported_with_its_angle_and_offset(
        local_context: rclpy.Context, monkeypatch: pytest.MonkeyPatch,
        capfd: pytest.CaptureFixture[str]) -> None:
    """The camera is level at 0.6 m; the URDF says 1.5 deg down and 3 cm higher.

    The floor fit corrects every frame (the costmap stays right), and /diagnostics says WARN
    with the angle and offset, naming the URDF and tools/estimate_mount.py.
    """
    from test_mount_source import StandInBuffer, _transform

    buffer = StandInBuffer(_transform(mount_rotation(math.radians(1.5), 0.0), (0, 0, 0.63)))
    node = _tf_node(local_context, buffer)
    try:
        ros_env.deliver(node, '/depth/camera_info', _camera_info(render_scene('corridor')))
        for seed in range(12):
            frame = render_scene('corridor', seed=seed, height_m=0.6, pitch_rad=0.0)
            node.stats.count('received')   # as the subscription's callback counts it
            assert node.handle_frame(_depth_image(frame))
        reports = ros_env.sent(node, '/diagnostics', monkeypatch)
        node.publish_diagnostics()
        status = reports[0].status[0]
        values = {kv.key: kv.value for kv in status.values}

        assert status.level == DiagnosticStatus.WARN
        assert 'the camera mount disagrees with the floor in view' in status.message
        assert 'the URDF (TF base_footprint <- depth_optical) is likely wrong' in status.message
        assert 'tools/estimate_mount.py' in status.message
        assert float(values['floor minus mount: pitch [deg]']) == pytest.approx(-1.5, abs=0.2)
        assert float(values['floor minus mount: height [cm]']) == pytest.approx(-3.0, abs=0.5)
        assert f"pitch {values['floor minus mount: pitch [deg]'][:4]}" in status.message
        assert status.message in capfd.readouterr().err   # and in the log
    finally:
        node.close()
        node.destroy_node()


def test_fused_costmap_follows_the_odometry_and_keeps_what_it_saw(
        local_context: rclpy.Context, monkeypatch: pytest.MonkeyPatch) -> None:
    """fuse: obstacles/fused_costmap in odom, moved by nav_msgs/Odometry; per-frame unchanged."""
    from nav_msgs.msg import Odometry

    node = DetectorNode(context=local_context, cli_args=[
        '--ros-args', '--params-file', str(CORRIDOR_YAML), '-p', 'fuse:=true',
        '-p', 'fused_size_m:=6.0'])
    fused = ros_env.sent(node, '/obstacles/fused_costmap', monkeypatch)
    frame = render_scene('corridor', seed=3)
    try:
        grids = _publish_frame(node, frame, monkeypatch)    # no odometry yet: in place
        assert len(fused) == 1 and fused[0].header.frame_id == 'odom'
        assert fused[0].info.width == fused[0].info.height == 120     # 6 m at 5 cm
        first = np.asarray(fused[0].data, np.int8)
        assert (first == CELL_OCCUPIED).sum() >= (np.asarray(grids[0].data) == 100).sum() // 2

        for sec, x in ((200, 0.0), (201, 1.0)):          # the robot drives 1 m forward
            odom = Odometry()
            odom.header.stamp = Time(sec=sec)
            odom.pose.pose.position.x = x
            odom.pose.pose.orientation.w = 1.0
            ros_env.deliver(node, '/odom', odom)
        image = _depth_image(frame)
        image.header.stamp = Time(sec=201)
        info = _camera_info(frame)
        info.header.stamp = Time(sec=201)
        ros_env.deliver(node, '/depth/camera_info', info)
        assert node.handle_frame(image)
        moved = fused[-1]
        assert moved.info.origin.position.x == pytest.approx(1.0 - 3.0)   # centred on x = 1 m
        assert (np.asarray(moved.data, np.int8) == CELL_OCCUPIED).any()
    finally:
        node.close()
        node.destroy_node()


def test_set_parameters_applies_to_the_next_frame(local_node: DetectorNode) -> None:
    result = local_node.set_parameters([Parameter('max_slope_deg', value=45.0),
                                        Parameter('validation_neighbours', value=3)])

    assert all(r.successful for r in result)
    params = local_node.config.detector.params
    assert params.max_slope_rad == math.radians(45.0) and params.validation_neighbours == 3


def test_zero_fallback_focal_length_is_refused(local_node: DetectorNode) -> None:
    result = local_node.set_parameters([Parameter('fallback_fx', value=0.0)])[0]
    assert not result.successful and 'focal lengths must be > 0' in result.reason


def test_unexpected_pipeline_exception_is_survived(local_node: DetectorNode,
                                                   monkeypatch: pytest.MonkeyPatch,
                                                   scene: SceneFrame) -> None:
    local_node.set_parameters([Parameter('use_fallback_intrinsics', value=True),
                               Parameter('fallback_fx', value=scene.intrinsics.fx),
                               Parameter('fallback_fy', value=scene.intrinsics.fy),
                               Parameter('fallback_cx', value=scene.intrinsics.cx),
                               Parameter('fallback_cy', value=scene.intrinsics.cy)])
    assert local_node.config.fallback_intrinsics == Intrinsics(
        scene.intrinsics.fx, scene.intrinsics.fy, scene.intrinsics.cx, scene.intrinsics.cy)

    def boom(*args: Any, **kwargs: Any) -> None:
        raise RuntimeError('boom')

    monkeypatch.setattr(local_node.config.detector, 'process', boom)
    assert not local_node.handle_frame(_depth_image(scene))
    assert local_node.stats.take(reader='log').errors == 1
    monkeypatch.undo()
    assert local_node.handle_frame(_depth_image(scene))
    assert local_node.stats.take(reader='log').processed == 1


def test_one_frame_mailbox_keeps_only_the_newest() -> None:
    slot = FrameMailbox(1)
    assert slot.take(timeout=0.0) is None
    assert not slot.put('a')
    assert slot.put('b') and slot.put('c')

    assert slot.take(timeout=0.0) == 'c'
    assert slot.take(timeout=0.0) is None


def test_frame_mailbox_lets_one_frame_wait_and_drops_the_oldest() -> None:
    box = FrameMailbox(2)
    assert not box.put('a') and not box.put('b')      # one waits behind the other: no drop
    assert box.put('c')                               # full: the oldest ('a') goes
    assert [box.take(timeout=0.0) for _ in range(3)] == ['b', 'c', None]
    done: list = []
    waiter = threading.Thread(target=lambda: done.append(box.take(timeout=5.0)))
    waiter.start()
    box.put('d')                                      # wakes a waiting take
    waiter.join(5.0)
    assert done == ['d']
    assert node_module.MAILBOX_FRAMES == 2
    box.put('e')
    box.close()                                       # closed: nothing more is taken
    assert box.take() is None


def test_every_parameter_has_a_description_and_numbers_a_range(
        local_node: DetectorNode) -> None:
    names = [spec.name for spec in ALL_PARAMS]
    for descriptor in local_node.describe_parameters(names):
        assert descriptor.description, descriptor.name
        if descriptor.type == ParameterType.PARAMETER_DOUBLE:
            assert len(descriptor.floating_point_range) == 1, descriptor.name
        if descriptor.type == ParameterType.PARAMETER_INTEGER:
            assert len(descriptor.integer_range) == 1, descriptor.name
    assert local_node.describe_parameter('reliable_input').read_only


def test_an_integer_for_a_float_stops_the_node_with_file_name_and_fix(tmp_path: Path) -> None:
    # rcl said "invalid parameters: Trying to set parameter ... INTEGER, expecting DOUBLE"
    # without the file or the fix; the tools say "write 30.0": now the node says it too
    bad = tmp_path / 'bad.yaml'
    bad.write_text('obstacle_detector:\n  ros__parameters:\n    max_range_m: 3\n')

    done = ros_env.run_detector(tmp_path, '--ros-args', '--params-file', str(bad),
                                salt=__name__ + ':int-file')

    assert done.returncode == 1
    assert done.stderr == (f"detector: error: {bad}: parameter 'max_range_m' must be a float, "
                           'got 3: write 3.0\n')


def test_invalid_params_file_stops_the_node_with_the_message(tmp_path: Path) -> None:
    bad = tmp_path / 'bad.yaml'
    bad.write_text(CORRIDOR_YAML.read_text().replace('median_kernel: 5 ', 'median_kernel: 4 '))

    done = ros_env.run_detector(tmp_path, '--ros-args', '--params-file', str(bad),
                                salt=__name__ + ':bad-file')

    assert done.returncode == 1
    assert 'invalid parameters: median_kernel=4 must be odd' in done.stdout + done.stderr


def test_use_tf_without_tf2_stops_the_node_with_the_fix(tmp_path: Path) -> None:
    """This venv has no tf2_ros: use_tf:=true exits 1 saying how to get TF or do without."""
    done = ros_env.run_detector(tmp_path, '--ros-args', '--params-file', str(CORRIDOR_YAML),
                                '-p', 'use_tf:=true', salt=__name__ + ':no-tf2')

    assert done.returncode == 1
    assert 'use_tf is true but tf2_ros cannot be imported' in done.stdout + done.stderr
    assert 'source the ROS 2 setup' in done.stdout + done.stderr


def test_diagnostics_report_each_fault_at_its_level(tmp_path: Path, scene: SceneFrame) -> None:
    """/diagnostics over DDS: no frame, no CameraInfo, mostly bad frames, healthy, silence."""
    node = NodeUnderTest(tmp_path, salt='diag')
    reports: list[Any] = []
    node.node.create_subscription(DiagnosticArray, '/diagnostics',
                                  lambda msg: reports.extend(msg.status), RELIABLE)

    def stream(image: Image, info: CameraInfo | None, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            node.send(image, info)     # about 5 Hz (send waits 0.2 s after a CameraInfo)
            node.spin_until(lambda: False, 0.05 if info is None else 0.0)

    def level_after(text: str, timeout: float = 10.0) -> tuple[int, str]:
        start = len(reports)
        assert node.spin_until(lambda: any(text in r.message for r in reports[start:]),
                               timeout), [r.message for r in reports[-5:]]
        found = next(r for r in reports[start:] if text in r.message)
        return found.level, found.message

    try:
        assert node.spin_until(lambda: bool(node.statuses), START_TIMEOUT_S), node.log()
        assert level_after('no depth frame received on /depth/image_raw yet')[0] == ERROR
        stream(_depth_image(scene), None, 2.5)
        level, message = level_after('skipped for bad input', 1.0)
        assert level == ERROR and '(no_camera_info ' in message
        stream(_depth_image(scene), _camera_info(scene), 2.5)
        assert node.spin_until(lambda: reports[-1].level == OK, 10.0), reports[-1].message
        assert reports[-1].message.endswith('frames/s processed')
        values = {kv.key: kv.value for kv in reports[-1].values}
        assert values['code path'] == 'compiled numba kernels'
        assert reports[-1].hardware_id == '/depth/image_raw'
        bad = _depth_image(scene)
        bad.encoding = 'rgb8'
        stream(bad, _camera_info(scene), 2.5)
        level, message = level_after('skipped for bad input', 1.0)
        assert level == ERROR and '(image ' in message
        assert level_after('no depth frame for', 5.0)[0] == ERROR
    finally:
        node.close()


def test_compressed_depth_input_gives_the_raw_frames_outputs(
        tmp_path: Path, scene: SceneFrame, corridor_params: Any) -> None:
    """depth_transport compressedDepth: PNG-compressed 16UC1 frames, bit-identical depth."""
    node = NodeUnderTest(tmp_path, salt='compressed',
                         extra_args=('-p', 'depth_transport:=compressedDepth'))
    try:
        compressed_pub = node.node.create_publisher(
            CompressedImage, 'depth/image_raw/compressedDepth', RELIABLE)
        assert node.spin_until(lambda: node.connected(compressed_pub), START_TIMEOUT_S), \
            node.log()
        expected = Detector(corridor_params).process(scene.depth_mm, scene.intrinsics)
        for _ in range(3):
            stamp = node.next_stamp()
            info = _camera_info(scene)
            info.header.stamp = stamp
            node.info_pub.publish(info)
            node.spin_until(lambda: False, 0.2)
            compressed_pub.publish(array_to_compressed_depth(scene.depth_mm, stamp,
                                                             'depth_optical'))
            out = node.outputs(stamp)
            if out is not None:
                break
        assert out is not None, node.log()
        _assert_matches(out, expected)

        start = len(node.lines)
        broken = array_to_compressed_depth(scene.depth_mm, node.next_stamp(), 'depth_optical')
        broken.data = bytes(broken.data)[:200]
        compressed_pub.publish(broken)
        assert node.wait_for_log('skipping depth frame: ', start), node.log()
        assert node.process.poll() is None
    finally:
        node.close()


def test_help_lists_every_parameter_and_starts_no_node(tmp_path: Path) -> None:
    done = ros_env.run_detector(tmp_path, '--help', salt=__name__ + ':help')

    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith('usage: detector')
    for spec in ALL_PARAMS:
        line = next(ln for ln in done.stdout.splitlines() if ln.startswith(f'  {spec.name}  '))
        assert spec.type_name in line and spec.range_text in line
        assert spec.description in done.stdout
    assert 'ready' not in done.stderr and not list((tmp_path / 'ros_log').glob('*'))


@pytest.mark.parametrize('content, expected', [
    (None, 'cannot read params file (No such file or directory)'),
    ('obstacle_detector: [\n', 'not valid YAML'),
])
def test_unreadable_params_file_is_one_clear_line(tmp_path: Path, content: str | None,
                                                  expected: str) -> None:
    path = tmp_path / 'params.yaml'
    if content is not None:
        path.write_text(content)

    done = ros_env.run_detector(tmp_path, '--ros-args', '--params-file', str(path),
                              salt=__name__ + ':unread')

    assert done.returncode == 1
    assert done.stderr.count('\n') == 1 and 'Traceback' not in done.stderr, done.stderr
    assert done.stderr.startswith(f'detector: error: {path}: {expected}')


@pytest.mark.parametrize('key, node_fqn, applies', [
    ('obstacle_detector', NODE, True), ('/obstacle_detector', NODE, True), ('/**', NODE, True),
    ('/**/obstacle_detector', NODE, True), ('/*', NODE, True), ('detector', NODE, False),
    ('/robot/obstacle_detector', NODE, False), ('obstacle_detection', NODE, False),
    # in a namespace: the shipped files' key still names the node, a bare name no longer does
    ('/**/obstacle_detector', '/x/obstacle_detector', True), ('/**', '/x/obstacle_detector', True),
    ('/x/obstacle_detector', '/x/obstacle_detector', True),
    ('obstacle_detector', '/x/obstacle_detector', False),
    ('/*', '/x/obstacle_detector', False)])
def test_params_file_sections_are_matched_as_rcl_does(tmp_path: Path, key: str, node_fqn: str,
                                                      applies: bool) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text(f'{key}:\n  ros__parameters:\n    median_kernel: 5\n')

    problems = params_file_problems(path, node_fqn)

    assert problems == ([] if applies else [
        f"{path}: section '{key}' does not name this node ({node_fqn}) and is ignored "
        '(use "/**/obstacle_detector:" or "/**:")'])


def test_rclpys_own_parameters_in_a_params_file_are_not_unknown(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/**/obstacle_detector:\n  ros__parameters:\n    use_sim_time: true\n'
                    '    use_sim_tme: true\n')

    assert params_file_problems(path) == [
        f"{path}: unknown parameter 'use_sim_tme' is ignored (did you mean 'use_sim_time'?); "
        '`detector --help` lists the parameters']


def test_params_file_problems_name_unknown_parameters(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/**:\n  ros__parameters:\n    median_kernel: 5\n    voxl_x_m: 0.02\n'
                    '    zzz: 1\n')

    problems = params_file_problems(path)

    assert params_file_problems(CORRIDOR_YAML) == []
    assert problems == [
        f"{path}: unknown parameter 'voxl_x_m' is ignored (did you mean 'voxel_x_m'?); "
        '`detector --help` lists the parameters',
        f"{path}: unknown parameter 'zzz' is ignored; `detector --help` lists the parameters"]


def test_node_warns_about_a_params_file_it_would_ignore(tmp_path: Path) -> None:
    wrong = tmp_path / 'wrong.yaml'
    wrong.write_text('detector:\n  ros__parameters:\n    median_kernel: 5\n'
                     'obstacle_detector:\n  ros__parameters:\n    max_slope: 20.0\n')
    env = ros_env.loopback_env(__name__ + ':wrong-file', log_dir=tmp_path / 'ros_log')
    process = subprocess.Popen(ros_env.detector_command() + ['--ros-args', '--params-file',
                                                             str(wrong)],
                               env=env, cwd=tmp_path, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    try:
        for line in process.stdout:
            lines.append(line)
            if 'did you mean' in line:
                break
    finally:
        process.send_signal(signal.SIGINT)
        process.wait(timeout=15)
    log = ''.join(lines)
    assert "section 'detector' does not name this node (/obstacle_detector) and is" in log
    assert "unknown parameter 'max_slope' is ignored (did you mean 'max_slope_deg'?)" in log


def test_refiner_model_file_is_validated_and_used(local_node: DetectorNode, tmp_path: Path,
                                                 scene: SceneFrame) -> None:
    from obstacle_detection.pipeline.refine import LogisticRefiner, RefinedDetector

    missing = tmp_path / 'missing.json'
    result = local_node.set_parameters([Parameter('refiner_model_file', value=str(missing))])[0]
    assert not result.successful and 'missing.json' in result.reason
    assert isinstance(local_node.config.detector, Detector)

    # a model that calls every pixel with a voxel an obstacle: the costmap must follow it
    everything = LogisticRefiner((50.0,) + (0.0,) * 9, (0.0,) * 9, (1.0,) * 9)
    path = tmp_path / 'refiner.json'
    everything.save(path)
    assert local_node.set_parameters([Parameter('refiner_model_file', value=str(path))])[0] \
        .successful
    assert isinstance(local_node.config.detector, RefinedDetector)
    out = local_node.config.detector.process(scene.depth_mm, scene.intrinsics)
    assert (out.voxel_is_obstacle.mean() > 0.9) and 'refine' in out.timings_ms
