"""Replay a rosbag2 bag on a ROS 2 graph: the player behind ``tools/bag_play.py`` and the demo."""

from __future__ import annotations

import dataclasses
import importlib
import io
import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Reader, ReaderError

from obstacle_detection.cli.support import ToolError, check_bag_path
from obstacle_detection.cli.progress import Progress


@dataclasses.dataclass(frozen=True)
class PlayOptions:
    """How to play a bag."""

    rate: float = 1.0
    loop: bool = False
    reliable: bool = False
    progress: bool = True

    def __post_init__(self) -> None:
        """Validate the values, naming the bad one."""
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ToolError(f'--rate must be a positive factor, got {self.rate}', usage=True)


@dataclasses.dataclass
class PlayStats:
    """What was published: messages per published topic, loops played, wall time [s]."""

    published: Counter[str] = dataclasses.field(default_factory=Counter)
    loops: int = 0
    wall_s: float = 0.0

    def lines(self) -> list[str]:
        """Return the summary as printable lines."""
        total = sum(self.published.values())
        out = [f'published {total} messages in {self.wall_s:.2f} s ({self.loops} loop(s))']
        out.extend(f'  {topic}: {count}' for topic, count in sorted(self.published.items()))
        return out


def message_class(msgtype: str) -> type:
    """Return the rclpy message class for a bag type name like ``sensor_msgs/msg/Image``."""
    package, _, name = msgtype.rpartition('/')
    try:
        return getattr(importlib.import_module(package.replace('/', '.')), name)
    except (ImportError, AttributeError) as err:
        raise ToolError(f'message type {msgtype} is not installed ({err})') from err


def open_bag(bag: Path) -> Reader:
    """Open ``bag``, a rosbag2 bag with messages; the caller closes the reader."""
    check_bag_path(bag, ros1=False)
    try:
        reader = Reader(bag)
        reader.open()
    except ReaderError as err:
        raise ToolError(f'{bag}: cannot read bag ({err})') from err
    if not reader.message_count:
        reader.close()
        raise ToolError(f'{bag}: has no messages to play')
    return reader


class Player:
    """Publish a bag's messages from an existing rclpy node."""

    def __init__(self, node: Any, bag: Path, options: PlayOptions) -> None:
        """Open the bag and create one publisher per played topic."""
        from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

        self.options = options
        self.node = node
        self.reader = open_bag(bag)
        qos = (QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
               if options.reliable else qos_profile_sensor_data)
        types = {conn.topic: conn.msgtype for conn in self.reader.connections}   # one per topic
        self.publishers = {topic: node.create_publisher(message_class(msgtype), topic, qos)
                           for topic, msgtype in types.items()}

    def close(self, ack_timeout_s: float = 3.0) -> None:
        """Close the bag and destroy the publishers."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + ack_timeout_s
        for publisher in self.publishers.values():
            left = deadline - time.monotonic()
            if left > 0:
                try:
                    publisher.wait_for_all_acked(Duration(seconds=left))
                except Exception:  # noqa: BLE001 - a context shut down: nothing to wait for
                    pass
            self.node.destroy_publisher(publisher)
        self.publishers = {}
        self.reader.close()

    def subscription_count(self) -> int:
        """Return matched subscriptions summed over the played topics."""
        return sum(p.get_subscription_count() for p in self.publishers.values())

    def play(self, stop: threading.Event | None = None,
             on_publish: Callable[[str, int], None] | None = None) -> PlayStats:
        """Publish the messages with their recorded spacing; return what was published."""
        stats = PlayStats()
        began = time.monotonic()
        total = None if self.options.loop else self.reader.message_count
        rate = self.options.rate
        with Progress(total, 'playing',
                      stream=None if self.options.progress else io.StringIO()) as bar:
            while self.options.loop or not stats.loops:
                loop_start = time.monotonic()
                for conn, timestamp, raw in self.reader.messages():
                    due = loop_start + (timestamp - self.reader.start_time) / 1e9 / rate
                    if not _sleep_until(due, stop):
                        stats.wall_s = time.monotonic() - began
                        return stats
                    self.publishers[conn.topic].publish(bytes(raw))
                    stats.published[conn.topic] += 1
                    bar.update()
                    if on_publish is not None:
                        on_publish(conn.topic, timestamp)
                stats.loops += 1
        stats.wall_s = time.monotonic() - began
        return stats


def _sleep_until(due: float, stop: threading.Event | None) -> bool:
    """Sleep until monotonic time ``due``; False if ``stop`` was set meanwhile."""
    left = max(due - time.monotonic(), 0.0)
    if stop is None:
        time.sleep(left)
        return True
    return not stop.wait(left)
