#!/usr/bin/env python3
"""The bundled demo: a recorded-looking depth sequence through the running detector node.

It renders a scene sequence, converts it to a rosbag2, replays it into the node on loopback DDS,
records what the node publishes and draws it, all in ``--output``. Exit code 0 when the node
produced output, else 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from obstacle_detection.cli import bag_player, bag_writer, node_process
from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.recorder import Recorder, write_bag
from obstacle_detection.cli.support import ToolError
from obstacle_detection.evaluation import datasets

DEFAULT_PARAMS = tool_support.package_file('params/corridor.yaml')
MARKER = '.obstacle_detection_demo'
#: The node's outputs (after its default names) -> message type name.
OUTPUT_TOPICS = {
    '/obstacles/points': 'sensor_msgs/msg/PointCloud2',
    '/obstacles/costmap': 'nav_msgs/msg/OccupancyGrid',
    '/obstacles/overlay': 'sensor_msgs/msg/Image',
    '/obstacle_detector/processing_time_ms': 'std_msgs/msg/Float64',
    '/obstacles/fused_costmap': 'nav_msgs/msg/OccupancyGrid',
}
#: Frames a second the demo replays at.
DEMO_FPS = 7.5
#: Every this many-th frame of the sequence (30 Hz) is taken.
STEP = 10
#: Seconds to wait for the node to be ready.
READY_TIMEOUT_S = 60.0
#: Width of a frame in the contact sheet [px]: two columns, about as wide as the README's text.
SHEET_THUMB_PX = 600


def save_pictures(folder: Path, recorder: Recorder, every: int,
                  poses: dict[tuple[int, int], Any]) -> list[Path]:
    """Save a picture of every ``every``-th frame the node published, and a contact sheet.

    Frames are matched across topics by header stamp; ``poses`` (by stamp) draw the robot on
    the fused costmap.
    """
    from nav_msgs.msg import OccupancyGrid
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image, PointCloud2

    from obstacle_detection.ros.conversions import image_to_rgb, occupancy_grid_to_costmap
    from obstacle_detection.viz import pictures

    def by_stamp(topic: str, cls: type) -> dict[tuple[int, int], Any]:
        messages = (deserialize_message(raw, cls) for _, raw in recorder.messages[topic])
        return {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in messages}

    grids = by_stamp('/obstacles/costmap', OccupancyGrid)
    overlays = by_stamp('/obstacles/overlay', Image)
    clouds = by_stamp('/obstacles/points', PointCloud2)
    fused = by_stamp('/obstacles/fused_costmap', OccupancyGrid)
    saved: list[Path] = []
    thumbs: list[np.ndarray] = []
    first_ns = min((sec * 10**9 + nsec for sec, nsec in grids), default=0)
    for k, stamp in enumerate(sorted(grids)):
        if k % every or stamp not in overlays:
            continue
        costmap = occupancy_grid_to_costmap(grids[stamp])
        cloud = clouds.get(stamp)
        points = int(cloud.width * cloud.height) if cloud is not None else 0
        when = f'frame {k}, {tool_support.time_text(stamp[0] * 10**9 + stamp[1], first_ns)}'
        caption = [f'{when}: {points} obstacle points, '
                   f'{int(np.count_nonzero(costmap.data == 100))} occupied cells']

        def draw(**options: Any) -> np.ndarray:
            return pictures.node_outputs(
                image_to_rgb(overlays[stamp]), costmap, caption=caption,
                robot_pose=poses.get(stamp, (0.0, 0.0, 0.0)),
                fused=occupancy_grid_to_costmap(fused[stamp]) if stamp in fused else None,
                **options)

        saved.append(folder / 'pictures' / f'frame_{k:04d}.png')
        pictures.write_png(saved[-1], pictures.titled(
            draw(), f'What the detector node published, {when}'))
        thumbs.append(pictures.fit_width(
            lambda scale: draw(image_scale=scale, with_legend=False), SHEET_THUMB_PX))
    if thumbs:
        sheet = pictures.tile(thumbs, columns=2)
        panels = 3 if fused else 2
        legend = pictures.node_outputs_legend([(sheet.shape[1] - 6 * (panels - 1)) // panels]
                                              * panels)
        pictures.write_png(folder / 'demo_sheet.png', pictures.titled(
            sheet, f'What the detector node published: {len(thumbs)} of its frames (overlay, '
                   'costmap, fused costmap in odom)', below=legend))
    return saved


def run_demo(args: argparse.Namespace) -> int:
    """Run every step into ``--output``, emptied first (only a folder the demo made)."""
    began = time.monotonic()
    out: Path = args.output.resolve()  # absolute: the node runs with another working directory
    if out.exists() and not (out / MARKER).exists() and (
            not out.is_dir() or any(out.iterdir())):
        raise ToolError(out, 'exists and was not made by the demo; choose another --output')
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    (out / MARKER).write_text('made by tools/demo.py; emptied when the demo runs again\n')
    report = _run_steps(args, out)
    print()
    print(f'demo done in {time.monotonic() - began:.1f} s; everything is in {args.output}/')
    print('\n'.join(report))
    return 0


def _write_input(args: argparse.Namespace, out: Path) -> tuple[Any, Any, dict, float]:
    """Render the frames as 16-bit PNGs and convert them to a bag (steps 1 and 2).

    Returns (bag summary, first SceneFrame, odometry pose by stamp, bag frame rate [Hz]).
    """
    from obstacle_detection.evaluation.camera import camera_yaml_text
    from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE
    from obstacle_detection.sim.sequences import SEQUENCE_RATE_HZ, SceneSequence

    depth_dir = out / 'input' / 'depth'
    print(f'[1/5] rendering {args.frames} frames of {args.scene!r} (every {STEP}th, with '
          f'odometry) into {depth_dir}')
    depth_dir.mkdir(parents=True)
    sequence = SceneSequence(args.scene, seed=0)
    items = [sequence.frame(i) for i in range(0, min(len(sequence), args.frames * STEP), STEP)]
    for k, item in enumerate(items):
        if not cv2.imwrite(str(depth_dir / f'{args.scene}_{k:04d}.png'), item.frame.depth_mm):
            raise ToolError(depth_dir, 'cannot write depth PNGs')
    camera = out / 'input' / 'camera.yaml'
    camera.write_text(camera_yaml_text(KINECT_V2_SD, size=KINECT_V2_SD_SIZE,
                                       comment='Kinect v2 SD camera of the rendered scene'))
    bag_hz = SEQUENCE_RATE_HZ / STEP
    print(f'[2/5] converting them to a rosbag2: {out / "input_bag"}')
    source = datasets.folder_frames(depth_dir, intrinsics_path=camera, rate_hz=bag_hz,
                                    start_s=float(int(time.time())))
    source.frames = [dataclasses.replace(f, pose=item.pose_odom)
                     for f, item in zip(source.frames, items)]
    summary = bag_writer.write_frames(source, out / 'input_bag', bag_writer.BagOptions())
    print('\n'.join('      ' + line for line in summary.lines()[1:4]))
    pose_by_stamp = {divmod(f.stamp_ns, 1_000_000_000): f.pose for f in source.frames}
    return summary, items[0].frame, pose_by_stamp, bag_hz


def _replay(out: Path, node: Any, bag_hz: float,
            frames: int) -> tuple[Recorder, list[str], int]:
    """Wait for the node, replay the bag into it, record what it publishes (steps 3, 4).

    Returns (recorder, the node's status lines, depth frames sent).
    """
    player = thread = None
    stop = threading.Event()
    stats: list[bag_player.PlayStats] = []
    with node_process.probe_node('demo_recorder', node) as (probe, executor, status):
        try:
            recorder = Recorder(probe, OUTPUT_TOPICS)
            player = bag_player.Player(probe, out / 'input_bag', bag_player.PlayOptions(
                rate=DEMO_FPS / bag_hz, reliable=True, progress=False))
            # until it says ready and subscribes to the depth and camera info
            ready = node_process.wait_ready(
                executor, node, status, READY_TIMEOUT_S, out / 'node.log',
                lambda _: player.subscription_count() >= 2)
            print(f'      node {ready}')
            settle = time.monotonic() + 0.5  # let the node's side of the match settle too
            while time.monotonic() < settle:
                executor.spin_once(timeout_sec=0.05)
            print(f'[4/5] replaying {frames} frames at {DEMO_FPS:g} Hz into the node')
            thread = threading.Thread(target=lambda: stats.append(player.play(stop)),
                                      daemon=True)
            thread.start()
            while thread.is_alive():
                executor.spin_once(timeout_sec=0.05)
                if node.poll() is not None:
                    stop.set()
            # Until every output of every frame arrived, or nothing new came for 3 s after the
            # replay ended (the recorder's clock starts before the node is ready).
            played = time.monotonic()
            while (min(map(recorder.count, OUTPUT_TOPICS)) < frames
                   and time.monotonic() - max(recorder.last_arrival, played) < 3.0
                   and node.poll() is None):
                executor.spin_once(timeout_sec=0.05)
        finally:
            stop.set()
            if thread is not None:
                thread.join(timeout=5)
            if player is not None:
                player.close()
    sent = stats[0].published.get(bag_writer.DEFAULT_DEPTH_TOPIC, 0) if stats else 0
    return recorder, status, sent


def _run_steps(args: argparse.Namespace, out: Path) -> list[str]:
    """Run the demo's steps into ``out``; return the summary lines to print."""
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64

    summary, first, pose_by_stamp, bag_hz = _write_input(args, out)
    env = node_process.use_loopback(args.domain_id, out / 'ros_log')
    # the fused costmap is on, moved by the bag's odometry
    command = node_process.node_command(
        args.params, ['publish_overlay:=true', 'stats_period_s:=1.0',
                      *node_process.mount_overrides(first), 'reliable_input:=true', 'fuse:=true',
                      f'odom_topic:={bag_writer.DEFAULT_ODOM_TOPIC}'],
        [f'depth/image_raw:={bag_writer.DEFAULT_DEPTH_TOPIC}',
         f'depth/camera_info:={bag_writer.DEFAULT_INFO_TOPIC}'])
    print(f'[3/5] starting the detector node (ROS_DOMAIN_ID={args.domain_id}, loopback only; '
          f'log: {out / "node.log"}):\n      {" ".join(command[1:])}')
    node = node_process.start_node(command, env, out / 'node.log')
    recorder, status, sent = _replay(out, node, bag_hz, summary.frames)

    received = recorder.count('/obstacles/costmap')
    if received == 0:
        raise ToolError(out / 'node.log', f'the detector node published nothing for '
                        f'{summary.frames} frames; the end of its log:\n'
                        + node_process.log_tail(out / 'node.log'))
    print(f'[5/5] writing what the node published: {out / "results_bag"}; pictures: '
          f'{out / "pictures"}')
    write_bag(out / 'results_bag', recorder)
    saved = save_pictures(out, recorder, args.save_every, pose_by_stamp)
    times = [deserialize_message(raw, Float64).data
             for _, raw in recorder.messages['/obstacle_detector/processing_time_ms']]
    report = [f'  depth frames sent: {sent}, results received: {received} costmaps, '
              f'{recorder.count("/obstacles/points")} obstacle clouds, '
              f'{recorder.count("/obstacles/overlay")} overlays']
    if times:
        report.append(f'  node processing time: mean {np.mean(times):.1f} ms, '
                      f'max {np.max(times):.1f} ms per frame')
    if status:
        report.append(f'  the node ended on the {status[-1].split(": ", 1)[-1]}')
    if received < sent:
        report.append(f'  {sent - received} frame(s) had no output: skipped by the node or '
                      'dropped while it was busy (see node.log)')
    report.append(f'  pictures: {len(saved)} side-by-side frames in {out / "pictures"}, '
                  f'contact sheet {out / "demo_sheet.png"}')
    report.append(f'  bags: {out / "input_bag"} (input), {out / "results_bag"} (node output)')
    return report


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    from obstacle_detection.sim.sequences import SEQUENCE_NAMES

    parser = argparse.ArgumentParser(prog='demo', description=__doc__.split('\n\n')[0])
    parser.add_argument('--output', type=Path, default=Path('out/demo'),
                        help='folder for everything the demo writes (default %(default)s), '
                             'emptied first')
    parser.add_argument('--scene', choices=SEQUENCE_NAMES, default='drive_past_boxes',
                        help='a scene sequence with odometry (the fused costmap follows it; '
                             'default %(default)s)')
    parser.add_argument('--frames', type=tool_support.int_in(1), default=30,
                        help='frames (default %(default)s)')
    parser.add_argument('--params', type=Path, default=DEFAULT_PARAMS,
                        help='node params file (default params/corridor.yaml); the camera '
                             'mount is set to the rendered scene\'s')
    parser.add_argument('--save-every', type=tool_support.int_in(1), default=5,
                        help='save pictures of one frame in N (default %(default)s)')
    tool_support.add_domain_id_option(
        parser, 'ROS_DOMAIN_ID of the demo, 0-232')
    return parser


@tool_support.command('demo')
def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; return the exit code (0 success, 1 failure, 2 bad usage)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.params.is_file():
        raise ToolError(args.params, 'params file not found')
    return run_demo(args)


if __name__ == '__main__':
    sys.exit(main())
