"""Run the detector over a whole rosbag2 bag offline (behind ``tools/bag_process.py``)."""

from __future__ import annotations

import dataclasses
import io
import statistics
from collections import Counter, deque
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader, ReaderError, Writer, WriterError
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.support import ToolError
from obstacle_detection.cli.bag_writer import (BAG_VERSION, DEFAULT_DEPTH_TOPIC, STORAGES,
                                               cdr_bytes, staged_output)
from obstacle_detection.cli.progress import Progress
from obstacle_detection.ros import frame_gate
from obstacle_detection.ros.compressed_depth import COMPRESSED_IMAGE_TYPE, raw_topic
from obstacle_detection.ros.config import NodeConfig, build_config
from obstacle_detection.ros.conversions import result_to_messages
from obstacle_detection.ros.frame_gate import CameraState
from obstacle_detection.ros.mount_source import MountSource, StaticTransforms
from obstacle_detection.ros.parameters import (ALL_PARAMS, params_file_problems,
                                               read_params_files)
from obstacle_detection.viz.overlay import render_overlay

DEFAULT_NAMESPACE = '/obstacles'
#: With use_tf, the camera mount comes from this topic's transforms (tf2_msgs/TFMessage).
TF_STATIC = '/tf_static'
#: The floor of every this many processed frames is checked against the mount (a RANSAC fit of
#: 0.1-0.4 s a 640x480 frame); with refine_floor on, every frame whose floor the per-frame fit
#: found beyond its bounds is checked too, so a camera that tilts mid-recording is reported.
MOUNT_CHECK_EVERY = 60
#: Fix named by a mount warning: of the parameters, or (use_tf) of the bag's /tf_static.
MOUNT_FIX = ('a --params-file setting camera_height_m, camera_pitch_deg and camera_roll_deg '
             '(tools/estimate_mount.py --params-out writes one from a depth frame)')
MOUNT_FIX_TF = ("the camera joint of the URDF the bag's /tf_static was recorded with "
                '(tools/estimate_mount.py measures the mount from a depth frame)')
#: result_to_messages key -> (topic below the namespace, message type).
OUTPUTS = {
    'obstacles': ('points', 'sensor_msgs/msg/PointCloud2'),
    'costmap': ('costmap', 'nav_msgs/msg/OccupancyGrid'),
    'ground': ('ground_points', 'sensor_msgs/msg/PointCloud2'),
    'overlay': ('overlay', 'sensor_msgs/msg/Image'),
}
#: Message types a depth topic may have -> rclpy class.
DEPTH_TYPES = {tool_support.IMAGE_TYPE: Image, COMPRESSED_IMAGE_TYPE: CompressedImage}


def node_param_values(path: Path | Sequence[Path]) -> dict[str, Any]:
    """All node parameter values: defaults updated with one or more ``--params-file`` YAMLs."""
    values: dict[str, Any] = {spec.name: spec.default for spec in ALL_PARAMS}
    paths = [path] if isinstance(path, (str, Path)) else list(path)
    values.update(read_params_files(paths))   # RosInputError: a ValueError, one line
    for path in paths:   # what the node would ignore, said as the node says it
        for problem in params_file_problems(path):
            tool_support.warn(problem)
    return values


def config_from_values(values: Mapping[str, Any], origin: str) -> NodeConfig:
    """Return the node's configuration (detector, frames, switches) from parameter values."""
    try:
        return build_config(dict(values))
    except ValueError as err:
        raise ToolError(f'{origin}: {err}') from err


@dataclasses.dataclass
class ProcessSummary:
    """What an offline run did."""

    output: Path
    frames: int = 0
    processed: int = 0
    obstacle_points: int = 0
    skipped: Counter[str] = dataclasses.field(default_factory=Counter)
    total_ms: list[float] = dataclasses.field(default_factory=list)
    wall_s: float = 0.0
    topics: dict[str, int] = dataclasses.field(default_factory=dict)
    info_topic: str | None = None
    info_how: str = ''
    mount: str = ''
    mount_warning: str | None = None
    #: frames (1-based) whose floor was checked against the mount, and those it did not fit
    mount_checked: list[int] = dataclasses.field(default_factory=list)
    mount_off: list[int] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)

    def lines(self) -> list[str]:
        """Return the summary as printable lines."""
        out = [f'wrote {self.output}',
               f'  intrinsics: CameraInfo on {self.info_topic} ({self.info_how})'
               if self.info_topic else f'  intrinsics: none recorded ({self.info_how})',
               f'  camera mount: {self.mount}',
               f'  depth frames: {self.frames}, processed {self.processed}, '
               f'skipped {sum(self.skipped.values())}']
        out.extend(f'    skipped {count}: {reason}' for reason, count in self.skipped.items())
        if self.mount_warning:
            out.append(f'  warning: {self.mount_warning}')
        if self.mount_off:
            shown = ', '.join(str(k) for k in self.mount_off[:10])
            more = ', ...' if len(self.mount_off) > 10 else ''
            out.append(f'  warning: the floor did not fit the mount in {len(self.mount_off)} of '
                       f'the checked frames: frame{"s" if len(self.mount_off) > 1 else ""} '
                       f'{shown}{more} ({len(self.mount_checked)} checked)')
        out.extend(f'  note: {note}' for note in self.notes)
        if self.total_ms:
            rate = self.processed / self.wall_s if self.wall_s > 0 else 0.0
            out.append(f'  pipeline time per frame: mean {statistics.fmean(self.total_ms):.1f} ms,'
                       f' median {statistics.median(self.total_ms):.1f} ms, '
                       f'max {max(self.total_ms):.1f} ms; {rate:.1f} frames/s overall '
                       f'({self.wall_s:.2f} s)')
        out.extend(f'  {topic}: {count} messages' for topic, count in self.topics.items())
        return out


def process_frame(depth: Image | CompressedImage, cameras: Sequence[CameraState],
                  config: NodeConfig, *, with_ground: bool, with_overlay: bool,
                  mounts: MountSource | None = None,
                  ) -> tuple[dict[str, Any] | None, Any, str, str | None]:
    """Run one depth message (raw or compressed) through the node's gate and pipeline.

    mounts: with use_tf, the mount from the bag's static transforms (as the node's from TF):
    a frame they do not place is skipped, never placed by the mount parameters.
    """
    array = frame_gate.decode(depth)
    if isinstance(array, frame_gate.Skip):
        return None, None, array.reason, None
    camera = frame_gate.camera_for(cameras, frame_gate.stamp_ns(depth.header.stamp),
                                   config.camera_info_tolerance_ns)
    if isinstance(camera, frame_gate.Skip):
        return None, None, camera.reason, None
    verdict = frame_gate.choose_intrinsics(
        camera, array.shape, use_fallback=config.use_fallback_intrinsics,
        fallback=config.fallback_intrinsics, no_camera='no camera info recorded before the frame')
    if verdict.skip is not None:
        return None, None, verdict.skip.reason, None
    skip = frame_gate.check_depth(array, depth)
    if skip is not None:
        return None, None, skip.reason, None
    detector = config.detector
    if mounts is not None:
        parameters = config.mount()
        mount = mounts.mount_for(depth.header.frame_id, None, parameters)
        if mount is None:
            return None, None, f"{mounts.last_problem}, the bag's {TF_STATIC}", None
        try:
            detector = detector if mount == parameters else config.detector_for(mount)
        except ValueError as err:
            return None, None, f'the mount from TF cannot be used: {err}', None
    try:
        result = detector.process(array, verdict.intrinsics)
    except ValueError as err:
        return None, None, str(err), None
    messages = result_to_messages(
        result, stamp=depth.header.stamp, cloud_frame_id=config.cloud_frame_id,
        costmap_frame_id=config.costmap_frame_id, image_frame_id=depth.header.frame_id,
        with_ground=with_ground,
        overlay_rgb=render_overlay(result.depth_m, result.labels) if with_overlay else None)
    return messages, result, '', verdict.note


def _grouped_by_timestamp(messages: Iterator[tuple[Any, int, bytes]], info_topic: str
                          ) -> Iterator[tuple[Any, int, bytes]]:
    """Messages in bag order, camera infos first among those with the same timestamp."""
    group: list[tuple[Any, int, bytes]] = []
    for item in messages:
        if group and item[1] != group[0][1]:
            yield from sorted(group, key=lambda m: m[0].topic != info_topic)
            group = []
        group.append(item)
    yield from sorted(group, key=lambda m: m[0].topic != info_topic)


def process_bag(src: Path, output: Path, config: NodeConfig, *,
                depth_topic: str = DEFAULT_DEPTH_TOPIC, info_topic: str | None = None,
                namespace: str = DEFAULT_NAMESPACE, with_ground: bool = False,
                with_overlay: bool = False, storage: str = 'sqlite3', progress: bool = True,
                mount_origin: str = 'the parameters') -> ProcessSummary:
    """Process every depth frame of ``src`` and write inputs + outputs to ``output``."""
    import time

    tool_support.check_bag_path(src, ros1=False)
    namespace = '/' + namespace.strip('/') if namespace.strip('/') else ''
    summary = ProcessSummary(output=output)
    summary.mount = f'{tool_support.mount_text(config.detector.params)} ({mount_origin})'
    wanted = ['obstacles', 'costmap'] + (['ground'] if with_ground else []) + (
        ['overlay'] if with_overlay else [])
    began = time.perf_counter()
    try:
        with Reader(src) as reader:
            outputs = {key: namespace + '/' + OUTPUTS[key][0] for key in wanted}
            depth_class = _check_topics(reader, src, depth_topic, info_topic, outputs, summary)
            n_depth = sum(c.msgcount for c in reader.connections if c.topic == depth_topic)
            with staged_output(output) as staging, \
                    Writer(staging, version=BAG_VERSION, storage_plugin=STORAGES[storage]) \
                    as writer, \
                    Progress(n_depth, 'processing',
                             stream=None if progress else io.StringIO()) as bar:
                typestore = get_typestore(Stores.ROS2_JAZZY)
                copies = {}   # the inputs, copied: {reader's connection id: writer's}
                for conn in reader.connections:
                    known = bool(conn.msgdef.data and conn.digest)
                    copies[conn.id] = writer.add_connection(
                        conn.topic, conn.msgtype, msgdef=conn.msgdef.data if known else None,
                        rihs01=conn.digest if known else None,
                        typestore=None if known else typestore,
                        serialization_format=getattr(conn.ext, 'serialization_format', 'cdr'),
                        offered_qos_profiles=getattr(conn.ext, 'offered_qos_profiles', ()))
                out_conns = {key: writer.add_connection(outputs[key], OUTPUTS[key][1],
                                                        typestore=typestore) for key in wanted}
                cameras: deque[CameraState] = deque(maxlen=frame_gate.CAMERA_INFO_HISTORY)
                counts: Counter[str] = Counter()
                mounts = _tf_mounts(reader, config, summary)
                for conn, timestamp, raw in _grouped_by_timestamp(
                        reader.messages(), summary.info_topic):
                    writer.write(copies[conn.id], timestamp, raw)
                    counts[conn.topic] += 1
                    if conn.topic == TF_STATIC and mounts is not None:
                        for transform in typestore.deserialize_cdr(
                                bytes(raw), conn.msgtype).transforms:
                            mounts.buffer.add(transform)
                    elif conn.topic == summary.info_topic:
                        camera = CameraState.from_camera_info(
                            deserialize_message(bytes(raw), CameraInfo))
                        frame_gate.keep_camera(cameras, camera)
                        _note(summary, None if camera.note is None else
                              f'CameraInfo on {summary.info_topic}: {camera.note}')
                    elif conn.topic == depth_topic:
                        messages = _frame(deserialize_message(bytes(raw), depth_class),
                                          list(cameras), config, summary, mounts=mounts,
                                          with_ground=with_ground, with_overlay=with_overlay)
                        for key in wanted if messages is not None else ():
                            writer.write(out_conns[key], timestamp, cdr_bytes(messages[key]))
                            counts[outputs[key]] += 1
                        bar.update()
    except ReaderError as err:
        raise ToolError(f'{src}: cannot read bag ({err})') from err
    except WriterError as err:
        raise ToolError(f'{output}: cannot write bag ({err})') from err
    summary.wall_s = time.perf_counter() - began
    summary.topics = dict(sorted(counts.items()))
    return summary


def _check_topics(reader: Reader, src: Path, depth_topic: str, info_topic: str | None,
                  outputs: Mapping[str, str], summary: ProcessSummary) -> type:
    """Check the bag's depth topic and outputs, find the CameraInfo topic; the depth class."""
    topics = {c.topic: c.msgtype for c in reader.connections}
    kinds = ' or '.join(DEPTH_TYPES)
    if depth_topic not in topics:
        images = sorted(t for t, m in topics.items() if m in DEPTH_TYPES)
        raise ToolError(f'{src}: no depth topic {depth_topic} (its {kinds} topics: '
                        f'{", ".join(images) or "none"}; use --depth-topic)')
    if topics[depth_topic] not in DEPTH_TYPES:
        raise ToolError(f'{src}: {depth_topic} has type {topics[depth_topic]}, not {kinds}')
    try:
        summary.info_topic, summary.info_how = tool_support.choose_info_topic(
            topics, raw_topic(depth_topic), info_topic)
    except ValueError as err:
        raise ToolError(f'{src}: {err}') from err
    if clash := sorted(set(outputs.values()) & set(topics)):
        raise ToolError(f'{src}: already has {", ".join(clash)}; choose another --namespace')
    return DEPTH_TYPES[topics[depth_topic]]


def _tf_mounts(reader: Reader, config: NodeConfig, summary: ProcessSummary,
               ) -> MountSource | None:
    """With use_tf, the mount source fed by the bag's static transforms; else None."""
    if not config.values['use_tf']:
        return None
    if not any(c.topic == TF_STATIC and c.msgtype == 'tf2_msgs/msg/TFMessage'
               for c in reader.connections):
        _note(summary, f'use_tf is set but the bag has no {TF_STATIC} (tf2_msgs/TFMessage): '
                       'no frame can be placed (record it, or set use_tf: false to use the '
                       'mount parameters)')
    summary.mount = f"from the bag's {TF_STATIC}: {config.cloud_frame_id} <- the frames' frame_id"
    return MountSource(StaticTransforms(), config.cloud_frame_id, static=True)


def _note(summary: ProcessSummary, note: str | None) -> None:
    if note is not None and note not in summary.notes:
        summary.notes.append(note)


def _frame(depth: Any, cameras: Sequence[CameraState], config: NodeConfig,
           summary: ProcessSummary, *, with_ground: bool, with_overlay: bool,
           mounts: MountSource | None = None) -> dict[str, Any] | None:
    """Process one depth message, counting it in ``summary``; its messages."""
    summary.frames += 1
    messages, result, reason, note = process_frame(
        depth, cameras, config, with_ground=with_ground, with_overlay=with_overlay,
        mounts=mounts)
    _note(summary, note)
    if messages is None:
        summary.skipped[reason] += 1
        return None
    if summary.processed == 0 and mounts is not None:
        summary.mount = f"{mounts.source} (the bag's {TF_STATIC}): " + \
            tool_support.mount_text(result.pose.nominal)
    beyond_bounds = result.floor is not None and result.floor.beyond_bounds
    if summary.processed % MOUNT_CHECK_EVERY == 0 or beyond_bounds:
        number = summary.processed + 1
        check = tool_support.check_mount(result.depth_m, result.intrinsics,
                                         result.pose.nominal,
                                         fix=MOUNT_FIX if mounts is None else MOUNT_FIX_TF)
        summary.mount_checked.append(number)
        if check.warning:
            summary.mount_off.append(number)
            if summary.mount_warning is None:   # said once; the summary counts the others
                summary.mount_warning = f'frame {number}: {check.warning}'
                tool_support.warn(summary.mount_warning)
    summary.obstacle_points += int(result.obstacle_points.shape[0])
    summary.processed += 1
    summary.total_ms.append(result.timings_ms.get('total', 0.0))
    return messages

