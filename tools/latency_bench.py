#!/usr/bin/env python3
"""Latency and throughput of the running detector node through DDS, as a camera would feed it.

Starts the node (``params/corridor.yaml``) and a camera publisher process on loopback DDS in a
domain of its own, streams 30 pre-rendered depth frames of the ``person_walking`` scene round
robin at ``--rate`` Hz (sensor-data QoS), and measures per frame the depth stamp
-> costmap latency, the node's processing time, frames without a costmap, and the node's memory
and CPU. Prints a table and one ``JSON`` line.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import queue
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from obstacle_detection.cli import node_process
from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.support import ToolError

PARAMS = tool_support.package_file('params/corridor.yaml')
NODE = '/obstacle_detector'
SCENE, FRAMES = 'person_walking', 30
#: Seconds to wait for the node to be ready.
READY_TIMEOUT_S = 300.0
#: Seconds at the start of the stream not counted.
WARMUP_S = 5.0


def _publish(depth: np.ndarray, rate_hz: float, duration_s: float, report: Any) -> None:
    """Publish the frames ``depth`` round robin; put a summary dict on ``report``."""
    import rclpy
    import rclpy.time
    from builtin_interfaces.msg import Time
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image

    from obstacle_detection.pipeline.params import KINECT_V2_SD
    from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info

    rclpy.init()
    node = rclpy.create_node('latency_bench_camera')
    depth_pub = node.create_publisher(Image, 'depth/image_raw', qos_profile_sensor_data)
    info_pub = node.create_publisher(CameraInfo, 'depth/camera_info', qos_profile_sensor_data)
    images = [array_to_image(frame, stamp=Time(), frame_id='depth_optical') for frame in depth]
    info = intrinsics_to_camera_info(KINECT_V2_SD, depth.shape[2], depth.shape[1], stamp=Time(),
                                     frame_id='depth_optical')
    deadline = time.monotonic() + 30.0
    while depth_pub.get_subscription_count() == 0 or info_pub.get_subscription_count() == 0:
        if time.monotonic() > deadline:
            report.put({'error': 'the node did not subscribe within 30 s'})
            return
        time.sleep(0.05)
    time.sleep(0.5)
    period = 1.0 / rate_hz
    start = time.monotonic()
    sent = 0
    while sent * period < duration_s:
        wait = start + sent * period - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        stamp = rclpy.time.Time(nanoseconds=time.time_ns()).to_msg()
        info.header.stamp = stamp
        image = images[sent % len(images)]
        image.header.stamp = stamp
        info_pub.publish(info)
        depth_pub.publish(image)
        sent += 1
    report.put({'sent': sent})
    time.sleep(1.0)
    node.destroy_node()
    rclpy.try_shutdown()


def _proc_stats(pid: int) -> tuple[float, float]:
    """(RSS [MiB], user + system CPU time [s]) of a process, from /proc."""
    try:
        stat = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        pages = int(Path(f'/proc/{pid}/statm').read_text().split()[1])
    except OSError:
        return math.nan, math.nan
    return (pages * os.sysconf('SC_PAGE_SIZE') / 2**20,
            (int(stat[11]) + int(stat[12])) / os.sysconf('SC_CLK_TCK'))


def _percentiles(values: Sequence[float]) -> dict[str, float]:
    """Median, p90, p99 and max of ``values`` (NaN when there are none)."""
    found = np.percentile(values, (50, 90, 99, 100)) if len(values) else [math.nan] * 4
    return dict(zip(('median', 'p90', 'p99', 'max'), map(float, found)))


def _probe(node: Any) -> tuple[dict[int, int], list]:
    """Subscribe to the node's costmap and processing time; return their records."""
    from nav_msgs.msg import OccupancyGrid
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    arrivals: dict[int, int] = {}   # costmap stamp -> arrival [ns]
    times_ms: list[tuple[int, float]] = []
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(
        OccupancyGrid, 'obstacles/costmap',
        lambda m: arrivals.setdefault(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec,
                                      time.time_ns()), reliable)
    node.create_subscription(Float64, f'{NODE}/processing_time_ms',
                             lambda m: times_ms.append((time.time_ns(), m.data)), reliable)
    return arrivals, times_ms


def _stream(args: argparse.Namespace, executor: Any, node: Any, publisher: Any,
            log: Path) -> float:
    """Spin while the publisher streams; return the node's memory [MiB] after the warm-up."""
    from obstacle_detection.cli.progress import Progress

    began = time.monotonic()
    rss_warm = math.nan
    with Progress(int(args.duration), 'streaming [s]') as bar:
        while publisher.is_alive():
            executor.spin_once(timeout_sec=0.01)
            elapsed = time.monotonic() - began
            if math.isnan(rss_warm) and elapsed >= WARMUP_S:
                rss_warm = _proc_stats(node.pid)[0]
            if bar.count < min(int(elapsed), int(args.duration)):
                bar.update()
            if node.poll() is not None:
                raise ToolError(log, f'the node exited with code {node.returncode}')
    drain = time.monotonic() + 2.0
    while time.monotonic() < drain:
        executor.spin_once(timeout_sec=0.01)
    return rss_warm


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Run the node, the camera process and the probe; return the figures."""
    from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE
    from obstacle_detection.sim.scenes import render_scene

    work = Path(tempfile.mkdtemp(prefix='latency_bench_'))
    log = work / 'node.log'
    frames = [render_scene(SCENE, seed=0, intrinsics=KINECT_V2_SD, size=KINECT_V2_SD_SIZE,
                           frame_index=k) for k in range(FRAMES)]
    env = node_process.use_loopback(args.domain_id, work / 'ros_log')
    os.environ['ROS_LOG_DIR'] = env['ROS_LOG_DIR']   # the camera process's too
    overrides = [*node_process.mount_overrides(frames[0]), *args.set]
    node = node_process.start_node(node_process.node_command(PARAMS, overrides), env, log)
    spawn = multiprocessing.get_context('spawn')
    reports = spawn.Queue()
    publisher = spawn.Process(target=_publish, args=(
        np.stack([f.depth_mm for f in frames]), args.rate, args.duration, reports))
    with node_process.probe_node('latency_bench_probe', node) as (probe, executor, status):
        try:
            arrivals, times_ms = _probe(probe)
            ready = node_process.wait_ready(   # compiled, or the numpy path for good
                executor, node, status, READY_TIMEOUT_S, log,
                lambda text: text.endswith('compiled numba kernels') or 'numpy path (' in text)
            print(f'node {ready}; publishing {SCENE} at {args.rate:g} Hz for '
                  f'{args.duration:g} s', file=sys.stderr)
            publisher.start()
            rss0, cpu0 = _proc_stats(node.pid)
            began = time.monotonic()
            rss_warm = _stream(args, executor, node, publisher, log)
            rss1, cpu1 = _proc_stats(node.pid)
            elapsed = time.monotonic() - began
            try:
                report = reports.get(timeout=10.0)
            except queue.Empty:
                raise ToolError(f'the camera process failed (exit code {publisher.exitcode})') \
                    from None
            if 'error' in report:
                raise ToolError(log, report['error'])
        finally:
            if publisher.is_alive():
                publisher.kill()
    # the first costmap's stamp starts the warm-up, which is not counted
    cut = min(arrivals, default=0) + int(WARMUP_S * 1e9)
    latencies = [(arrival - stamp) / 1e6 for stamp, arrival in sorted(arrivals.items())
                 if stamp >= cut]
    sent = max(report['sent'] - round(WARMUP_S * args.rate), 0)
    rss_warm = rss0 if math.isnan(rss_warm) else rss_warm
    return {
        'rate_hz': args.rate, 'duration_s': args.duration, 'overrides': list(args.set),
        'frames_sent': sent, 'costmaps_received': len(latencies),
        'frames_without_output': max(sent - len(latencies), 0),
        'latency_ms': _percentiles(latencies),
        'processing_ms': _percentiles([ms for t, ms in times_ms if t >= cut]),
        'node_cpu_share': (cpu1 - cpu0) / elapsed, 'node_rss_mib': {
            'start': rss0, 'after_warmup': rss_warm, 'end': rss1,
            'growth_after_warmup': rss1 - rss_warm},
        'log': str(log),
    }


def format_table(fig: dict[str, Any]) -> str:
    """Return the figures as a Markdown table."""
    mem = fig['node_rss_mib']
    rows = [
        ('frames sent / costmaps received', f'{fig["frames_sent"]} / '
                                            f'{fig["costmaps_received"]}'),
        ('frames without a costmap', str(fig['frames_without_output'])),
        ('latency stamp -> costmap [ms] median / p90 / p99 / max',
         ' / '.join(f'{v:.1f}' for v in fig['latency_ms'].values())),
        ('node processing [ms] median / p90 / p99 / max',
         ' / '.join(f'{v:.1f}' for v in fig['processing_ms'].values())),
        ('node CPU [share of one core]', f'{fig["node_cpu_share"]:.2f}'),
        ('node memory [MiB] after warm-up -> end (growth)',
         f'{mem["after_warmup"]:.0f} -> {mem["end"]:.0f} ({mem["growth_after_warmup"]:+.1f})'),
    ]
    head = (f'{SCENE} at {fig["rate_hz"]:g} Hz for {fig["duration_s"]:g} s, sensor-data QoS, '
            f'{PARAMS.name} {" ".join(fig["overrides"])}')
    lines = [head, '', '| figure | value |', '| --- | --- |']
    lines += [f'| {name} | {value} |' for name, value in rows]
    return '\n'.join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(prog='latency_bench',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--duration', type=float, default=600.0,
                        help='seconds of streaming (default %(default)s: 10 minutes)')
    parser.add_argument('--rate', type=float, default=30.0, help='frames per second (30)')
    parser.add_argument('--set', action='append', default=[], metavar='NAME:=VALUE',
                        help='node parameter override, e.g. median_kernel:=5 (repeatable)')
    tool_support.add_domain_id_option(
        parser, 'ROS_DOMAIN_ID, 0-232')
    return parser


@tool_support.command('latency_bench')
def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; return the exit code (0 done, 1 could not run, 2 bad usage)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.duration > WARMUP_S or not 0 < args.rate <= 1000:
        parser.error(f'--duration must exceed the {WARMUP_S:g} s of warm-up, --rate be in '
                     '(0, 1000]')
    figures = run(args)
    print(format_table(figures))
    print('JSON ' + json.dumps(figures))
    return 0


if __name__ == '__main__':
    sys.exit(main())
