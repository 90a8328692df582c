"""Tests of tools/bag_play.py: a bag replayed on loopback DDS reaches a subscriber intact."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import rclpy
import ros_env
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from obstacle_detection.ros.conversions import image_to_array
from obstacle_detection.evaluation import datasets
from obstacle_detection.cli import bag_player, bag_writer
from obstacle_detection.tools import bag_play


REPO = Path(__file__).resolve().parents[1]
N_FRAMES = 6
RATE_HZ = 30.0
DEPTH = bag_writer.DEFAULT_DEPTH_TOPIC
INFO = bag_writer.DEFAULT_INFO_TOPIC
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


def frame_depth(k: int) -> np.ndarray:
    """(24, 32) uint16 frame whose every pixel encodes k, so order is checkable."""
    return np.full((24, 32), 1000 + k, dtype=np.uint16) + np.arange(32, dtype=np.uint16)


def folder_source(root: Path, rate_hz: float) -> datasets.FrameSource:
    """Write N_FRAMES depth PNGs (frame_depth) and intrinsics under root; their frame source."""
    import cv2

    (root / 'depth').mkdir()
    for k in range(N_FRAMES):
        cv2.imwrite(str(root / 'depth' / f'{k:03d}.png'), frame_depth(k))
    (root / 'k.yaml').write_text('fx: 30.0\nfy: 30.0\ncx: 16.0\ncy: 12.0\n')
    return datasets.folder_frames(root / 'depth', intrinsics_path=root / 'k.yaml',
                                  rate_hz=rate_hz, start_s=50.0)


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Return a converted bag of N_FRAMES depth + camera-info frames at 30 Hz."""
    root = tmp_path_factory.mktemp('play')
    source = folder_source(root, RATE_HZ)
    bag_writer.write_frames(source, root / 'bag', bag_writer.BagOptions(progress=False))
    return root / 'bag'


@pytest.fixture(scope='module')
def env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """Loopback DDS environment of this module, applied to this process too."""
    environment = ros_env.loopback_env('test_bag_play',
                                       log_dir=tmp_path_factory.mktemp('ros_log'))
    old = ros_env.apply(environment)
    yield environment
    ros_env.restore(old)


@pytest.fixture()
def context(env: dict[str, str]) -> Iterator[rclpy.context.Context]:
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    yield ctx
    ctx.try_shutdown()


class Recorder:
    """Subscribes to topics and keeps every message received, in order."""

    def __init__(self, context: rclpy.context.Context, topics: dict[str, type],
                 qos: QoSProfile) -> None:
        self.node = Node('play_recorder', context=context)
        self.received: dict[str, list] = {topic: [] for topic in topics}
        for topic, msg_type in topics.items():
            self.node.create_subscription(
                msg_type, topic, lambda msg, t=topic: self.received[t].append(msg), qos)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)

    def spin_until(self, done, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def stamps_s(messages: list) -> list[float]:
    return [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in messages]


def wait_matched(player: bag_player.Player) -> None:
    """Wait until the test's subscriber is matched (the player itself does not wait)."""
    deadline = time.monotonic() + 20.0
    while player.subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)


def test_cli_loops_every_frame_in_order_until_ctrl_c(bag: Path, env: dict[str, str],
                                                     context: rclpy.context.Context) -> None:
    recorder = Recorder(context, {DEPTH: Image, INFO: CameraInfo}, RELIABLE)
    try:
        player = subprocess.Popen(
            [sys.executable, str(REPO / 'tools' / 'bag_play.py'), str(bag), '--reliable',
             '--quiet', '--loop'],
            env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        # the first frames may go out before the subscriber is matched: two loops more
        recorder.spin_until(lambda: len(recorder.received[DEPTH]) >= 3 * N_FRAMES, 30.0)
        player.send_signal(signal.SIGINT)
        _, err = player.communicate(timeout=10)
        assert player.returncode == 130, err
        assert err.endswith('bag_play: interrupted\n')
        depth = recorder.received[DEPTH]
        frames = [int(image_to_array(m)[0, 0]) - 1000 for m in depth]
        start = frames.index(0)
        assert frames[start:start + 2 * N_FRAMES] == list(range(N_FRAMES)) * 2
        for k, msg in enumerate(depth[start:start + N_FRAMES]):
            np.testing.assert_array_equal(image_to_array(msg), frame_depth(k))
        np.testing.assert_allclose(stamps_s(depth[start:start + N_FRAMES]),
                                   50.0 + np.arange(N_FRAMES) / RATE_HZ, atol=1e-9)
        assert len(recorder.received[INFO]) >= 2 * N_FRAMES
    finally:
        recorder.close()


@pytest.fixture(scope='module')
def slow_bag_with_odometry(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Return a 3 Hz bag of depth, camera info and odometry (three messages a stamp)."""
    import dataclasses

    root = tmp_path_factory.mktemp('play_slow')
    source = folder_source(root, 3.0)
    source.frames = [dataclasses.replace(f, pose=(0.1 * k, 0.0, 0.0))
                     for k, f in enumerate(source.frames)]
    bag_writer.write_frames(source, root / 'bag', bag_writer.BagOptions(progress=False))
    return root / 'bag'


def test_ctrl_c_is_one_line_when_sigint_was_ignored_at_start(
        slow_bag_with_odometry: Path, env: dict[str, str],
        context: rclpy.context.Context) -> None:
    # A shell starts a background job (`bag_play ... &` in a script) with SIGINT ignored; Python
    # then leaves SIGINT alone and only rclpy's handler sees it: it shut the context down and
    # the next publish died with "RCLError: publisher's context is invalid", exit 1.
    recorder = Recorder(context, {DEPTH: Image}, qos_profile_sensor_data)
    player = None
    try:
        player = subprocess.Popen(
            [sys.executable, str(REPO / 'tools' / 'bag_play.py'), str(slow_bag_with_odometry),
             '--quiet', '--loop'], env=env, cwd=REPO, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
        recorder.spin_until(lambda: len(recorder.received[DEPTH]) >= 2, 30.0)
        assert recorder.received[DEPTH], 'bag_play published nothing'
        player.send_signal(signal.SIGINT)
        _, err = player.communicate(timeout=20)
        assert (player.returncode, err) == (130, 'bag_play: interrupted\n')
    finally:
        if player is not None and player.poll() is None:
            player.kill()
        recorder.close()


def test_library_loop_and_timing(bag: Path, context: rclpy.context.Context,
                                 monkeypatch: pytest.MonkeyPatch) -> None:
    recorder = Recorder(context, {DEPTH: Image}, RELIABLE)
    arrivals: list[float] = []
    topics: list[str] = []
    publisher_node = Node('player_under_test', context=context)
    options = bag_player.PlayOptions(rate=0.5, loop=True, reliable=True, progress=False)
    player = bag_player.Player(publisher_node, bag, options)
    stats: list[bag_player.PlayStats] = []
    stop = threading.Event()   # set after the last message of the second loop
    dues: list[float] = []    # when the player means to publish each message (its schedule)
    sleep_until = bag_player._sleep_until   # no public name: the player's one wait

    def recorded_sleep_until(due: float, stop: threading.Event | None) -> bool:
        dues.append(due)
        return sleep_until(due, stop)

    monkeypatch.setattr(bag_player, '_sleep_until', recorded_sleep_until)

    def published(topic: str, stamp: int) -> None:
        arrivals.append(time.monotonic())
        topics.append(topic)
        if len(arrivals) == 4 * N_FRAMES:   # two loops of depth and camera info
            stop.set()

    def run() -> None:
        wait_matched(player)
        stats.append(player.play(stop, on_publish=published))

    thread = threading.Thread(target=run)
    try:
        thread.start()
        recorder.spin_until(lambda: len(recorder.received[DEPTH]) >= 2 * N_FRAMES, 20.0)
        thread.join(timeout=10)
        got = [int(image_to_array(m)[0, 0]) - 1000 for m in recorder.received[DEPTH]]
        assert got == list(range(N_FRAMES)) * 2
        assert stats[0].loops == 2
        assert stats[0].published == {DEPTH: 2 * N_FRAMES, INFO: 2 * N_FRAMES}
        # Half speed: frame i of the first loop is due i / 15 s after the first, and none is
        # published before it is due (how late depends on the machine: not asserted).
        depth = [k for k in range(2 * N_FRAMES) if topics[k] == DEPTH]   # the first loop's
        first_loop = np.array(dues)[depth]
        np.testing.assert_allclose(first_loop - first_loop[0], np.arange(N_FRAMES) * 2 / RATE_HZ,
                                   atol=1e-6)
        assert np.all(np.array(arrivals)[depth] >= first_loop)
    finally:
        thread.join(timeout=10)
        player.close()
        publisher_node.destroy_node()
        recorder.close()


def test_sensor_data_qos_by_default(bag: Path, context: rclpy.context.Context) -> None:
    node = Node('qos_probe', context=context)
    player = bag_player.Player(node, bag, bag_player.PlayOptions(progress=False))
    try:
        infos = node.get_publishers_info_by_topic(DEPTH)
        assert [i.qos_profile.reliability for i in infos] == [qos_profile_sensor_data.reliability]
    finally:
        player.close()
        node.destroy_node()


def test_a_bad_rate_is_a_usage_error(bag: Path, capsys: pytest.CaptureFixture[str],
                                     env: dict[str, str]) -> None:
    assert bag_play.main([str(bag), '--rate', '0', '--quiet']) == 2
    err = capsys.readouterr().err
    assert err == 'bag_play: error: --rate must be a positive factor, got 0.0\n'


def test_a_bag_without_messages_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                            env: dict[str, str]) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    with Writer(tmp_path / 'empty', version=9) as writer:
        writer.add_connection(DEPTH, 'sensor_msgs/msg/Image',
                              typestore=get_typestore(Stores.ROS2_JAZZY))
    assert bag_play.main([str(tmp_path / 'empty')]) == 1
    assert capsys.readouterr().err == f'error: {tmp_path / "empty"}: has no messages to play\n'


def test_missing_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                     env: dict[str, str]) -> None:
    assert bag_play.main([str(tmp_path / 'none')]) == 1
    assert str(tmp_path / 'none') in capsys.readouterr().err


def test_a_folder_that_is_not_a_bag_is_one_line(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str],
                                                env: dict[str, str]) -> None:
    (tmp_path / 'pictures').mkdir()
    (tmp_path / 'pictures' / 'a.png').write_bytes(b'')
    assert bag_play.main([str(tmp_path / 'pictures')]) == 1
    err = capsys.readouterr().err
    assert err == (f'error: {tmp_path / "pictures"}: not a bag: no metadata.yaml in the folder;'
                   ' expected a rosbag2 folder (holding metadata.yaml)\n')


def test_compressed_depth_topic_is_played_and_decodes(tmp_path: Path,
                                                      context: rclpy.context.Context) -> None:
    # a compressedDepth topic is played as recorded: the subscriber decodes the same frames
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    from message_helpers import array_to_compressed_depth
    from obstacle_detection.ros.compressed_depth import compressed_depth_to_array

    topic = f'{DEPTH}/compressedDepth'
    with Writer(tmp_path / 'bag', version=9) as writer:
        conn = writer.add_connection(topic, 'sensor_msgs/msg/CompressedImage',
                                     typestore=get_typestore(Stores.ROS2_JAZZY))
        for k in range(3):
            msg = array_to_compressed_depth(frame_depth(k), Time(sec=60 + k), 'cam')
            writer.write(conn, (60 + k) * 10**9 // 30, serialize_message(msg))
    recorder = Recorder(context, {topic: CompressedImage}, RELIABLE)
    node = Node('compressed_player', context=context)
    player = bag_player.Player(node, tmp_path / 'bag', bag_player.PlayOptions(
        reliable=True, progress=False))
    try:
        wait_matched(player)
        stats = player.play()
        recorder.spin_until(lambda: len(recorder.received[topic]) >= 3, 10.0)
        assert stats.published[topic] == 3
        got = recorder.received[topic]
        assert [m.format for m in got] == ['16UC1; compressedDepth png'] * 3
        for k, msg in enumerate(got):
            np.testing.assert_array_equal(compressed_depth_to_array(msg), frame_depth(k))
    finally:
        player.close()
        node.destroy_node()
        recorder.close()
