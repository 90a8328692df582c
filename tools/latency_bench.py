#!/usr/bin/env python3
"""Latency and throughput of the running detector node through DDS, as a camera would feed it.

Starts the node and a camera publisher process on loopback DDS in a domain of its own, streams
pre-rendered depth frames of a scene at ``--rate`` Hz, and measures per frame the depth stamp
-> costmap latency, the node's processing time, frames without a costmap, and the node's memory
and CPU. Prints a table and one ``JSON`` line; exit code 0 when the run completed, 1 when it
could not run, 2 for bad usage.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
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

DEFAULT_PARAMS = tool_support.package_file('params/corridor.yaml')
NODE = '/obstacle_detector'


def _publish(frames_file: Path, rate_hz: float, duration_s: float, reliable: bool) -> int:
    """Publish the frames of ``frames_file`` round robin; print a JSON summary; return 0."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image

    from obstacle_detection.pipeline.params import KINECT_V2_SD
    from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info

    depth = np.load(frames_file)['depth_mm']
    rclpy.init()
    node = rclpy.create_node('latency_bench_camera')
    qos = (QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE) if reliable
           else qos_profile_sensor_data)
    depth_pub = node.create_publisher(Image, 'depth/image_raw', qos)
    info_pub = node.create_publisher(CameraInfo, 'depth/camera_info', qos)
    from builtin_interfaces.msg import Time

    images = [array_to_image(frame, stamp=Time(), frame_id='depth_optical') for frame in depth]
    info = intrinsics_to_camera_info(KINECT_V2_SD, depth.shape[2], depth.shape[1], stamp=Time(),
                                     frame_id='depth_optical')
    deadline = time.monotonic() + 30.0
    while depth_pub.get_subscription_count() == 0 or info_pub.get_subscription_count() == 0:
        if time.monotonic() > deadline:
            print(json.dumps({'error': 'the node did not subscribe within 30 s'}), flush=True)
            return 1
        time.sleep(0.05)
    time.sleep(0.5)
    period = 1.0 / rate_hz
    start = time.monotonic()
    sent, late = 0, 0
    while sent * period < duration_s:
        wait = start + sent * period - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        elif wait < -period:
            late += 1
        now_ns = time.time_ns()
        stamp = Time(sec=now_ns // 1_000_000_000, nanosec=now_ns % 1_000_000_000)
        info.header.stamp = stamp
        image = images[sent % len(images)]
        image.header.stamp = stamp
        info_pub.publish(info)
        depth_pub.publish(image)
        sent += 1
    print(json.dumps({'sent': sent, 'late': late, 'seconds': time.monotonic() - start}),
          flush=True)
    time.sleep(1.0)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def _proc_stats(pid: int) -> tuple[float, float]:
    """(RSS [MiB], user + system CPU time [s]) of a process, from /proc."""
    try:
        status = Path(f'/proc/{pid}/status').read_text()
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return float('nan'), float('nan')
    rss_kb = next(int(line.split()[1]) for line in status.splitlines()
                  if line.startswith('VmRSS:'))
    ticks = os.sysconf('SC_CLK_TCK')
    return rss_kb / 1024.0, (int(fields[11]) + int(fields[12])) / ticks


def _percentiles(values: Sequence[float]) -> dict[str, float]:
    if not values:
        return {'median': float('nan'), 'p90': float('nan'), 'p99': float('nan'),
                'max': float('nan')}
    arr = np.asarray(values, dtype=np.float64)
    return {'median': float(np.median(arr)), 'p90': float(np.percentile(arr, 90)),
            'p99': float(np.percentile(arr, 99)), 'max': float(arr.max())}


def _probe(executor: Any, node: Any) -> tuple[dict, list, list[str]]:
    """Subscribe to the node's costmap, processing time and status; return their records."""
    from nav_msgs.msg import OccupancyGrid
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64, String

    arrivals: dict[tuple[int, int], int] = {}
    times_ms: list[tuple[int, float]] = []
    status: list[str] = []
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(
        OccupancyGrid, 'obstacles/costmap',
        lambda m: arrivals.setdefault((m.header.stamp.sec, m.header.stamp.nanosec),
                                      time.time_ns()), reliable)
    node.create_subscription(Float64, f'{NODE}/processing_time_ms',
                             lambda m: times_ms.append((time.time_ns(), m.data)), reliable)
    node.create_subscription(String, f'{NODE}/status', lambda m: status.append(m.data),
                             node_process.status_qos())
    executor.add_node(node)
    return arrivals, times_ms, status


def _stream(args: argparse.Namespace, executor: Any, node: Any, publisher: Any,
            log: Path) -> list[tuple[float, float]]:
    """Spin while the publisher streams; return the node's memory [MiB] each second."""
    from obstacle_detection.cli.progress import Progress

    memory = [(0.0, _proc_stats(node.pid)[0])]
    began = last_sample = time.monotonic()
    total = int(args.duration)
    with Progress(total if not args.quiet else None, 'streaming [s]',
                  stream=sys.stderr if not args.quiet else open(os.devnull, 'w')) as bar:
        while publisher.poll() is None:
            executor.spin_once(timeout_sec=0.01)
            now = time.monotonic()
            if now - last_sample >= 1.0:
                last_sample = now
                memory.append((now - began, _proc_stats(node.pid)[0]))
                if bar.count < total:
                    bar.update()
            if node.poll() is not None:
                raise ToolError(log, f'the node exited with code {node.returncode}')
    drain = time.monotonic() + 2.0
    while time.monotonic() < drain:
        executor.spin_once(timeout_sec=0.01)
    return memory


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Run the three processes and return the figures."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE
    from obstacle_detection.sim.scenes import render_scene

    work = Path(tempfile.mkdtemp(prefix='latency_bench_'))
    log = work / 'node.log'
    frames = [render_scene(args.scene, seed=0, intrinsics=KINECT_V2_SD,
                           size=KINECT_V2_SD_SIZE, frame_index=k) for k in range(args.frames)]
    np.savez(work / 'frames.npz', depth_mm=np.stack([f.depth_mm for f in frames]))
    env = node_process.use_loopback(args.domain_id, work / 'ros_log')
    overrides = ['stats_period_s:=10.0', *node_process.mount_overrides(frames[0], args.reliable),
                 *args.set]
    node = node_process.start_node(node_process.node_command(args.params, overrides), env, log)
    context = rclpy.Context()
    rclpy.init(context=context)
    probe = rclpy.create_node('latency_bench_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    arrivals, times_ms, status = _probe(executor, probe)
    publisher = None
    try:
        deadline = time.monotonic() + args.start_timeout
        while not (status and status[-1] == 'ready: compiled numba kernels'
                   or status and 'numpy path (' in status[-1]):
            if node.poll() is not None or time.monotonic() > deadline:
                raise ToolError(log, 'the node did not become ready: '
                                + (status[-1] if status else 'no status'))
            executor.spin_once(timeout_sec=0.1)
        print(f'node {status[-1]}; publishing {args.scene} at {args.rate:g} Hz for '
              f'{args.duration:g} s ({"reliable" if args.reliable else "sensor-data"} QoS)',
              file=sys.stderr)
        publisher = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), '--role', 'publisher',
             '--frames-file', str(work / 'frames.npz'), '--rate', str(args.rate),
             '--duration', str(args.duration)] + (['--reliable'] if args.reliable else []),
            cwd=tool_support.PACKAGE_ROOT, env=env, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True)
        rss0, cpu0 = _proc_stats(node.pid)
        began = time.monotonic()
        memory = _stream(args, executor, node, publisher, log)
        rss1, cpu1 = _proc_stats(node.pid)
        elapsed = time.monotonic() - began
        report = json.loads(publisher.stdout.read().strip().splitlines()[0])
        if 'error' in report:
            raise ToolError(log, report['error'])
    finally:
        if publisher is not None and publisher.poll() is None:
            publisher.kill()
        executor.shutdown()
        probe.destroy_node()
        context.try_shutdown()
        node_process.stop_node(node)
    return _figures(args, report, arrivals, times_ms, memory, rss0, rss1,
                    (cpu1 - cpu0) / elapsed, work)


def _figures(args: argparse.Namespace, report: dict[str, Any],
             arrivals: dict[tuple[int, int], int], times_ms: list[tuple[int, float]],
             memory: list[tuple[float, float]], rss0: float, rss1: float, cpu_share: float,
             work: Path) -> dict[str, Any]:
    """Turn the raw arrivals into the benchmark's figures (warm-up frames left out)."""
    stamps = sorted(arrivals)
    first_ns = (stamps[0][0] * 1_000_000_000 + stamps[0][1]) if stamps else 0
    cut = first_ns + int(args.warmup * 1e9)
    latencies = [(arrivals[s] - (s[0] * 1_000_000_000 + s[1])) / 1e6 for s in stamps
                 if s[0] * 1_000_000_000 + s[1] >= cut]
    processing = [ms for t, ms in times_ms if t >= cut]
    sent = int(report['sent'])
    counted_sent = max(sent - int(round(args.warmup * args.rate)), 0)
    received = len(latencies)
    mem_after_warmup = [rss for t, rss in memory if t >= args.warmup] or [rss0]
    return {
        'scene': args.scene, 'rate_hz': args.rate, 'duration_s': args.duration,
        'params': str(args.params), 'overrides': list(args.set),
        'qos': 'reliable' if args.reliable else 'sensor_data',
        'frames_sent': counted_sent, 'costmaps_received': received,
        'frames_without_output': max(counted_sent - received, 0),
        'publisher_late': int(report.get('late', 0)),
        'latency_ms': _percentiles(latencies), 'processing_ms': _percentiles(processing),
        'node_cpu_share': cpu_share, 'node_rss_mib': {
            'start': rss0, 'after_warmup': mem_after_warmup[0], 'end': rss1,
            'growth_after_warmup': rss1 - mem_after_warmup[0]},
        'log': str(work / 'node.log'),
    }


def format_table(fig: dict[str, Any]) -> str:
    """Return the figures as a Markdown table."""
    lat, proc = fig['latency_ms'], fig['processing_ms']
    mem = fig['node_rss_mib']
    rows = [
        ('frames sent / costmaps received', f'{fig["frames_sent"]} / '
                                            f'{fig["costmaps_received"]}'),
        ('frames without a costmap', str(fig['frames_without_output'])),
        ('latency stamp -> costmap [ms] median / p90 / p99 / max',
         f'{lat["median"]:.1f} / {lat["p90"]:.1f} / {lat["p99"]:.1f} / {lat["max"]:.1f}'),
        ('node processing [ms] median / p90 / p99 / max',
         f'{proc["median"]:.1f} / {proc["p90"]:.1f} / {proc["p99"]:.1f} / {proc["max"]:.1f}'),
        ('node CPU [share of one core]', f'{fig["node_cpu_share"]:.2f}'),
        ('node memory [MiB] after warm-up -> end (growth)',
         f'{mem["after_warmup"]:.0f} -> {mem["end"]:.0f} ({mem["growth_after_warmup"]:+.1f})'),
        ('publisher frames late by a period or more', str(fig['publisher_late'])),
    ]
    head = (f'{fig["scene"]} at {fig["rate_hz"]:g} Hz for {fig["duration_s"]:g} s, '
            f'{fig["qos"]} QoS, {Path(fig["params"]).name} {" ".join(fig["overrides"])}')
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
    parser.add_argument('--params', type=Path, default=DEFAULT_PARAMS,
                        help='node params file (default params/corridor.yaml)')
    parser.add_argument('--set', action='append', default=[], metavar='NAME:=VALUE',
                        help='node parameter override, e.g. median_kernel:=5 (repeatable)')
    parser.add_argument('--scene', default='person_walking',
                        help='scene of the generator (default %(default)s)')
    parser.add_argument('--frames', type=int, default=30,
                        help='distinct frames, sent round robin (default %(default)s)')
    parser.add_argument('--reliable', action='store_true',
                        help='reliable QoS instead of the camera sensor-data (best effort)')
    parser.add_argument('--warmup', type=float, default=5.0,
                        help='seconds at the start not counted (default %(default)s)')
    parser.add_argument('--start-timeout', type=float, default=300.0,
                        help='seconds to wait for the node to be ready (default %(default)s)')
    tool_support.add_domain_id_option(
        parser, 'ROS_DOMAIN_ID, 0-232 (default: 100-200 from the process id)')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')
    parser.add_argument('--role', choices=('bench', 'publisher'), default='bench',
                        help=argparse.SUPPRESS)
    parser.add_argument('--frames-file', type=Path, help=argparse.SUPPRESS)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; return the exit code (0 done, 1 could not run, 2 bad usage)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.role == 'publisher':
        return _publish(args.frames_file, args.rate, args.duration, args.reliable)
    if not args.duration > 0 or not 0 < args.rate <= 1000 or args.frames < 1:
        parser.error('--duration, --rate (<= 1000) and --frames must be positive')
    if not 0 <= args.warmup < args.duration:
        parser.error('--warmup must be in [0, --duration)')
    try:
        if not args.params.is_file():
            raise ToolError(args.params, 'params file not found')
        figures = run(args)
    except ToolError as error:
        return tool_support.report_error('latency_bench', error)
    print(format_table(figures))
    print('JSON ' + json.dumps(figures))
    return 0


if __name__ == '__main__':
    sys.exit(main())
