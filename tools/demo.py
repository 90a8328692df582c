#!/usr/bin/env python3
"""The bundled demo: a recorded-looking depth sequence through the running detector node.

Steps, all into one output folder (default ``out/demo``):

1. render a short sequence of the scene generator (30 frames of 'person_walking' at the Kinect v2
   SD size) as a folder of 16-bit depth PNGs plus an intrinsics YAML (``input/``);
2. convert it to a rosbag2 with the converter (``input_bag/``, Kinect v2 driver topics);
3. start the detector node (``python -m obstacle_detection.ros.node --ros-args --params-file
   params/corridor.yaml``, its inputs remapped to the bag's topics; log in ``node.log``);
4. replay the bag into it with the player, while a recorder in this process subscribes to
   what the node publishes and writes it to ``results_bag/``;
5. save, per saved frame, the node's overlay (depth with obstacle pixels red), the costmap and
   both side by side (``pictures/``), plus a contact sheet (``demo_sheet.png``).

The replay starts only when the node says it is ready (its latched ``~/status`` topic), not when
its subscription is matched. Everything is written into ``<output>.partial`` and moved to
``<output>`` only when the demo succeeded, so a failed run leaves the previous result in place
(the failed run's files go to ``<output>.failed``, for its ``node.log``).

DDS stays on the loopback interface (``obstacle_detection/ros/fastdds_loopback.xml``) in a ROS
domain of the demo's own. Exit code 0 when the node produced output, 1 (with the reason) otherwise.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from obstacle_detection.cli import support as tool_support
from obstacle_detection.evaluation import datasets
from obstacle_detection.cli import bag_player, bag_writer
from obstacle_detection.cli.recorder import Recorder, write_bag
from obstacle_detection.ros.dds_env import loopback_env

REPO = tool_support.PACKAGE_ROOT
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
#: Frames a second the demo replays at, unless --rate says otherwise.
DEMO_FPS = 7.5
#: Width of a frame in the contact sheet [px]: two columns, about as wide as the README's text.
SHEET_THUMB_PX = 600


class DemoError(Exception):
    """The demo could not run or the node produced nothing; the message says why."""


def _check_demo_folder(folder: Path) -> None:
    """Refuse ``folder`` if it exists and was not made by the demo."""
    if folder.exists():
        if not folder.is_dir():
            raise DemoError(f'{folder}: exists and is not a folder')
        if any(folder.iterdir()) and not (folder / MARKER).exists():
            raise DemoError(f'{folder}: exists and was not made by the demo; choose another '
                            '--output')


def prepare_output(folder: Path) -> None:
    """Create ``folder``, or empty it if an earlier demo made it; refuse any other folder."""
    _check_demo_folder(folder)
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    (folder / MARKER).write_text('made by tools/demo.py; emptied when the demo runs again\n')


def staging_folders(output: Path) -> tuple[Path, Path]:
    """Return (work, failed): where a run writes, and where a failed run's files are kept."""
    return (output.with_name(output.name + '.partial'),
            output.with_name(output.name + '.failed'))


def publish_output(work: Path, output: Path) -> None:
    """Replace ``output`` (a demo folder, or absent) with the finished ``work`` folder."""
    _check_demo_folder(output)
    old = output.with_name(output.name + '.old')
    if old.exists():
        shutil.rmtree(old)
    if output.exists():
        output.rename(old)
    work.rename(output)
    if old.exists():
        shutil.rmtree(old)


def keep_failed(work: Path, failed: Path) -> None:
    """Move a failed run's ``work`` folder to ``failed`` (replacing an older failure)."""
    if not work.exists():
        return
    if failed.exists():
        _check_demo_folder(failed)
        shutil.rmtree(failed)
    work.rename(failed)


def render_sequence(folder: Path, scene: str, frames: int, seed: int, step: int = 1
                    ) -> tuple[Path, Path, Any, list[tuple[float, float, float]] | None]:
    """Write the frames as 16-bit PNGs [mm] and a camera YAML.

    scene: a scene of the generator (a static camera) or a sequence with a known trajectory
    (every ``step``-th frame of it). Returns (depth folder, camera YAML, the first SceneFrame,
    the odometry pose of each frame or None for a static scene).
    """
    from obstacle_detection.evaluation.camera import camera_yaml_text
    from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE
    from obstacle_detection.sim.scenes import render_scene
    from obstacle_detection.sim.sequences import SEQUENCE_NAMES, SceneSequence

    depth_dir = folder / 'depth'
    depth_dir.mkdir(parents=True)
    first = None
    poses: list[tuple[float, float, float]] | None = None
    if scene in SEQUENCE_NAMES:
        sequence = SceneSequence(scene, seed=seed)
        indices = range(0, min(len(sequence), frames * step), step)
        poses = []
        rendered = []
        for index in indices:
            item = sequence.frame(index)
            poses.append(item.pose_odom)
            rendered.append(item.frame)
    else:
        rendered = (render_scene(scene, seed=seed, intrinsics=KINECT_V2_SD,
                                 size=KINECT_V2_SD_SIZE, frame_index=k) for k in range(frames))
    for k, frame in enumerate(rendered):
        first = frame if first is None else first
        if not cv2.imwrite(str(depth_dir / f'{scene}_{k:04d}.png'), frame.depth_mm):
            raise DemoError(f'{depth_dir}: cannot write depth PNGs')
    intr = KINECT_V2_SD
    camera = folder / 'camera.yaml'
    camera.write_text(camera_yaml_text(intr, comment='Kinect v2 SD camera of the rendered scene',
                                       size=KINECT_V2_SD_SIZE))
    return depth_dir, camera, first, poses


def save_pictures(folder: Path, recorder: Recorder, every: int, params: Any = None,
                  intrinsics: Any = None,
                  poses: dict[tuple[int, int], Any] | None = None) -> list[Path]:
    """Save overlay, costmap and side-by-side PNGs of every ``every``-th frame; a contact sheet.

    Frames are matched across topics by header stamp. The costmap panel has metre axes, the
    camera, the region of interest (hatched outside) and the floor in view when ``params``
    (the node's DetectorParams) and ``intrinsics`` are given; the fused costmap (odom) beside
    it when the node published one, the robot at its odometry pose (``poses`` by stamp); each
    picture has a title and a legend. The contact sheet: two columns of thumbnails drawn at
    the size they are shown (the images scaled, the text not), one legend underneath.
    Returns the side-by-side paths.
    """
    from nav_msgs.msg import OccupancyGrid
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image, PointCloud2

    from obstacle_detection.ros.conversions import image_to_rgb, occupancy_grid_to_costmap
    from obstacle_detection.viz import pictures

    def by_stamp(topic: str, cls: type) -> dict[tuple[int, int], Any]:
        out = {}
        for _, raw in recorder.messages[topic]:
            msg = deserialize_message(raw, cls)
            out[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = msg
        return out

    grids = by_stamp('/obstacles/costmap', OccupancyGrid)
    overlays = by_stamp('/obstacles/overlay', Image)
    clouds = by_stamp('/obstacles/points', PointCloud2)
    fused = by_stamp('/obstacles/fused_costmap', OccupancyGrid)
    saved: list[Path] = []
    thumbs: list[np.ndarray] = []
    out = folder / 'pictures'
    for k, stamp in enumerate(sorted(grids)):
        if k % every or stamp not in overlays:
            continue
        overlay = image_to_rgb(overlays[stamp])
        costmap = occupancy_grid_to_costmap(grids[stamp])
        cloud = clouds.get(stamp)
        points = int(cloud.width * cloud.height) if cloud is not None else 0
        occupied = int(np.count_nonzero(costmap.data == 100))
        when = f'frame {k}, t = {stamp[0]}.{stamp[1]:09d} s'
        caption = [f'{when}: {points} obstacle points, {occupied} occupied cells']
        options = dict(caption=caption, params=params, intrinsics=intrinsics,
                       fused=occupancy_grid_to_costmap(fused[stamp]) if stamp in fused else None,
                       robot_pose=(poses or {}).get(stamp) or (0.0, 0.0, 0.0))
        picture, grid_rgb = pictures.node_outputs(overlay, costmap, **options)
        name = f'frame_{k:04d}'
        pictures.write_png(out / f'overlay_{k:04d}.png', pictures.titled(
            overlay, f'obstacles/overlay, {when}',
            below=pictures.overlay_legend(overlay.shape[1])))
        pictures.write_png(out / f'costmap_{k:04d}.png', pictures.titled(
            grid_rgb, f'obstacles/costmap, {when}',
            below=pictures.costmap_legend(max(grid_rgb.shape[1], 480))))
        pictures.write_png(out / f'{name}.png', pictures.titled(
            picture, f"What the detector node published, {when}"))
        saved.append(out / f'{name}.png')
        thumb = pictures.fit_width(
            lambda scale: pictures.node_outputs(overlay, costmap, **options, image_scale=scale,
                                                with_legend=False)[0], SHEET_THUMB_PX)
        thumbs.append(thumb)
    if thumbs:
        sheet = pictures.contact_sheet(thumbs, columns=2, thumb_width=SHEET_THUMB_PX)
        panels = 3 if fused else 2
        legend = pictures.node_outputs_legend([(sheet.shape[1] - 6 * (panels - 1)) // panels]
                                              * panels)
        pictures.write_png(folder / 'demo_sheet.png', pictures.titled(
            sheet, f'What the detector node published: {len(thumbs)} of its frames (overlay, '
                   'costmap, fused costmap in odom)', below=legend))
    return saved


def _scene_params(path: Path, frame: Any) -> Any:
    """Return the node's pipeline parameters: the params file, the rendered scene's mount."""
    import dataclasses

    from obstacle_detection.evaluation.runner import load_params_file

    params = load_params_file(path)
    return dataclasses.replace(params, camera_height_m=float(frame.height_m),
                               camera_pitch_rad=float(frame.pitch_rad),
                               camera_roll_rad=float(frame.roll_rad))


def _node_command(params: Path, frame: Any, *, reliable: bool, odom_topic: str) -> list[str]:
    """Return the detector node command: inputs remapped to the bag's, the scene's mount.

    The fused costmap is on, moved by the bag's odometry (a static scene has none: it fuses
    in place, as the node says in its log).
    """
    import math

    return [sys.executable, '-m', 'obstacle_detection.ros.node', '--ros-args',
            '--params-file', str(params),
            '-r', f'depth/image_raw:={bag_writer.DEFAULT_DEPTH_TOPIC}',
            '-r', f'depth/camera_info:={bag_writer.DEFAULT_INFO_TOPIC}',
            '-p', 'publish_overlay:=true', '-p', 'stats_period_s:=1.0',
            '-p', f'camera_height_m:={float(frame.height_m)!r}',
            '-p', f'camera_pitch_deg:={round(math.degrees(frame.pitch_rad), 9)!r}',
            '-p', f'camera_roll_deg:={round(math.degrees(frame.roll_rad), 9)!r}',
            '-p', f'reliable_input:={"true" if reliable else "false"}',
            '-p', 'fuse:=true', '-p', f'odom_topic:={odom_topic}']


def _stop(process: subprocess.Popen) -> None:
    """Stop the node with Ctrl-C, as a user would; kill it if it does not stop."""
    if process.poll() is not None:
        return
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=5)


def _log_tail(path: Path, lines: int = 15) -> str:
    try:
        return '\n'.join(path.read_text(errors='replace').splitlines()[-lines:])
    except OSError:
        return '(no log)'


def _why_no_output(log_path: Path, best_effort: bool, rate: float) -> str:
    """Say from the node's log why frames had no output: skipped (and why) or dropped."""
    import re

    text = log_path.read_text(errors='replace') if log_path.is_file() else ''
    dropped = sum(int(n) for n in re.findall(r'(\d+) dropped \(a newer frame', text))
    skipped = sum(int(n) for n in re.findall(r'(\d+) skipped \(bad input\)', text))
    reasons = sorted(set(re.findall(r'skipping depth frame: ([^(\n]*)', text)))
    parts = []
    if skipped:
        why = '; '.join(r.strip() for r in reasons)
        if any('no valid depth pixel' in r for r in reasons):
            why += (': a camera closer than 0.5 m to a wall sees nothing, the Kinect v2\'s '
                    'blind zone')
        parts.append(f'{skipped} skipped by the node ({why})')
    if dropped:
        parts.append(f'{dropped} replaced by a newer frame while the node was busy (a lower '
                     f'--rate, now {rate:g}, gives it more time)')
    if best_effort:
        parts.append('best-effort frames may also be lost in transit')
    return '; '.join(parts) or 'see node.log'


def run_demo(args: argparse.Namespace) -> int:
    """Run every step into ``<output>.partial``; move it to ``<output>`` only on success.

    Raises DemoError when a step fails; the failed run's files are then in
    ``<output>.failed`` and the previous ``<output>`` is untouched.
    """
    began = time.monotonic()
    final: Path = args.output.resolve()  # absolute: the node runs with another working directory
    _check_demo_folder(final)
    work, failed = staging_folders(final)
    _check_demo_folder(work)
    prepare_output(work)
    try:
        report = _run_steps(args, work, failed)
    except BaseException:
        keep_failed(work, failed)
        raise
    publish_output(work, final)
    if failed.exists() and (failed / MARKER).exists():
        shutil.rmtree(failed)   # an older failure, now superseded
    print()
    print(f'demo done in {time.monotonic() - began:.1f} s; everything is in {args.output}/')
    for line in report:
        print(line.replace(str(work), str(final)))
    return 0


def _wait_until_ready(executor: Any, status: list[str], player: Any, node_process: Any,
                      timeout_s: float, log_hint: Path, log_path: Path) -> None:
    """Spin until the node's ~/status says ready and the player's topics are matched."""
    deadline = time.monotonic() + timeout_s
    while not (status and status[-1].startswith('ready') and player.subscription_count() >= 2):
        if node_process.poll() is not None:
            raise DemoError(f'the detector node exited with code {node_process.returncode}'
                            f' before it was ready; its log ({log_hint}):\n'
                            + _log_tail(log_path))
        if time.monotonic() > deadline:
            raise DemoError(f'the detector node did not say it was ready within {timeout_s:g} s'
                            f' (--timeout); its log ({log_hint}):\n' + _log_tail(log_path))
        executor.spin_once(timeout_sec=0.05)


def _run_steps(args: argparse.Namespace, out: Path, failed: Path) -> list[str]:
    """Run the demo's steps into ``out``; return the summary lines to print."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    import dataclasses

    from obstacle_detection.sim.sequences import SEQUENCE_NAMES, SEQUENCE_RATE_HZ

    step = args.step if args.scene in SEQUENCE_NAMES else 1
    print(f'[1/5] rendering {args.frames} frames of {args.scene!r}'
          f'{f" (every {step}th, with odometry)" if step > 1 else ""} into {out / "input"}')
    depth_dir, camera, first, poses = render_sequence(out / 'input', args.scene, args.frames,
                                                      args.seed, step)
    bag_hz = SEQUENCE_RATE_HZ / step
    rate = args.rate if args.rate is not None else DEMO_FPS / bag_hz

    print(f'[2/5] converting them to a rosbag2: {out / "input_bag"}')
    source = datasets.folder_frames(depth_dir, intrinsics_path=camera, rate_hz=bag_hz,
                                       start_s=float(int(time.time())))
    if poses is not None:
        source.frames = [dataclasses.replace(f, pose=p) for f, p in zip(source.frames, poses)]
    pose_by_stamp = ({(f.stamp_ns // 1_000_000_000, f.stamp_ns % 1_000_000_000): f.pose
                      for f in source.frames} if poses is not None else {})
    summary = bag_writer.write_frames(source, out / 'input_bag',
                                       bag_writer.BagOptions(progress=not args.quiet))
    print('\n'.join('      ' + line for line in summary.lines()[1:4]))

    env = loopback_env(args.domain_id)
    os.environ.update({k: env[k] for k in ('FASTDDS_DEFAULT_PROFILES_FILE',
                                           'FASTRTPS_DEFAULT_PROFILES_FILE',
                                           'RMW_IMPLEMENTATION', 'ROS_DOMAIN_ID')})
    for name in ('ROS_LOCALHOST_ONLY', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS'):
        os.environ.pop(name, None)
    child_env = dict(env, PYTHONPATH=os.pathsep.join(
        p for p in (str(REPO), env.get('PYTHONPATH', '')) if p), PYTHONUNBUFFERED='1',
        RCUTILS_COLORIZED_OUTPUT='0', ROS_LOG_DIR=str(out / 'ros_log'))
    command = _node_command(args.params, first, reliable=not args.best_effort,
                            odom_topic=bag_writer.DEFAULT_ODOM_TOPIC)
    print(f'[3/5] starting the detector node (ROS_DOMAIN_ID={args.domain_id}, loopback only; '
          f'log: {out / "node.log"}):\n      {" ".join(command[1:])}')
    with (out / 'node.log').open('w') as log:
        node_process = subprocess.Popen(command, cwd=REPO, env=child_env, stdout=log,
                                        stderr=subprocess.STDOUT)
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = Node('demo_recorder', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    player = None
    thread = None
    stop = threading.Event()
    try:
        recorder = Recorder(node, OUTPUT_TOPICS)
        status: list[str] = []
        node.create_subscription(String, '/obstacle_detector/status',
                                 lambda msg: status.append(msg.data),
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        options = bag_player.PlayOptions(rate=rate, reliable=not args.best_effort,
                                       wait_for_subscribers=2,
                                       wait_timeout_s=args.timeout, progress=False)
        player = bag_player.Player(node, out / 'input_bag', options)
        _wait_until_ready(executor, status, player, node_process, args.timeout,
                          failed / 'node.log', out / 'node.log')
        print(f'      node {status[-1]}')
        settle = time.monotonic() + 0.5  # let the node's side of the match settle too
        while time.monotonic() < settle:
            executor.spin_once(timeout_sec=0.05)

        print(f'[4/5] replaying {summary.frames} frames at {bag_hz * rate:g} Hz into the node')
        stats: list[bag_player.PlayStats] = []
        thread = threading.Thread(target=lambda: stats.append(player.play(stop)), daemon=True)
        thread.start()
        while thread.is_alive():
            executor.spin_once(timeout_sec=0.05)
            if node_process.poll() is not None:
                stop.set()
        # Let the last frames come out: until every output of every frame arrived, or
        # nothing new came for 3 s after the replay ended (frames the node dropped never
        # come). Counted from the replay's end too: the recorder's clock starts before the
        # node is ready, so a slow start must not end this wait before the first output.
        played = time.monotonic()
        while (min(map(recorder.count, OUTPUT_TOPICS)) < summary.frames
               and time.monotonic() - max(recorder.last_arrival, played) < 3.0
               and node_process.poll() is None):
            executor.spin_once(timeout_sec=0.05)
    finally:
        stop.set()
        if thread is not None:
            thread.join(timeout=5)
        if player is not None:
            player.close()
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
        _stop(node_process)

    received = recorder.count('/obstacles/costmap')
    if received == 0:
        raise DemoError(f'the detector node published nothing for {summary.frames} frames; '
                        f'its log ({failed / "node.log"}):\n' + _log_tail(out / 'node.log'))
    print(f'[5/5] writing what the node published: {out / "results_bag"}; pictures: '
          f'{out / "pictures"}')
    write_bag(out / 'results_bag', recorder)
    saved = save_pictures(out, recorder, args.save_every, _scene_params(args.params, first),
                          first.intrinsics, pose_by_stamp)

    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64

    times = [deserialize_message(raw, Float64).data
             for _, raw in recorder.messages['/obstacle_detector/processing_time_ms']]
    sent = stats[0].published.get(bag_writer.DEFAULT_DEPTH_TOPIC, 0) if stats else 0
    report = [f'  depth frames sent: {sent}, results received: {received} costmaps, '
              f'{recorder.count("/obstacles/points")} obstacle clouds, '
              f'{recorder.count("/obstacles/overlay")} overlays']
    if times:
        report.append(f'  node processing time: mean {np.mean(times):.1f} ms, '
                      f'max {np.max(times):.1f} ms per frame')
    if status:
        report.append(f'  the node ended on the {status[-1].split(": ", 1)[-1]}')
    if received < sent:
        report.append(f'  {sent - received} frame(s) had no output: '
                      + _why_no_output(out / 'node.log', args.best_effort, rate))
    report.append(f'  pictures: {len(saved)} side-by-side frames in {out / "pictures"}, '
                  f'contact sheet {out / "demo_sheet.png"}')
    report.append(f'  bags: {out / "input_bag"} (input), {out / "results_bag"} (node output)')
    return report


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    from obstacle_detection.sim.scenes import SCENE_NAMES
    from obstacle_detection.sim.sequences import SEQUENCE_NAMES

    parser = argparse.ArgumentParser(prog='demo', description=__doc__.split('\n\n')[0])
    parser.add_argument('--output', type=Path, default=Path('out/demo'),
                        help='folder for everything the demo writes (default %(default)s); '
                             'replaced only when the demo succeeds')
    parser.add_argument('--scene', choices=(*SEQUENCE_NAMES, *SCENE_NAMES),
                        default='drive_past_boxes',
                        help='a sequence with odometry (the robot drives or a person crosses; '
                             'the fused costmap follows it) or a scene of the generator seen '
                             'from a still camera (default %(default)s)')
    parser.add_argument('--step', type=int, default=10,
                        help='of a sequence (30 Hz), take every N-th frame (default '
                             '%(default)s)')
    parser.add_argument('--frames', type=int, default=30, help='frames (default %(default)s)')
    parser.add_argument('--seed', type=int, default=0, help='scene seed (default %(default)s)')
    parser.add_argument('--params', type=Path, default=DEFAULT_PARAMS,
                        help='node params file (default params/corridor.yaml); the camera '
                             'mount is set to the rendered scene\'s')
    parser.add_argument('--rate', type=float, default=None,
                        help='replay speed factor of the recorded timing (default: frames at '
                             f'{DEMO_FPS:g} Hz)')
    parser.add_argument('--best-effort', action='store_true',
                        help="replay with the camera's sensor-data QoS (best effort) instead of "
                             'reliable; large frames over UDP may then be lost')
    parser.add_argument('--save-every', type=int, default=5,
                        help='save pictures of one frame in N (default %(default)s)')
    tool_support.add_domain_id_option(
        parser, 'ROS_DOMAIN_ID of the demo, 0-232 (default: 100-200 from the process id)')
    parser.add_argument('--timeout', type=float, default=30.0,
                        help='seconds to wait for the node to say it is ready on its ~/status '
                             'topic (default %(default)s)')
    parser.add_argument('--quiet', action='store_true', help='no progress bars')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; return the exit code (0 success, 1 failure, 2 bad usage)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.frames < 1 or args.save_every < 1 or args.step < 1:
        parser.error('--frames, --step and --save-every must be >= 1')
    if args.rate is not None and not args.rate > 0:
        parser.error(f'--rate must be > 0, got {args.rate:g}')
    if not args.params.is_file():
        print(f'error: {args.params}: params file not found', file=sys.stderr)
        return 1
    try:
        return run_demo(args)
    except (DemoError, datasets.EvaluationError, tool_support.ToolError) as err:
        print(f'error: {err}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
