"""Replay a rosbag2 bag on a ROS 2 graph: the player behind ``tools/bag_play.py`` and the demo."""

from __future__ import annotations

import dataclasses
import importlib
import io
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Reader, ReaderError

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.support import ToolError
from obstacle_detection.cli.progress import Progress

#: How long to sleep at most between checks for a stop request [s].
_POLL_S = 0.05


@dataclasses.dataclass(frozen=True)
class PlayOptions:
    """How to play a bag."""

    topics: tuple[str, ...] = ()
    rate: float = 1.0
    loops: int = 1
    start_offset_s: float = 0.0
    reliable: bool = False
    remap: dict[str, str] = dataclasses.field(default_factory=dict)
    wait_for_subscribers: int = 0
    wait_timeout_s: float = 30.0
    progress: bool = True

    def __post_init__(self) -> None:
        """Validate the values, naming the bad one."""
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ToolError(f'--rate must be a positive factor, got {self.rate}', usage=True)
        if self.loops < 0:
            raise ToolError(f'--loops must be >= 0 (0 = until stopped), got {self.loops}',
                            usage=True)
        if not (math.isfinite(self.start_offset_s) and self.start_offset_s >= 0):
            raise ToolError(f'--start-offset must be >= 0 s, got {self.start_offset_s}',
                            usage=True)
        if self.wait_for_subscribers < 0:
            raise ToolError('--wait-for-subscribers must be >= 0, got '
                            f'{self.wait_for_subscribers}', usage=True)


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


def parse_remap(items: Sequence[str]) -> dict[str, str]:
    """Parse ``old:=new`` strings into a mapping."""
    remap = {}
    for item in items:
        old, sep, new = item.partition(':=')
        if not sep or not old or not new:
            raise ToolError(f'--remap expects old:=new, got {item!r}', usage=True)
        remap[old] = new
    return remap


def message_class(msgtype: str) -> type:
    """Return the rclpy message class for a bag type name like ``sensor_msgs/msg/Image``."""
    package, _, name = msgtype.rpartition('/')
    try:
        return getattr(importlib.import_module(package.replace('/', '.')), name)
    except (ImportError, AttributeError) as err:
        raise ToolError(f'message type {msgtype} is not installed ({err})') from err


def open_bag(bag: Path, options: PlayOptions) -> tuple[Reader, list[Any]]:
    """Open ``bag`` and pick the connections to play; the caller closes the reader."""
    tool_support.check_bag_path(bag, ros1=False)
    try:
        reader = Reader(bag)
        reader.open()
    except ReaderError as err:
        raise ToolError(f'{bag}: cannot read bag ({err})') from err
    try:
        known = {c.topic for c in reader.connections}
        if missing := sorted(set(options.topics) - known):
            raise ToolError(f'{bag}: has no topic {", ".join(missing)} '
                            f'(it has {", ".join(sorted(known))})')
        connections = [c for c in reader.connections
                       if not options.topics or c.topic in options.topics]
        if unknown := sorted(set(options.remap) - {c.topic for c in connections}):
            raise ToolError(f'{bag}: --remap of {", ".join(unknown)}, which is not played')
        offset_ns = int(round(options.start_offset_s * 1e9))
        if not any(c.msgcount for c in connections) or (
                reader.start_time + offset_ns > reader.end_time):
            raise ToolError(f'{bag}: no messages to play after {options.start_offset_s:g} s '
                            f'(the bag lasts {(reader.end_time - reader.start_time) / 1e9:g} s)')
    except BaseException:
        reader.close()
        raise
    return reader, connections


class Player:
    """Publish a bag's messages from an existing rclpy node."""

    def __init__(self, node: Any, bag: Path, options: PlayOptions) -> None:
        """Open the bag and create one publisher per played topic."""
        from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

        self.bag = bag
        self.options = options
        self.node = node
        self.reader, self.connections = open_bag(bag, options)
        qos = (QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
               if options.reliable else qos_profile_sensor_data)
        self.publishers: dict[str, Any] = {}
        try:
            for conn in self.connections:
                if conn.topic not in self.publishers:
                    self.publishers[conn.topic] = node.create_publisher(
                        message_class(conn.msgtype), options.remap.get(conn.topic, conn.topic),
                        qos)
        except BaseException:
            self.close()
            raise
        self.start_ns = self.reader.start_time + int(round(options.start_offset_s * 1e9))
        self.total = sum(c.msgcount for c in self.connections) if not options.start_offset_s \
            else None

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

    def wait_for_subscribers(self) -> None:
        """Block until ``options.wait_for_subscribers`` subscriptions are matched."""
        want = self.options.wait_for_subscribers
        deadline = time.monotonic() + self.options.wait_timeout_s
        while self.subscription_count() < want:
            if time.monotonic() > deadline:
                raise ToolError(f'{self.bag}: only {self.subscription_count()} of {want} '
                                f'subscriptions matched after {self.options.wait_timeout_s:g} s')
            time.sleep(_POLL_S)

    def play(self, stop: threading.Event | None = None,
             on_publish: Callable[[str, int], None] | None = None) -> PlayStats:
        """Publish the messages with their recorded spacing; return what was published."""
        stats = PlayStats()
        began = time.monotonic()
        loops = self.options.loops
        total = self.total * loops if self.total and loops else None
        most = max(c.msgcount for c in self.connections)  # its mean spacing: the loop seam's
        gap_s = self.reader.duration / 1e9 / (most - 1) if most > 1 else 0.0
        bar = Progress(total, 'playing', stream=None if self.options.progress else io.StringIO())
        with bar:
            while not loops or stats.loops < loops:
                if stats.loops and not _sleep_until(
                        time.monotonic() + gap_s / self.options.rate, stop):
                    break  # keep one frame's spacing across the loop seam
                loop_start = time.monotonic()
                first_t = None
                for conn, timestamp, raw in self.reader.messages(connections=self.connections,
                                                                 start=self.start_ns):
                    first_t = timestamp if first_t is None else first_t
                    due = loop_start + (timestamp - first_t) / 1e9 / self.options.rate
                    if not _sleep_until(due, stop):
                        stats.wall_s = time.monotonic() - began
                        return stats
                    publisher = self.publishers[conn.topic]
                    publisher.publish(bytes(raw))
                    topic = publisher.topic_name
                    stats.published[topic] += 1
                    bar.update()
                    if on_publish is not None:
                        on_publish(topic, timestamp)
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
