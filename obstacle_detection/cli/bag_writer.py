"""Write rosbag2 bags: dataset frames on the Kinect v2 driver's topics, or a ROS 1 bag."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math
import shutil
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from obstacle_detection.cli import support as tool_support
from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info
from obstacle_detection.cli.progress import Progress
from obstacle_detection.evaluation.datasets import (EvaluationError, FrameSource,
                                                 default_intrinsics, read_color, read_depth_png)

DEFAULT_DEPTH_TOPIC = tool_support.DEFAULT_DEPTH_TOPIC
DEFAULT_INFO_TOPIC = tool_support.DEFAULT_INFO_TOPIC
DEFAULT_COLOR_TOPIC = '/kinect2/sd/image_color_rect'
DEFAULT_FRAME_ID = 'kinect2_ir_optical_frame'
#: Odometry of frames that carry a pose (nav_msgs/Odometry, base_footprint in odom).
DEFAULT_ODOM_TOPIC = '/odom'
BAG_VERSION = 9
STORAGES = {'sqlite3': StoragePlugin.SQLITE3, 'mcap': StoragePlugin.MCAP}
_JAZZY = get_typestore(Stores.ROS2_JAZZY)


@dataclasses.dataclass(frozen=True)
class BagOptions:
    """How frames are written: storage plugin, with colour, with a progress bar."""

    storage: str = 'sqlite3'
    with_color: bool = True
    progress: bool = True


@dataclasses.dataclass
class Summary:
    """What a conversion wrote."""

    output: Path
    frames: int = 0
    messages: int = 0
    duration_s: float = 0.0
    size: tuple[int, int] | None = None
    dropped: Counter[str] = dataclasses.field(default_factory=Counter)
    topics: Counter[str] = dataclasses.field(default_factory=Counter)
    notes: list[str] = dataclasses.field(default_factory=list)

    def lines(self) -> list[str]:
        """Return the summary as printable lines."""
        out = [f'wrote {self.output}', f'  {self.messages} messages; duration '
                                       f'{self.duration_s:.3f} s']
        if self.size is not None:
            out[1] = (f'  frames: {self.frames} depth ({self.size[0]}x{self.size[1]}, 16UC1 '
                      f'mm); duration {self.duration_s:.3f} s')
        out.extend(f'  {topic}: {count} messages' for topic, count in self.topics.items())
        if self.size is not None:
            out.append(f'  dropped pairs: {sum(self.dropped.values())}')
            out.extend(f'    {count}: {reason}' for reason, count in self.dropped.items())
        out.extend(f'  note: {note}' for note in self.notes)
        return out


def cdr_bytes(msg: Any) -> bytes:
    """Serialize an rclpy message as ``serialize_message`` does, with its padding bytes zeroed.

    rmw's CDR serializer leaves the alignment padding inside a message (after PointField's
    datatype, before a uint32 after a bool...) uninitialised, so equal messages gave different
    bytes from run to run. rosbags' serializer writes zeros there: one round trip through it
    keeps every field (rclpy reads the result back equal) and makes the bytes reproducible.
    """
    msgtype = f'{type(msg).__module__.split(".")[0]}/msg/{type(msg).__name__}'
    return bytes(_JAZZY.serialize_cdr(_JAZZY.deserialize_cdr(serialize_message(msg), msgtype),
                                      msgtype))


@contextlib.contextmanager
def staged_output(output: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``output``; rename it to ``output`` on success."""
    if output.exists() or output.is_symlink():
        raise EvaluationError(f'{output}: output already exists; remove it or choose another name')
    staging = output.parent / f'.{output.name}.partial'
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)   # an OSError names the folder: one line of the tool
    try:
        yield staging / output.name
        (staging / output.name).rename(output)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _odometry(stamp: Time, pose: tuple[float, float, float]) -> Any:
    """Return the base pose ``(x, y, yaw)`` in odom as a nav_msgs/Odometry."""
    from nav_msgs.msg import Odometry

    msg = Odometry()
    msg.header.stamp = stamp
    msg.header.frame_id = 'odom'
    msg.child_frame_id = 'base_footprint'
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(pose[0]), float(pose[1])
    msg.pose.pose.orientation.z = math.sin(pose[2] / 2.0)
    msg.pose.pose.orientation.w = math.cos(pose[2] / 2.0)
    return msg


def write_frames(source: FrameSource, output: Path, options: BagOptions) -> Summary:
    """Write the frames of ``source`` as a rosbag2 at ``output``: depth [mm], info, colour."""
    if not source.frames:
        raise EvaluationError(f'{output}: no frames to write')
    first = source.frames[0].depth_path
    scale = source.depth_units_per_m
    problem = tool_support.depth_unit_warning(read_depth_png(first), scale)
    if problem is not None and not source.depth_units_origin:
        raise EvaluationError(f'{first}: {problem}; if it is in millimetres after all, pass '
                              '--depth-scale 1000')
    if problem is not None:
        tool_support.warn(f'{first}: {problem}')
    shape = read_depth_png(first).shape
    size = (shape[1], shape[0])
    if source.size is not None and source.size != size:
        raise EvaluationError(f'{source.intrinsics_origin.removeprefix("from ")}: intrinsics are '
                              f'for {source.size[0]}x{source.size[1]} images but {first} is '
                              f'{size[0]}x{size[1]}')
    intr, origin = source.intrinsics, source.intrinsics_origin
    if intr is None:
        intr, origin = default_intrinsics(source.default_view, size)
        tool_support.warn(f'no intrinsics given (--intrinsics FILE or FX,FY,CX,CY): using '
                          f'{origin}, '
                          f'fx={intr.fx:.2f} fy={intr.fy:.2f} cx={intr.cx:.2f} '
                          f'cy={intr.cy:.2f}. Obstacle positions are only as right as these '
                          'values.')
    units_origin = source.depth_units_origin or ('millimetres, the default; --depth-scale for '
                                                 'another unit, TUM: 5000')
    summary = Summary(output=output, size=size, dropped=source.dropped.copy(),
                      notes=[*source.notes, f'intrinsics: {origin} (fx={intr.fx:g} '
                             f'fy={intr.fy:g} cx={intr.cx:g} cy={intr.cy:g})',
                             f'depth read at {scale:g} units/m ({units_origin}), written in '
                             'millimetres'])
    typestore = get_typestore(Stores.ROS2_JAZZY)
    stamps = [f.stamp_ns for f in source.frames]
    summary.duration_s = (max(stamps) - min(stamps)) / 1e9
    with staged_output(output) as staging:
        try:
            with Writer(staging, version=BAG_VERSION,
                        storage_plugin=STORAGES[options.storage]) as writer, \
                    Progress(len(source.frames), 'converting',
                             stream=None if options.progress else io.StringIO()) as bar:
                connections: dict[str, Any] = {}

                def write(topic: str, stamp: int, msg: Any) -> None:
                    if topic not in connections:
                        msgtype = f'{type(msg).__module__.split(".")[0]}/msg/{type(msg).__name__}'
                        connections[topic] = writer.add_connection(topic, msgtype,
                                                                   typestore=typestore)
                    writer.write(connections[topic], stamp, cdr_bytes(msg))
                    summary.topics[topic] += 1
                    summary.messages += 1

                for frame in source.frames:
                    depth = read_depth_png(frame.depth_path, units_per_m=scale)
                    if depth.shape != shape:
                        raise EvaluationError(
                            f'{frame.depth_path}: {depth.shape[1]}x{depth.shape[0]} but the '
                            f'first depth image {first} is {size[0]}x{size[1]}')
                    time = Time(sec=frame.stamp_ns // 10**9, nanosec=frame.stamp_ns % 10**9)
                    if frame.pose is not None:
                        write(DEFAULT_ODOM_TOPIC, frame.stamp_ns, _odometry(time, frame.pose))
                    write(DEFAULT_INFO_TOPIC, frame.stamp_ns, intrinsics_to_camera_info(
                        intr, size[0], size[1], stamp=time, frame_id=DEFAULT_FRAME_ID))
                    write(DEFAULT_DEPTH_TOPIC, frame.stamp_ns, array_to_image(
                        depth, stamp=time, frame_id=DEFAULT_FRAME_ID, encoding='16UC1'))
                    if options.with_color and frame.color_path is not None:
                        write(DEFAULT_COLOR_TOPIC, frame.stamp_ns, array_to_image(
                            read_color(frame.color_path, 'bgr8'), stamp=time,
                            frame_id=DEFAULT_FRAME_ID, encoding='bgr8'))
                    summary.frames += 1
                    bar.update()
        except WriterError as err:
            raise EvaluationError(f'{output}: cannot write bag ({err})') from err
    return summary


#: The first line of a ROS 1 bag file.
ROS1_MAGIC = b'#ROSBAG V2.0'
_NO_CONVERSION = 'needs no conversion (bag_play, bag_process and pictures --bag read it)'


def check_ros1_bag(src: Path) -> None:
    """Raise EvaluationError unless ``src`` is a ROS 1 bag file, saying what it is instead."""
    if src.is_dir():
        if (src / 'metadata.yaml').is_file():
            raise EvaluationError(f'{src}: a rosbag2 bag, not a ROS 1 bag: it {_NO_CONVERSION}')
        raise EvaluationError(f'{src}: a folder, not a ROS 1 .bag file')
    if not src.is_file():
        raise EvaluationError(f'{src}: ROS 1 bag not found')
    with open(src, 'rb') as stream:
        head = stream.read(len(ROS1_MAGIC))
    if head == ROS1_MAGIC:
        return
    if src.suffix in ('.db3', '.mcap') and (src.parent / 'metadata.yaml').is_file():
        raise EvaluationError(f'{src}: a rosbag2 storage file, not a ROS 1 bag: its folder '
                              f'{src.parent} is a rosbag2 bag already and {_NO_CONVERSION}')
    raise EvaluationError(f'{src}: not a ROS 1 bag (no "{ROS1_MAGIC.decode()}" header)')


def convert_ros1(src: Path, output: Path, *, storage: str = 'sqlite3',
                 topics: Sequence[str] = (), progress: bool = True) -> Summary:
    """Convert a ROS 1 bag to rosbag2, every message to its ROS 2 Jazzy type.

    Compressed depth topics are kept as recorded (the node, with its ``depth_transport``, and
    ``bag_process.py --depth-topic`` read them).
    """
    from rosbags.convert.converter import create_connections_converters
    from rosbags.highlevel import AnyReader, AnyReaderError

    check_ros1_bag(src)
    summary = Summary(output=output)
    with staged_output(output) as staging:
        try:
            with AnyReader([src], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
                connections = [c for c in reader.connections if not topics or c.topic in topics]
                if missing := sorted(set(topics) - {c.topic for c in reader.connections}):
                    raise EvaluationError(f'{src}: has no topic {", ".join(missing)}')
                if not connections:
                    raise EvaluationError(f'{src}: contains no messages')
                with Writer(staging, version=BAG_VERSION,
                            storage_plugin=STORAGES[storage]) as writer, \
                        Progress(sum(c.msgcount for c in connections), 'converting',
                                 stream=None if progress else io.StringIO()) as bar:
                    # rosbags prints which types it migrates; keep stdout for our summary.
                    with contextlib.redirect_stdout(io.StringIO()):
                        connmap, convmap = create_connections_converters(
                            connections, get_typestore(Stores.ROS2_JAZZY), reader, writer)
                    for conn, timestamp, data in reader.messages(connections=connections):
                        writer.write(connmap[(conn.id, conn.owner)], timestamp,
                                     convmap[conn.msgtype](data))
                        summary.topics[conn.topic] += 1
                        bar.update()
                summary.duration_s = (reader.end_time - reader.start_time) / 1e9
        except AnyReaderError as err:
            raise EvaluationError(f'{src}: cannot read ROS 1 bag ({err})') from err
        except WriterError as err:
            raise EvaluationError(f'{output}: cannot write bag ({err})') from err
    summary.topics = Counter(dict(sorted(summary.topics.items())))
    summary.messages = sum(summary.topics.values())
    return summary

