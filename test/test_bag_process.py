"""Tests of tools/bag_process.py: offline output equals the node's messages for the same frames."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader, Writer
from rosbags.typesys import Stores, get_typestore
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2

from message_helpers import array_to_compressed_depth
from obstacle_detection.viz.overlay import render_overlay
from obstacle_detection.ros.conversions import (array_to_image, image_to_array,
                                            intrinsics_to_camera_info, result_to_messages)
from obstacle_detection.pipeline.params import KINECT_V2_SD, Intrinsics
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.ros.parameters import detector_params_from_ros
from obstacle_detection.sim.scenes import render_scene
from obstacle_detection.cli import bag_writer
from obstacle_detection.cli import bag_processor
from obstacle_detection.tools import bag_convert, bag_process

REPO = Path(__file__).resolve().parents[1]
JAZZY = get_typestore(Stores.ROS2_JAZZY)
DEPTH = bag_writer.DEFAULT_DEPTH_TOPIC
INFO = bag_writer.DEFAULT_INFO_TOPIC
SIZE = (128, 106)  # a quarter of the Kinect v2 SD image
INTR = Intrinsics(KINECT_V2_SD.fx / 4, KINECT_V2_SD.fy / 4, KINECT_V2_SD.cx / 4,
                  KINECT_V2_SD.cy / 4)
FRAME_ID = 'kinect2_ir_optical_frame'
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333
#: Parameters of the tests: the node's format, small kernels for a small image.
PARAMS_YAML = """\
obstacle_detector:
  ros__parameters:
    median_kernel: 5
    normal_neighbours: 8
    validation_neighbours: 6
    max_range_m: 2.5
    costmap_length_m: 2.5
    cloud_frame_id: base_link
    publish_ground: true
    publish_overlay: true
"""
PARAM_VALUES = {'median_kernel': 5, 'normal_neighbours': 8, 'validation_neighbours': 6,
                'max_range_m': 2.5, 'costmap_length_m': 2.5}
OUTPUT_TOPICS = {'obstacles': '/obstacles/points', 'costmap': '/obstacles/costmap',
                 'ground': '/obstacles/ground_points', 'overlay': '/obstacles/overlay'}
OUTPUT_TYPES = {'/obstacles/points': PointCloud2, '/obstacles/costmap': OccupancyGrid,
                '/obstacles/ground_points': PointCloud2, '/obstacles/overlay': Image}


def to_time(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def frames() -> list[np.ndarray]:
    return [render_scene(name, seed=k, intrinsics=INTR, size=SIZE).depth_mm
            for k, name in enumerate(('corridor', 'people', 'corridor'))]


def write_bag(path: Path, items: list[tuple[str, int, object]]) -> None:
    """Return a rosbag2 with (topic, bag timestamp, rclpy message) items, in the order given."""
    with Writer(path, version=9) as writer:
        conns = {}
        for topic, _, msg in items:
            if topic not in conns:
                msgtype = type(msg).__module__.split('.')[0] + '/msg/' + type(msg).__name__
                conns[topic] = writer.add_connection(topic, msgtype, typestore=JAZZY)
        for topic, timestamp, msg in items:
            writer.write(conns[topic], timestamp, serialize_message(msg))


def read_raw(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    topics: dict[str, list[tuple[int, bytes]]] = {}
    with Reader(path) as reader:
        for conn, timestamp, raw in reader.messages():
            topics.setdefault(conn.topic, []).append((timestamp, bytes(raw)))
    return topics


def frame_messages(depths: list[np.ndarray], intr: Intrinsics = INTR
                   ) -> list[tuple[str, int, object]]:
    items: list[tuple[str, int, object]] = []
    for k, depth in enumerate(depths):
        t = T0_NS + k * PERIOD_NS
        info = intrinsics_to_camera_info(intr, SIZE[0], SIZE[1], stamp=to_time(t),
                                         frame_id=FRAME_ID)
        items.append((INFO, t, info))
        items.append((DEPTH, t, array_to_image(depth, stamp=to_time(t), frame_id=FRAME_ID)))
    return items


def expected_outputs(depth: np.ndarray, intr: Intrinsics, t: int) -> dict[str, object]:
    """Return the messages result_to_messages gives in-process for one frame, as they read back.

    A serialization round trip stores float32 fields (OccupancyGrid's resolution) as float32,
    so the in-process messages are compared after one.
    """
    detector = Detector(detector_params_from_ros(PARAM_VALUES))
    result = detector.process(depth, intr)
    messages = result_to_messages(
        result, stamp=to_time(t), cloud_frame_id='base_link',
        costmap_frame_id='base_footprint', image_frame_id=FRAME_ID, with_ground=True,
        overlay_rgb=render_overlay(result.depth_m, result.labels))
    return {key: deserialize_message(serialize_message(msg), type(msg))
            for key, msg in messages.items()}


def decoded(topic: str, raw: bytes) -> object:
    """Return the rclpy message of a serialized output.

    Messages are compared field by field, not as bytes: rclpy leaves CDR padding bytes
    uninitialised, so equal messages may serialize to different bytes.
    """
    return deserialize_message(raw, OUTPUT_TYPES[topic])


@pytest.fixture(scope='module')
def processed(tmp_path_factory: pytest.TempPathFactory, depths: list[np.ndarray],
              params_file: Path) -> tuple[Path, Path, str]:
    """(input bag, output bag, stdout) of one offline run over the frames."""
    root = tmp_path_factory.mktemp('process')
    write_bag(root / 'in', frame_messages(depths))
    out = subprocess.run(
        [sys.executable, str(REPO / 'tools' / 'bag_process.py'), str(root / 'in'),
         str(root / 'out'), '--params-file', str(params_file)],
        cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return root / 'in', root / 'out', out.stdout


def test_outputs_equal_result_to_messages_in_process(
        processed: tuple[Path, Path, str], depths: list[np.ndarray]) -> None:
    _, out_bag, _ = processed
    got = read_raw(out_bag)
    for key, topic in OUTPUT_TOPICS.items():
        assert len(got[topic]) == len(depths)
    for k, depth in enumerate(depths):
        t = T0_NS + k * PERIOD_NS
        want = expected_outputs(depth, INTR, t)
        for key, topic in OUTPUT_TOPICS.items():
            timestamp, raw = got[topic][k]
            assert timestamp == t
            assert decoded(topic, raw) == want[key], f'{topic} of frame {k} differs'


def test_inputs_are_copied_unchanged(processed: tuple[Path, Path, str]) -> None:
    in_bag, out_bag, _ = processed
    source, copy = read_raw(in_bag), read_raw(out_bag)
    for topic in (DEPTH, INFO):
        assert copy[topic] == source[topic]


def test_output_stamps_and_types_read_back(processed: tuple[Path, Path, str]) -> None:
    _, out_bag, stdout = processed
    with Reader(out_bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, timestamp, raw in reader.messages():
            msg = JAZZY.deserialize_cdr(raw, conn.msgtype)
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == timestamp
    assert types['/obstacles/points'] == 'sensor_msgs/msg/PointCloud2'
    assert types['/obstacles/costmap'] == 'nav_msgs/msg/OccupancyGrid'
    assert types['/obstacles/overlay'] == 'sensor_msgs/msg/Image'
    assert 'processed 3, skipped 0' in stdout


def test_camera_info_recorded_before_each_frame_matched_by_stamp(
        tmp_path: Path, depths: list[np.ndarray], params_file: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """As the node: the stamp nearest the frame's, else the newest if all agree, else skip."""
    other = Intrinsics(INTR.fx * 1.2, INTR.fy * 1.2, INTR.cx + 3, INTR.cy - 2)
    t = [T0_NS + k * PERIOD_NS for k in range(4)]
    stamp = [to_time(x) for x in t]
    info = [intrinsics_to_camera_info(i, SIZE[0], SIZE[1], stamp=s, frame_id=FRAME_ID)
            for i, s in ((INTR, stamp[0]), (other, stamp[2]))]
    items = [
        (DEPTH, t[0], array_to_image(depths[0], stamp=stamp[0], frame_id=FRAME_ID)),
        (INFO, t[0] + 1, info[0]),  # after frame 0: frame 0 has no camera info
        (DEPTH, t[1], array_to_image(depths[1], stamp=stamp[1], frame_id=FRAME_ID)),
        (DEPTH, t[2], array_to_image(depths[2], stamp=stamp[2], frame_id=FRAME_ID)),
        (INFO, t[2], info[1]),  # written after, same bag time as frame 2: counts as before it
        # stamped between the two CameraInfos, which disagree: the node skips it
        (DEPTH, t[3], array_to_image(depths[0], stamp=to_time((t[0] + t[2]) // 2),
                                     frame_id=FRAME_ID)),
    ]
    write_bag(tmp_path / 'in', items)
    code = bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--params-file',
                             str(params_file)])
    out = capsys.readouterr().out
    assert code == 0
    assert 'no camera info recorded before the frame' in out
    assert 'while the recent CameraInfos disagree' in out
    got = read_raw(tmp_path / 'out')
    assert [ts for ts, _ in got['/obstacles/costmap']] == [t[1], t[2]]
    points = [decoded('/obstacles/points', raw) for _, raw in got['/obstacles/points']]
    assert points[0] == expected_outputs(depths[1], INTR, t[1])['obstacles']
    assert points[1] == expected_outputs(depths[2], other, t[2])['obstacles']
    assert points[0] != expected_outputs(depths[1], other, t[1])['obstacles']


def test_node_param_values_match_the_node_format(params_file: Path) -> None:
    values = bag_processor.node_param_values(params_file)
    assert values['median_kernel'] == 5 and values['publish_ground'] is True
    config = bag_processor.config_from_values(values, str(params_file))
    assert config.detector.params == detector_params_from_ros(PARAM_VALUES)
    corridor = bag_processor.node_param_values(REPO / 'params' / 'corridor.yaml')
    assert bag_processor.config_from_values(corridor, 'corridor').detector.params.median_kernel \
        == 5


@pytest.mark.parametrize(('text', 'match'), [
    ('obstacle_detector:\n  ros__parameters:\n    voxel_x_m: 1\n', "voxel_x_m.*float"),
    ('other_node:\n  ros__parameters: {}\n', 'no section naming the node'),
    ('obstacle_detector:\n  ros__parameters:\n    median_kernel: 4\n', 'median_kernel'),
])
def test_bad_params_file(tmp_path: Path, text: str, match: str, depths: list[np.ndarray],
                         capsys: pytest.CaptureFixture[str]) -> None:
    write_bag(tmp_path / 'in', frame_messages(depths[:1]))
    bad = tmp_path / 'bad.yaml'
    bad.write_text(text)
    code = bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--params-file',
                             str(bad)])
    err = capsys.readouterr().err
    assert code == 1
    assert str(bad) in err
    assert re.search(match, err)
    assert not (tmp_path / 'out').exists()


def test_a_misspelt_parameter_is_the_nodes_warning(tmp_path: Path, depths: list[np.ndarray],
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    # the node ignores it with a did-you-mean warning; bag_process refused the file: now the
    # same warning, and the run goes on with the other values
    write_bag(tmp_path / 'in', frame_messages(depths[:1]))
    typo = tmp_path / 'typo.yaml'
    typo.write_text('obstacle_detector:\n  ros__parameters:\n    max_rnge_m: 3.0\n'
                    '    median_kernel: 5\n')
    code = bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--params-file',
                             str(typo), '--quiet'])
    err = capsys.readouterr().err
    assert code == 0
    assert (f"warning: {typo}: unknown parameter 'max_rnge_m' is ignored (did you mean "
            "'max_range_m'?); `detector --help` lists the parameters\n") in err


def test_bad_bags(tmp_path: Path, depths: list[np.ndarray],
                  capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / 'missing'
    assert bag_process.main([str(missing), str(tmp_path / 'out')]) == 1
    assert str(missing) in capsys.readouterr().err
    write_bag(tmp_path / 'in', frame_messages(depths[:1]))
    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--depth-topic',
                             '/nope']) == 1
    err = capsys.readouterr().err
    assert '/nope' in err and DEPTH in err
    (tmp_path / 'exists').mkdir()
    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'exists')]) == 1
    assert str(tmp_path / 'exists') in capsys.readouterr().err
    assert list((tmp_path / 'exists').iterdir()) == []
    assert not list(tmp_path.glob('.*partial*'))


# -------------------------------------------------------------------------------------------
# The running node gives the same messages as the offline run.


@pytest.fixture()
def node_env(tmp_path: Path) -> Iterator[dict[str, str]]:
    import ros_env

    env = ros_env.loopback_env('test_bag_process', log_dir=tmp_path / 'ros_log')
    env['PYTHONPATH'] = os.pathsep.join([str(REPO), env.get('PYTHONPATH', '')])
    old = ros_env.apply(env)
    yield env
    ros_env.restore(old)


def test_running_node_publishes_the_offline_messages(
        processed: tuple[Path, Path, str], params_file: Path, node_env: dict[str, str],
        tmp_path: Path) -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    in_bag, out_bag, _ = processed
    offline = read_raw(out_bag)
    inputs = read_raw(in_bag)
    log = (tmp_path / 'node.log').open('w')
    node_proc = subprocess.Popen(
        [sys.executable, '-m', 'obstacle_detection.ros.node', '--ros-args', '--params-file',
         str(params_file), '-p', 'reliable_input:=true', '-r', f'depth/image_raw:={DEPTH}',
         '-r', f'depth/camera_info:={INFO}'],
        cwd=REPO, env=node_env, stdout=log, stderr=subprocess.STDOUT)
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = Node('node_equality_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    # Outputs by header stamp: a frame is resent until its outputs come (see below).
    received: dict[str, dict[tuple[int, int], object]] = {t: {} for t in OUTPUT_TOPICS.values()}

    def keep(topic: str, msg: object) -> None:
        received[topic][(msg.header.stamp.sec, msg.header.stamp.nanosec)] = msg

    try:
        subs = [node.create_subscription(OUTPUT_TYPES[topic], topic,
                                         lambda m, t=topic: keep(t, m), reliable)
                for topic in OUTPUT_TOPICS.values()]
        depth_pub = node.create_publisher(Image, DEPTH, reliable)
        info_pub = node.create_publisher(CameraInfo, INFO, reliable)

        def spin_until(done, timeout_s: float) -> bool:
            deadline = time.monotonic() + timeout_s
            while not done():
                if time.monotonic() > deadline or node_proc.poll() is not None:
                    return False
                executor.spin_once(timeout_sec=0.05)
            return True

        assert spin_until(lambda: depth_pub.get_subscription_count() and
                          info_pub.get_subscription_count() and
                          all(s.get_publisher_count() for s in subs), 30.0), 'no node'
        stamps = []
        for k, ((_, info_raw), (_, depth_raw)) in enumerate(zip(inputs[INFO], inputs[DEPTH])):
            stamp = divmod(inputs[DEPTH][k][0], 1_000_000_000)
            stamps.append(stamp)
            # Discovery may match our writer on the node's side a moment after ours: a sample
            # sent before that is not delivered (volatile reader), so resend until outputs come.
            for _ in range(15):
                info_pub.publish(info_raw)
                spin_until(lambda: False, 0.2)  # let the node take the camera info first
                depth_pub.publish(depth_raw)
                if spin_until(lambda: all(stamp in v for v in received.values()), 2.0):
                    break
            else:
                pytest.fail(f'no output for frame {k}')
        for topic, by_stamp in received.items():
            offline_messages = [decoded(topic, raw) for _, raw in offline[topic]]
            assert [by_stamp[stamp] for stamp in stamps] == offline_messages, topic
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
        node_proc.terminate()
        node_proc.wait(timeout=10)
        log.close()


def test_deserialized_offline_messages_are_rclpy_readable(processed: tuple[Path, Path, str]
                                                          ) -> None:
    _, out_bag, _ = processed
    got = read_raw(out_bag)
    grid = deserialize_message(got['/obstacles/costmap'][0][1], OccupancyGrid)
    assert grid.header.frame_id == 'base_footprint'
    assert grid.info.width > 0 and len(grid.data) == grid.info.width * grid.info.height


def test_several_params_files_are_merged_in_order(tmp_path: Path) -> None:
    # as ROS: a later file wins for a parameter both set, the others keep the earlier values
    first = tmp_path / 'first.yaml'
    first.write_text('obstacle_detector:\n  ros__parameters:\n    median_kernel: 5\n'
                     '    max_range_m: 3.0\n')
    second = tmp_path / 'second.yaml'
    second.write_text('obstacle_detector:\n  ros__parameters:\n    median_kernel: 7\n'
                      '    camera_height_m: 1.25\n')
    values = bag_processor.node_param_values([first, second])
    assert (values['median_kernel'], values['max_range_m'], values['camera_height_m']) == (
        7, 3.0, 1.25)
    args = bag_process.build_parser().parse_args(
        ['in', 'out', '--params-file', str(first), '--params-file', str(second)])
    assert args.params_file == [first, second]


def test_merged_params_files_reach_the_output(tmp_path: Path, depths: list[np.ndarray],
                                              params_file: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    # the second file changes the range: the output equals a run with both values
    write_bag(tmp_path / 'in', frame_messages(depths[:1]))
    shorter = tmp_path / 'shorter.yaml'
    shorter.write_text('obstacle_detector:\n  ros__parameters:\n    max_range_m: 1.5\n')
    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--quiet',
                             '--params-file', str(params_file), '--params-file',
                             str(shorter)]) == 0
    got = read_raw(tmp_path / 'out')
    points = decoded('/obstacles/points', got['/obstacles/points'][0][1])
    values = dict(PARAM_VALUES, max_range_m=1.5)
    result = Detector(detector_params_from_ros(values)).process(depths[0], INTR)
    cloud = np.frombuffer(bytes(points.data), np.float32).reshape(-1, 3)
    assert cloud.shape[0] == result.obstacle_points.shape[0] > 0
    assert cloud[:, 0].max() <= 1.5 + 1e-6


def test_a_folder_that_is_not_a_bag_is_one_clear_line(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / 'frames'
    folder.mkdir()
    (folder / 'depth.png').write_bytes(b'')
    assert bag_process.main([str(folder), str(tmp_path / 'out')]) == 1
    captured = capsys.readouterr()
    assert captured.err == (f'error: {folder}: not a bag: no metadata.yaml in the folder; '
                            'expected a rosbag2 folder (holding metadata.yaml)\n')
    assert not (tmp_path / 'out').exists()
    ros1 = tmp_path / 'old.bag'
    ros1.write_bytes(b'#ROSBAG V2.0\n')
    assert bag_process.main([str(ros1), str(tmp_path / 'out')]) == 1
    assert 'a ROS 1 bag: convert it first with tools/bag_convert.py ros1' in \
        capsys.readouterr().err


def test_camera_info_is_found_by_type(tmp_path: Path, depths: list[np.ndarray],
                                      capsys: pytest.CaptureFixture[str]) -> None:
    # the camera info is on a topic of another name: found by its type, and said so
    items = [('/cam/camera_info' if topic == INFO else topic, t, msg)
             for topic, t, msg in frame_messages(depths[:2])]
    write_bag(tmp_path / 'in', items)
    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--quiet']) == 0
    out = capsys.readouterr().out
    assert 'depth frames: 2, processed 2, skipped 0' in out
    assert 'intrinsics: CameraInfo on /cam/camera_info (found by type' in out
    assert ("camera mount: height 0.60 m, pitch 0.0 deg, roll 0.0 deg (the node's defaults: no "
            'params file changes it)') in out
    # an --info-topic that is not a CameraInfo is refused, naming the bag
    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out2'), '--info-topic',
                             DEPTH]) == 1
    assert f'error: {tmp_path / "in"}: {DEPTH} has type sensor_msgs/msg/Image' in \
        capsys.readouterr().err


def test_a_mount_far_from_the_floor_is_a_warning(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    # a flat floor seen from 1.2 m, processed with the node's default mount (0.6 m, level)
    floor = render_scene('flat_floor', seed=0, intrinsics=INTR, size=SIZE, height_m=1.2,
                         pitch_rad=np.radians(25.0)).depth_mm
    write_bag(tmp_path / 'in', frame_messages([floor]))
    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--quiet']) == 0
    err = capsys.readouterr().err
    assert re.search(r'warning: frame 1: the floor in view .* puts the camera at height '
                     r'1\.2\d m, pitch 2[45]\.\d deg', err)
    assert 'but the mount used is height 0.60 m, pitch 0.0 deg' in err
    mount = tmp_path / 'mount.yaml'
    mount.write_text('obstacle_detector:\n  ros__parameters:\n    camera_height_m: 1.2\n'
                     '    camera_pitch_deg: 25.0\n')
    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out2'), '--quiet',
                             '--params-file', str(mount)]) == 0
    captured = capsys.readouterr()
    assert 'warning' not in captured.err
    assert f'camera mount: height 1.20 m, pitch 25.0 deg, roll 0.0 deg ({mount})' in \
        captured.out


def test_a_later_frame_off_the_mount_is_a_warning(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    # the mount fits frames 1-3 (1.2 m, pitch 25 deg, level); in frame 4 the camera rolled 8 deg
    # (a bump): the mount was checked on frame 1 only and the floor of frame 4 went unsaid
    depths = [render_scene('flat_floor', seed=k, intrinsics=INTR, size=SIZE, height_m=1.2,
                           pitch_rad=np.radians(25.0),
                           roll_rad=np.radians(8.0 if k == 3 else 0.0)).depth_mm
              for k in range(4)]
    write_bag(tmp_path / 'in', frame_messages(depths))
    mount = tmp_path / 'mount.yaml'
    mount.write_text('obstacle_detector:\n  ros__parameters:\n    camera_height_m: 1.2\n'
                     '    camera_pitch_deg: 25.0\n')
    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--quiet',
                             '--params-file', str(mount)]) == 0
    out, err = capsys.readouterr()
    assert re.fullmatch(r'warning: frame 4: the floor in view .* roll [78]\.\d deg, but the '
                        r'mount used is height 1\.20 m, pitch 25\.0 deg, roll 0\.0 deg: .*\n',
                        err)
    assert '  warning: the floor did not fit the mount in 1 of the checked frames: frame 4' in out


def test_an_interrupted_many_bag_run_resumes(tmp_path: Path, depths: list[np.ndarray],
                                             monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    # Ctrl-C during the second bag: the first is kept and said so; the same command again with
    # --skip-existing processes the rest (it used to say FAILED ... output already exists)
    for i in range(2):
        write_bag(tmp_path / 'bags' / f'bag{i}', frame_messages(depths))
    command = [str(tmp_path / 'bags'), str(tmp_path / 'out'), '--workers', '0', '--quiet']
    real = bag_processor.process_frame
    calls = []

    def interrupted(*args: object, **kwargs: object) -> object:
        calls.append(1)
        if len(calls) == len(depths) + 2:   # the second frame of the second bag
            raise KeyboardInterrupt
        return real(*args, **kwargs)
    monkeypatch.setattr(bag_processor, 'process_frame', interrupted)
    assert bag_process.main(command) == 130
    err = capsys.readouterr().err
    assert f'kept 1 finished output bag: {tmp_path / "out" / "bag0"}' in err
    assert 'the same command with --skip-existing processes the other 1' in err
    monkeypatch.setattr(bag_processor, 'process_frame', real)
    kept = read_raw(tmp_path / 'out' / 'bag0')

    assert bag_process.main(command) == 1   # without the option: one line, nothing done
    out, err = capsys.readouterr()
    assert out == '' and err == (f'error: {tmp_path / "out" / "bag0"}: output already exists '
                                 '(1 of 2); --skip-existing keeps them and processes the rest, '
                                 'or remove them\n')
    assert bag_process.main([*command, '--skip-existing']) == 0
    out, err = capsys.readouterr()
    assert f'kept 1 output bag from an earlier run: {tmp_path / "out" / "bag0"}' in err
    assert '1 ok, 0 failed' in out and str(tmp_path / 'bags' / 'bag1') in out
    assert read_raw(tmp_path / 'out' / 'bag0') == kept
    assert set(read_raw(tmp_path / 'out' / 'bag1')) == set(kept)


def test_many_bags_say_their_intrinsics_and_mount_as_one_bag_does(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    # docs/bags.md: bag_process prints the intrinsics (which CameraInfo topic) and the mount it
    # used; run on many bags (Dask or --workers 0) it printed neither
    for i in range(2):
        write_bag(tmp_path / 'bags' / f'bag{i}', frame_messages(depths[:1]))
    assert bag_process.main([str(tmp_path / 'bags'), str(tmp_path / 'out'), '--workers', '0',
                             '--quiet']) == 0
    out = capsys.readouterr().out.splitlines()
    assert (f'intrinsics: CameraInfo on {INFO} (the default topic): {tmp_path / "bags" / "bag0"}, '
            f'{tmp_path / "bags" / "bag1"}') in out
    assert ("camera mount: height 0.60 m, pitch 0.0 deg, roll 0.0 deg (the node's defaults: no "
            'params file changes it)') in out

def _tf_static(parent: str, child: str, xyz: tuple[float, float, float],
               quaternion: tuple[float, float, float, float]) -> bytes:
    """Return one transform as a serialized tf2_msgs/TFMessage (robot_state_publisher's)."""
    t = JAZZY.types
    header = t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
                                      frame_id=parent)
    transform = t['geometry_msgs/msg/Transform'](
        translation=t['geometry_msgs/msg/Vector3'](x=xyz[0], y=xyz[1], z=xyz[2]),
        rotation=t['geometry_msgs/msg/Quaternion'](*quaternion))
    msg = t['tf2_msgs/msg/TFMessage'](transforms=[t['geometry_msgs/msg/TransformStamped'](
        header=header, child_frame_id=child, transform=transform)])
    return bytes(JAZZY.serialize_cdr(msg, 'tf2_msgs/msg/TFMessage'))


def test_use_tf_takes_the_mount_from_the_bags_tf_static(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    """As the node with TF: the mount from the recorded /tf_static; no transform, no output."""
    from scipy.spatial.transform import Rotation

    from obstacle_detection.pipeline.geometry import mount_rotation

    pitch = math.radians(20.0)
    quaternion = tuple(Rotation.from_matrix(mount_rotation(pitch, 0.0)).as_quat())
    floor = render_scene('corridor', seed=1, intrinsics=INTR, size=SIZE, height_m=0.8,
                         pitch_rad=pitch).depth_mm
    write_bag(tmp_path / 'plain', frame_messages([floor]))
    with Reader(tmp_path / 'plain') as reader, Writer(tmp_path / 'in', version=9) as writer:
        tf_conn = writer.add_connection('/tf_static', 'tf2_msgs/msg/TFMessage',
                                        typestore=JAZZY)
        writer.write(tf_conn, T0_NS - 1, _tf_static('base_link', FRAME_ID, (0.0, 0.0, 0.8),
                                                    quaternion))
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=JAZZY)
                 for c in reader.connections}
        for conn, timestamp, raw in reader.messages():
            writer.write(conns[conn.id], timestamp, raw)
    params = tmp_path / 'tf.yaml'
    params.write_text(PARAMS_YAML + '    use_tf: true\n')

    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--quiet',
                             '--params-file', str(params)]) == 0
    out = capsys.readouterr().out
    assert "camera mount: TF base_link <- kinect2_ir_optical_frame (the bag's /tf_static): " \
        'height 0.80 m, pitch 20.0 deg' in out
    expected = Detector(detector_params_from_ros(dict(
        PARAM_VALUES, camera_height_m=0.8, camera_pitch_deg=20.0))).process(floor, INTR)
    grid = decoded('/obstacles/costmap', read_raw(tmp_path / 'out')['/obstacles/costmap'][0][1])
    np.testing.assert_array_equal(
        np.asarray(grid.data, np.int8).reshape(expected.costmap.data.shape),
        expected.costmap.data)

    # the same frames without /tf_static: skipped with the reason, never the parameters
    assert bag_process.main([str(tmp_path / 'plain'), str(tmp_path / 'out2'), '--quiet',
                             '--params-file', str(params)]) == 0
    out = capsys.readouterr().out
    assert 'depth frames: 1, processed 0, skipped 1' in out
    assert "skipped 1: no transform base_link <- 'kinect2_ir_optical_frame' from TF" in out
    assert 'use_tf is set but the bag has no /tf_static' in out
    assert '/obstacles/costmap' not in read_raw(tmp_path / 'out2')


# --------------------------------------------------------------------------------------------
# Compressed depth topics: the same outputs as the raw depth of the same frames


def _iai_tiff(depth: np.ndarray) -> tuple[str, bytes]:
    """iai_kinect2's depth/compressed (use_png: false): ConfigHeader + TIFF."""
    return '16UC1; compressedDepth', bytes(12) + cv2.imencode('.tif', depth)[1].tobytes()


def _headerless_png(depth: np.ndarray) -> tuple[str, bytes]:
    """image_transport's compressed plugin on a 16UC1 image: a PNG, no header."""
    return '16UC1; png compressed', cv2.imencode('.png', depth)[1].tobytes()


def _compressed_depth(depth: np.ndarray) -> tuple[str, bytes]:
    """compressed_depth_image_transport's compressedDepth: ConfigHeader + PNG."""
    msg = array_to_compressed_depth(depth, Time(), 'f')
    return msg.format, bytes(msg.data)


def _rvl_compressed_depth(depth: np.ndarray) -> tuple[str, bytes]:
    """Return compressedDepth with format rvl (image_transport_plugins 4.0): header + RVL."""
    from rvl_encoder import rvl_message

    msg = rvl_message(depth, Time(), 'f')
    return msg.format, bytes(msg.data)


COMPRESSIONS = {'compressedDepth': ('compressedDepth', _compressed_depth),
                'compressedDepth rvl': ('compressedDepth', _rvl_compressed_depth),
                'iai_kinect2 tiff': ('compressed', _iai_tiff),
                'png': ('compressed', _headerless_png)}


def compressed_items(items: list[tuple[str, int, object]], suffix: str,
                     compress: Callable[[np.ndarray], tuple[str, bytes]],
                     damage: Callable[[int, bytes], bytes] = lambda k, data: data
                     ) -> list[tuple[str, int, object]]:
    """Return the bag items with each raw depth Image replaced by a CompressedImage of it."""
    out: list[tuple[str, int, object]] = []
    for topic, t, msg in items:
        if topic == DEPTH:
            fmt, data = compress(image_to_array(msg))
            msg = CompressedImage(header=msg.header, format=fmt,
                                  data=damage(len(out), data))
            topic = f'{DEPTH}/{suffix}'
        out.append((topic, t, msg))
    return out


def output_messages(bag: Path) -> dict[str, list[tuple[int, object]]]:
    """Return the output topics of a processed bag: (bag timestamp, message) per frame."""
    got = read_raw(bag)
    return {topic: [(t, decoded(topic, raw)) for t, raw in got.get(topic, [])]
            for topic in OUTPUT_TOPICS.values()}


@pytest.fixture(scope='module')
def raw_outputs(tmp_path_factory: pytest.TempPathFactory, depths: list[np.ndarray],
                params_file: Path) -> dict[str, list[tuple[int, object]]]:
    """Process the raw (16UC1) bag of the frames in this process; return its outputs."""
    root = tmp_path_factory.mktemp('raw')
    write_bag(root / 'raw', frame_messages(depths))
    assert bag_process.main([str(root / 'raw'), str(root / 'raw_out'), '--params-file',
                             str(params_file), '--quiet']) == 0
    return output_messages(root / 'raw_out')


@pytest.mark.parametrize('kind', sorted(COMPRESSIONS))
def test_compressed_depth_bag_gives_the_raw_bags_outputs(
        tmp_path: Path, depths: list[np.ndarray], params_file: Path, kind: str,
        raw_outputs: dict[str, list[tuple[int, object]]],
        capsys: pytest.CaptureFixture[str]) -> None:
    suffix, compress = COMPRESSIONS[kind]
    assert max(int(d.max()) for d in depths) <= 10000  # within compressedDepth's 10 m
    write_bag(tmp_path / 'compressed', compressed_items(frame_messages(depths), suffix,
                                                        compress))
    common = ['--params-file', str(params_file), '--quiet']

    assert bag_process.main([str(tmp_path / 'compressed'), str(tmp_path / 'compressed_out'),
                             *common, '--depth-topic', f'{DEPTH}/{suffix}']) == 0

    out = capsys.readouterr().out
    assert f'intrinsics: CameraInfo on {INFO} (the default topic)' in out
    compressed_out = output_messages(tmp_path / 'compressed_out')
    for topic in OUTPUT_TOPICS.values():
        assert len(raw_outputs[topic]) == len(depths)
        assert compressed_out[topic] == raw_outputs[topic], f'{topic} differs'


def test_ros1_iai_kinect2_compressed_bag_gives_the_raw_bags_outputs(
        tmp_path: Path, depths: list[np.ndarray], params_file: Path) -> None:
    # ROS 1 bags as kinect2_bridge records them: raw depth, or its .../compressed (TIFF)
    from test_bag_convert import write_ros1_kinect2

    compressed_topic = f'{DEPTH}/compressed'
    write_ros1_kinect2(tmp_path / 'raw.bag', depths, INTR)
    write_ros1_kinect2(tmp_path / 'compressed.bag', depths, INTR,
                       depth_topic=compressed_topic, compress=_iai_tiff)
    convert = ['ros1', '--quiet']
    assert bag_convert.main([*convert, str(tmp_path / 'raw.bag'), str(tmp_path / 'raw')]) == 0
    assert bag_convert.main([*convert, str(tmp_path / 'compressed.bag'),
                             str(tmp_path / 'kept')]) == 0
    common = ['--params-file', str(params_file), '--quiet']

    for name, extra in (('raw', []), ('kept', ['--depth-topic', compressed_topic])):
        assert bag_process.main([str(tmp_path / name), str(tmp_path / f'{name}_out'),
                                 *common, *extra]) == 0

    want = output_messages(tmp_path / 'raw_out')
    assert all(len(want[topic]) == len(depths) for topic in OUTPUT_TOPICS.values())
    assert output_messages(tmp_path / 'kept_out') == want


def test_a_corrupt_compressed_frame_is_skipped_with_the_reason(
        tmp_path: Path, depths: list[np.ndarray], params_file: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    def truncate_second(index: int, data: bytes) -> bytes:
        return data[:-50] if index == 3 else data  # items: info, depth, info, depth, ...

    write_bag(tmp_path / 'in', compressed_items(frame_messages(depths), 'compressedDepth',
                                                _compressed_depth, truncate_second))

    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--params-file',
                             str(params_file), '--quiet', '--depth-topic',
                             f'{DEPTH}/compressedDepth']) == 0

    out = capsys.readouterr().out
    assert 'depth frames: 3, processed 2, skipped 1' in out
    assert 'skipped 1: corrupt PNG: OpenCV cannot decode' in out
    got = output_messages(tmp_path / 'out')
    assert [t for t, _ in got['/obstacles/points']] == [T0_NS, T0_NS + 2 * PERIOD_NS]


def test_compressed_topic_named_in_the_missing_topic_error(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    write_bag(tmp_path / 'in', compressed_items(frame_messages(depths[:1]), 'compressedDepth',
                                                _compressed_depth))

    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out')]) == 1

    assert capsys.readouterr().err == (
        f'error: {tmp_path / "in"}: no depth topic {DEPTH} (its sensor_msgs/msg/Image or '
        f'sensor_msgs/msg/CompressedImage topics: {DEPTH}/compressedDepth; use '
        '--depth-topic)\n')


def test_camera_info_is_found_beside_the_raw_topic_of_a_compressed_one(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    items = []
    for topic, t, msg in compressed_items(frame_messages(depths[:2]), 'compressedDepth',
                                          _compressed_depth):
        if topic == INFO:
            items.append(('/cam/color/camera_info', t, msg))  # a second CameraInfo topic
            topic = '/cam/depth/camera_info'
        else:
            topic = '/cam/depth/image_raw/compressedDepth'
        items.append((topic, t, msg))
    write_bag(tmp_path / 'in', items)

    assert bag_process.main([str(tmp_path / 'in'), str(tmp_path / 'out'), '--quiet',
                             '--depth-topic', '/cam/depth/image_raw/compressedDepth']) == 0

    out = capsys.readouterr().out
    assert ('intrinsics: CameraInfo on /cam/depth/camera_info (found by type, the nearest to '
            '/cam/depth/image_raw)') in out
    assert 'depth frames: 2, processed 2, skipped 0' in out
