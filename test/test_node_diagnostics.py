"""What a robot builder reads on /diagnostics, from a node built in-process.

The status is named and identified as diagnostic_updater does (ros/diagnostics, ros2-jazzy,
diagnostic_updater/_diagnostic_updater.py: ``Updater.publish`` writes ``<node name>: <task>``,
``Updater.__init__`` reads ``diagnostic_updater.use_fqn``, ``Updater.setHardwareID`` sets one
hardware_id); it says which intrinsics the frames used and the slowest frame of the period.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
import rclpy
import ros_env
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus

from obstacle_detection.pipeline.params import SEED_TABLE_4_1, table_4_2
from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info
from obstacle_detection.ros.node import DetectorNode
from obstacle_detection.sim.scenes import SceneFrame, render_scene

CORRIDOR_YAML = ros_env.REPO_ROOT / 'params' / 'corridor.yaml'
TASK = 'depth obstacle detection'
SLOW_S = 0.25


@pytest.fixture(scope='module')
def scene() -> SceneFrame:
    params = table_4_2()
    return render_scene('corridor', seed=3, height_m=params.camera_height_m,
                        pitch_rad=params.camera_pitch_rad, roll_rad=params.camera_roll_rad)


def _node(context: rclpy.Context, *args: str, namespace: str | None = None) -> DetectorNode:
    return DetectorNode(context=context, namespace=namespace,
                        cli_args=['--ros-args', '--params-file', str(CORRIDOR_YAML), *args])


def _report(node: DetectorNode, monkeypatch: pytest.MonkeyPatch) -> DiagnosticStatus:
    sent = ros_env.sent(node, '/diagnostics', monkeypatch)
    node.publish_diagnostics()
    (status,) = sent[-1].status
    return status


def _values(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _frame(scene: SceneFrame) -> Any:
    return array_to_image(scene.depth_mm, stamp=Time(), frame_id='depth_optical')


def test_fallback_intrinsics_warn_and_the_slow_frame_is_reported(
        local_context: rclpy.Context, scene: SceneFrame, monkeypatch: pytest.MonkeyPatch) -> None:
    node = _node(local_context, '-p', 'use_fallback_intrinsics:=true')
    try:
        assert node.handle_frame(_frame(scene))           # no CameraInfo: the fallback
        process = node.config.detector.process

        def slow(*args: Any, **kwargs: Any) -> Any:
            time.sleep(SLOW_S)
            return process(*args, **kwargs)

        monkeypatch.setattr(node.config.detector, 'process', slow)
        assert node.handle_frame(_frame(scene))
        monkeypatch.undo()
        status = _report(node, monkeypatch)
        values = _values(status)
        fallback = (f'fx={SEED_TABLE_4_1.fx:g} fy={SEED_TABLE_4_1.fy:g} '
                    f'cx={SEED_TABLE_4_1.cx:g} cy={SEED_TABLE_4_1.cy:g}')

        assert status.level == DiagnosticStatus.WARN
        assert status.message == (f'2 of 2 frames used the fallback intrinsics {fallback}: '
                                  'no CameraInfo on /depth/camera_info')
        assert values['intrinsics'] == (f'fallback {fallback} '
                                        '(no CameraInfo on /depth/camera_info)')
        assert float(values['processing max [ms]']) >= SLOW_S * 1e3
        assert float(values['processing mean [ms]']) < float(values['processing max [ms]'])

        height, width = scene.depth_mm.shape
        ros_env.deliver(node, '/depth/camera_info', intrinsics_to_camera_info(
            scene.intrinsics, width, height, stamp=Time(), frame_id='depth_optical'))
        assert node.handle_frame(_frame(scene))
        after = _report(node, monkeypatch)

        assert _values(after)['intrinsics'] == 'CameraInfo on /depth/camera_info'
        assert 'fallback' not in after.message
    finally:
        node.close()
        node.destroy_node()


def test_name_and_hardware_id_are_diagnostic_updaters_and_stay_put(
        local_context: rclpy.Context, scene: SceneFrame, monkeypatch: pytest.MonkeyPatch) -> None:
    node = _node(local_context, '-r', 'depth/image_raw:=/camera/camera/depth/image_rect_raw',
                 namespace='front')
    try:
        before = _report(node, monkeypatch)
        height, width = scene.depth_mm.shape
        ros_env.deliver(node, '/front/depth/camera_info', intrinsics_to_camera_info(
            scene.intrinsics, width, height, stamp=Time(), frame_id='depth_optical'))
        assert node.handle_frame(_frame(scene))
        after = _report(node, monkeypatch)
    finally:
        node.close()
        node.destroy_node()

    # Updater: node_name = node.get_name() unless diagnostic_updater.use_fqn
    assert before.name == after.name == f'obstacle_detector: {TASK}'
    # one hardware_id for the node's life, the frames' frame_id not taken in
    assert before.hardware_id == after.hardware_id == '/camera/camera/depth/image_rect_raw'


@pytest.mark.parametrize(('args', 'names'), [
    ((), [f'obstacle_detector: {TASK}'] * 2),
    (('-p', 'diagnostic_updater.use_fqn:=true'),
     [f'/front/obstacle_detector: {TASK}', f'/rear/obstacle_detector: {TASK}']),
])
def test_two_namespaced_nodes_need_use_fqn_for_two_names(
        local_context: rclpy.Context, monkeypatch: pytest.MonkeyPatch, args: tuple[str, ...],
        names: list[str]) -> None:
    nodes = [_node(local_context, *args, namespace=ns) for ns in ('front', 'rear')]
    try:
        reports = [_report(node, monkeypatch) for node in nodes]
        use_fqn = [node.get_parameter('diagnostic_updater.use_fqn').value for node in nodes]
    finally:
        for node in nodes:
            node.close()
            node.destroy_node()

    assert [r.name for r in reports] == names
    assert [r.hardware_id for r in reports] == ['/front/depth/image_raw', '/rear/depth/image_raw']
    assert use_fqn == [bool(args)] * 2
