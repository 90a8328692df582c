#!/usr/bin/env python3
"""Benchmark bag_process over many bags: one process against a local Dask cluster of 1..N workers.

Writes ``--bags`` bags of ``--frames`` depth frames, processes them in this process and on local
clusters of 1..``--max-workers`` workers, prints frames/s and the speed-up, checks the outputs
are identical, and measures what one task costs beyond its work (docs/fleet.md explains it)::

    python tools/benchmark_fleet.py --bags 4 --frames 50
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from obstacle_detection.cli import support as tool_support
from obstacle_detection.fleet import bags as fleet_bags
from obstacle_detection.fleet.cluster import (DASK_AVAILABLE, INSTALL_HINT, Fleet, open_fleet,
                                              run_tasks)
from obstacle_detection.ros.parameters import ALL_PARAMS

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333
#: Scenes whose frames fill the bags (seen from the node's default mount or near it).
SCENES = ('corridor', 'people', 'office', 'ramps')
DISTINCT_FRAMES = 12
EMPTY_TASKS = 200


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(prog='benchmark_fleet',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--bags', type=tool_support.int_in(1), default=8,
                        help='bags [default: 8]')
    parser.add_argument('--frames', type=tool_support.int_in(1), default=300,
                        help='depth frames per bag [default: 300]')
    parser.add_argument('--max-workers', type=tool_support.int_in(1), default=2,
                        help='largest local cluster measured [default: 2]')
    parser.add_argument('--repeat', type=tool_support.int_in(1), default=1,
                        help='runs of each, in turn; the best is shown [default: 1]')
    parser.add_argument('--work-dir', type=Path,
                        help='where the bags and outputs go (kept) [default: a temporary '
                             'folder, removed]')
    return parser


def _nothing() -> None:
    """Do nothing: an empty task."""


def _warm_up() -> None:
    """Import the bag processing and load the compiled kernels (what a first task pays)."""
    from obstacle_detection.cli import bag_processor  # noqa: F401 - the import is the work
    from obstacle_detection.fleet.cluster import limit_threads
    from obstacle_detection.pipeline import Detector

    limit_threads()
    Detector().warm_up()


def write_bags(folder: Path, count: int, frames: int) -> list[Path]:
    """Write ``count`` bags of ``frames`` frames; bag i starts at distinct frame i."""
    import cv2

    from obstacle_detection.cli.bag_writer import BagOptions, write_frames
    from obstacle_detection.evaluation.datasets import Frame, FrameSource
    from obstacle_detection.pipeline.params import KINECT_V2_SD
    from obstacle_detection.sim.scenes import render_scene

    pngs = []
    (folder / 'png').mkdir(parents=True)
    for k in range(DISTINCT_FRAMES):
        depth = render_scene(SCENES[k % len(SCENES)], seed=k).depth_mm
        pngs.append(folder / 'png' / f'{k:03d}.png')
        cv2.imwrite(str(pngs[-1]), depth)
    bags = []
    for i in range(count):
        source = FrameSource(
            [Frame(T0_NS + n * PERIOD_NS, pngs[(i + n) % len(pngs)]) for n in range(frames)],
            KINECT_V2_SD, 'the Kinect v2 SD defaults')
        bags.append(folder / 'bags' / f'bag{i}')
        write_frames(source, bags[-1], BagOptions(with_color=False, progress=False))
    return bags


def outputs_equal(first: Path, second: Path) -> bool:
    """Tell whether two processed bags hold equal output messages (compared decoded)."""
    from nav_msgs.msg import OccupancyGrid
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    from sensor_msgs.msg import PointCloud2

    types = {'/obstacles/points': PointCloud2, '/obstacles/costmap': OccupancyGrid}

    def read(path: Path) -> dict[str, list[tuple[int, object]]]:
        out: dict[str, list[tuple[int, object]]] = {topic: [] for topic in types}
        with Reader(path) as reader:
            wanted = [c for c in reader.connections if c.topic in types]
            for conn, stamp, raw in reader.messages(connections=wanted):
                out[conn.topic].append((stamp, deserialize_message(bytes(raw),
                                                                   types[conn.topic])))
        return out
    return read(first) == read(second)


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f'load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} CPUs'


def _measure(args: argparse.Namespace, work: Path, bags: list[Path], tiny: list[Path],
             jobs: Any) -> tuple[dict, bool, float, float]:
    """Process the bags on every fleet size ``--repeat`` times.

    Returns (best (wall s, start-up s, outcomes, CPU s) per worker count, whether a run failed
    or differed, an empty task's and a one-frame bag's worker time [ms]).
    """
    frames = args.bags * args.frames
    best: dict[int, tuple[float, float, list[fleet_bags.BagOutcome], float]] = {}
    failed = False
    for repeat in range(args.repeat):   # in turn, so that a change of load hits all
        for name, workers in _runs(args.max_workers):
            out = work / f'out_{workers}'
            shutil.rmtree(out, ignore_errors=True)
            began = time.perf_counter()
            with open_fleet(workers=workers, tasks=args.bags) as fleet:
                if fleet.distributed:
                    fleet.client.run(_warm_up)
                else:
                    _warm_up()
                startup = time.perf_counter() - began
                cpu = _cpu_s(fleet)
                began = time.perf_counter()
                outcomes = fleet_bags.process_bags(jobs(bags, out.name), fleet, progress=False)
                wall = time.perf_counter() - began
                cpu = _cpu_s(fleet) - cpu
                if workers == args.max_workers and repeat == 0:
                    empty_ms, tiny_ms = _task_overhead(fleet, jobs(tiny, 'out_tiny'))
            failed |= any(o.error for o in outcomes)
            if workers and not all(outputs_equal(work / 'out_0' / b.name, out / b.name)
                                   for b in bags):
                print(f'{name}: OUTPUTS DIFFER from one process', file=sys.stderr)
                failed = True
            if workers not in best or wall < best[workers][0]:
                best[workers] = (wall, startup, outcomes, cpu)
            print(f'  run {repeat + 1} {name}: {frames / wall:.1f} frames/s', flush=True)
    return best, failed, empty_ms, tiny_ms


def _runs(max_workers: int) -> list[tuple[str, int]]:
    """Return (name, workers) of every run: one process (0), then 1..max_workers workers."""
    return [('one process', 0)] + [(f'{n} worker{"s" if n > 1 else ""}', n)
                                   for n in range(1, max_workers + 1)]


def _print_results(args: argparse.Namespace, best: dict, failed: bool, empty_ms: float,
                   tiny_ms: float) -> None:
    """Print the best run of each fleet size, the idle-core speed-up and the task costs."""
    frames = args.bags * args.frames
    one = frames / best[0][0]
    of = f', best of {args.repeat}' if args.repeat > 1 else ''
    for name, workers in _runs(args.max_workers):
        wall, startup, outcomes, cpu = best[workers]
        ms = sum(o.pipeline_ms for o in outcomes) / max(1, sum(o.processed for o in outcomes))
        print(f'{name:>12}: {frames / wall:6.1f} frames/s, x{frames / wall / one:.2f} one '
              f'process ({wall:.1f} s{of}'
              f'; pipeline {ms:.1f} ms/frame; CPU {cpu * 1000 / frames:.1f} ms/frame; '
              f'start and warm-up {startup:.1f} s'
              f'{"; outputs identical to one process" if workers and not failed else ""})')
    frame_ms = best[args.max_workers][0] * 1000 * args.max_workers / frames
    # CPU time does not depend on what else runs (much): the speed-up on idle cores
    most = args.max_workers
    print(f'on {most} idle cores: x{most * best[0][3] / best[most][3]:.2f} one process at '
          f'most (CPU per frame of one process / of {most} workers, times {most}; the '
          'wall-clock figures above are what this machine gave now)')
    fixed_ms = max(0.0, tiny_ms - frame_ms)
    print(f'per task ({args.max_workers} workers, worker time): an empty task '
          f'{empty_ms:.1f} ms (scheduling + serialisation, {EMPTY_TASKS} tasks); a '
          f'one-frame bag {tiny_ms:.0f} ms against {frame_ms:.1f} ms a frame in the long '
          f'bags, so {fixed_ms:.0f} ms a bag beyond its frames: bags (or chunks) of '
          f'{max(1, round(10 * fixed_ms / frame_ms))} frames or more keep that under 10 %')


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; return the exit code (0 done, 1 outputs differ or a bag failed)."""
    args = build_parser().parse_args(argv)
    if not DASK_AVAILABLE:
        print(f'benchmark_fleet.py: error: needs dask.distributed: {INSTALL_HINT}',
              file=sys.stderr)
        return tool_support.EXIT_BAD_INPUT
    work = args.work_dir or Path(tempfile.mkdtemp(prefix='benchmark_fleet_'))
    if args.work_dir is not None and args.work_dir.exists():
        print(f'error: {args.work_dir}: exists; choose a new folder', file=sys.stderr)
        return tool_support.EXIT_BAD_INPUT
    values = {spec.name: spec.default for spec in ALL_PARAMS}
    values['compute_threads'] = 1

    def jobs(bags: list[Path], out: str) -> list[fleet_bags.BagJob]:
        return [fleet_bags.BagJob(bag, work / out / bag.name, values, 'defaults',
                                  "the node's defaults") for bag in bags]

    try:
        print(f'before: {_load()}')
        started = time.perf_counter()
        bags = write_bags(work, args.bags, args.frames)
        tiny = write_bags(work / 'tiny', args.bags, 1)
        print(f'wrote {args.bags} bags of {args.frames} frames (512x424) in '
              f'{time.perf_counter() - started:.1f} s')
        best, failed, empty_ms, tiny_ms = _measure(args, work, bags, tiny, jobs)
        _print_results(args, best, failed, empty_ms, tiny_ms)
        print(f'after: {_load()}')
    finally:
        if args.work_dir is None:
            shutil.rmtree(work, ignore_errors=True)
    return tool_support.EXIT_BAD_INPUT if failed else tool_support.EXIT_OK


def _cpu_s(fleet: Fleet) -> float:
    """CPU seconds used so far by this process (client, scheduler) and the workers."""
    used = time.process_time()
    if fleet.distributed:
        used += sum(fleet.client.run(time.process_time).values())
    return used


def _task_overhead(fleet: Fleet, tiny: list[Any]) -> tuple[float, float]:
    """Worker time [ms] of an empty task and of a one-frame bag's task on ``fleet``."""
    began = time.perf_counter()
    run_tasks(fleet, _nothing, [()] * EMPTY_TASKS, label='empty', progress=False)
    empty_ms = (time.perf_counter() - began) * 1000 * fleet.workers / EMPTY_TASKS
    began = time.perf_counter()
    fleet_bags.process_bags(tiny, fleet, progress=False)
    tiny_ms = (time.perf_counter() - began) * 1000 * fleet.workers / len(tiny)
    return empty_ms, tiny_ms


if __name__ == '__main__':
    sys.exit(main())
