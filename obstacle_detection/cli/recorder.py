"""Record topics of a live ROS 2 graph as raw messages, and write them as a rosbag2 bag."""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .bag_player import message_class
from .bag_writer import BAG_VERSION


class Recorder:
    """Subscribes (raw) to topics and keeps every message with its arrival time [ns]."""

    def __init__(self, node: Any, topics: Mapping[str, str], *, depth: int = 50) -> None:
        """Create one reliable raw subscription per ``{topic: message type name}`` on ``node``."""
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
        self.topics = dict(topics)
        self.messages: dict[str, list[tuple[int, bytes]]] = {t: [] for t in self.topics}
        self.last_arrival = time.monotonic()
        self.subscriptions = [
            node.create_subscription(message_class(msgtype), topic,
                                     lambda raw, t=topic: self._keep(t, raw), qos, raw=True)
            for topic, msgtype in self.topics.items()]

    def _keep(self, topic: str, raw: bytes) -> None:
        self.messages[topic].append((time.time_ns(), raw))
        self.last_arrival = time.monotonic()

    def count(self, topic: str) -> int:
        """Return the number of messages received on ``topic``."""
        return len(self.messages[topic])


def write_bag(path: Path, recorder: Recorder) -> None:
    """Write what was recorded: header stamps as bag time (the arrival time if none)."""
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=BAG_VERSION) as writer:
        for topic, msgtype in recorder.topics.items():
            if not recorder.messages[topic]:
                continue
            conn = writer.add_connection(topic, msgtype, typestore=typestore)
            cls = message_class(msgtype)
            for arrival, raw in recorder.messages[topic]:
                msg = deserialize_message(raw, cls)
                header = getattr(msg, 'header', None)
                stamp = (header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
                         if header is not None else arrival)
                writer.write(conn, stamp, raw)
