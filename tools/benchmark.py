#!/usr/bin/env python3
"""Benchmark the detection pipeline: per-stage and total milliseconds, frames per second.

Rendered scenes, cycled over for every frame size x median kernel K, one thread pinned to one
CPU unless ``--threads N``; ``--fusion`` times the fused costmap, ``--fleet N`` bag_process on
Dask. Prints a table and one line starting with ``JSON `` (docs/speed.md, docs/fleet.md)::

    python tools/benchmark.py --frames 300 --preset table_4_2   # the seed method exactly
"""

from __future__ import annotations

import os

for _var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ[_var] = '1'

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from obstacle_detection.cli import support as tool_support  # noqa: E402
from obstacle_detection.pipeline.jit import enabled as jit_enabled  # noqa: E402
from obstacle_detection.pipeline.params import KINECT_V2_SD, PRESETS, Intrinsics  # noqa: E402
from obstacle_detection.pipeline.detector import NEW_STAGES, STAGES, Detector  # noqa: E402
from obstacle_detection.sim.scenes import render_scene, scene_params  # noqa: E402

#: (label, (width, height), intrinsics). 960x540 is the Kinect v2 colour stream at half size.
SIZES = {
    '512x424': ((512, 424), KINECT_V2_SD),
    '960x540': ((960, 540), Intrinsics(fx=540.7, fy=540.7, cx=479.75, cy=269.75)),
}
DEFAULT_SCENES = ('corridor', 'people', 'ramps', 'farm_row')
#: Row of the per-frame sum of the stages that are not the seed's (robot level, floor fit).
NEW_TOTAL = 'new stages'


def _stats(per_row: dict[str, list[float]]) -> dict[str, dict[str, float]]:
    return {row: {'median_ms': float(np.median(v)), 'p90_ms': float(np.percentile(v, 90))}
            for row, v in per_row.items()}


def run_config(scenes: tuple[str, ...], size_label: str, kernel: int, frames: int,
               preset: str, distinct: int, rate_hz: float = 0.0, threads: int = 1) -> dict:
    """Time ``frames`` frames of one configuration; return the statistics.

    rate_hz > 0: a frame starts every 1 / rate_hz s (sleeping in between, never catching up
    on a late frame); 0: back to back.
    """
    (width, height), intr = SIZES[size_label]
    rendered = []
    for name in scenes:
        for seed in range(distinct):
            frame = render_scene(name, seed=seed, intrinsics=intr, size=(width, height))
            params = scene_params(frame, PRESETS[preset](median_kernel=kernel,
                                                         compute_threads=threads))
            rendered.append((frame, Detector(params)))
    rendered[0][1].warm_up()  # numba kernels compiled or loaded before timing
    rendered[0][1].process(rendered[0][0].depth_mm, rendered[0][0].intrinsics)
    per_stage = {stage: [] for stage in (*STAGES, NEW_TOTAL, 'total')}
    voxels, obstacles = [], []
    period_s = 1.0 / rate_hz if rate_hz > 0.0 else 0.0
    wall_start = next_start = time.perf_counter()
    for i in range(frames):
        if period_s:
            next_start = max(next_start + period_s, time.perf_counter())
            time.sleep(max(0.0, next_start - time.perf_counter()))
        frame, detector = rendered[i % len(rendered)]
        result = detector.process(frame.depth_mm, frame.intrinsics)
        for stage, ms in result.timings_ms.items():
            per_stage[stage].append(ms)
        per_stage[NEW_TOTAL].append(sum(result.timings_ms[s] for s in NEW_STAGES))
        voxels.append(result.voxel_points.shape[0])
        obstacles.append(result.obstacle_points.shape[0])
    wall = time.perf_counter() - wall_start
    return {
        'label': f'{size_label} K={kernel}', 'size': size_label, 'kernel': kernel,
        'preset': preset, 'frames': frames, 'scenes': list(scenes), 'stages': _stats(per_stage),
        'threads': threads, 'fps': frames / wall, 'rate_hz': rate_hz,
        'voxels_median': float(np.median(voxels)),
        'obstacle_points_median': float(np.median(obstacles)),
    }


def run_fusion(frames: int, preset: str) -> dict:
    """Time FusedGrid.update and to_costmap on the costmaps of 'drive_past_boxes' (every 5th)."""
    from obstacle_detection.evaluation.video import observe_sequence
    from obstacle_detection.pipeline.fusion import FusedGrid, FusionParams
    from obstacle_detection.sim.sequences import SceneSequence

    print('# running the detector on drive_past_boxes ...', file=sys.stderr, flush=True)
    observations = list(observe_sequence(SceneSequence('drive_past_boxes'),
                                         PRESETS[preset]()))[::5]
    fusion = FusionParams()
    times: dict[str, list[float]] = {'update': [], 'to_costmap': [], 'total': []}
    wall_start = time.perf_counter()
    for i in range(frames):
        if i % len(observations) == 0:
            grid = FusedGrid(fusion)   # each pass over the frames starts a new grid
        obs = observations[i % len(observations)]
        start = time.perf_counter()
        grid.update(obs.costmap, obs.pose_odom)
        middle = time.perf_counter()
        grid.to_costmap()
        end = time.perf_counter()
        times['update'].append((middle - start) * 1e3)
        times['to_costmap'].append((end - middle) * 1e3)
        times['total'].append((end - start) * 1e3)
    costmap = observations[0].costmap
    return {'label': f'fused {fusion.cells}x{fusion.cells}', 'preset': preset, 'frames': frames,
            'costmap_cells': [costmap.width, costmap.height], 'fused_cells': fusion.cells,
            'stages': _stats(times), 'fps': frames / (time.perf_counter() - wall_start)}


def _write_bags(folder: Path, scenes: tuple[str, ...], distinct: int, count: int,
                frames: int) -> list[Path]:
    """Write ``count`` bags of ``frames`` rendered 512x424 frames; bag i starts at frame i."""
    from obstacle_detection.cli.bag_writer import BagOptions, write_frames
    from obstacle_detection.evaluation.datasets import Frame, FrameSource

    pngs = [folder / f'{name}_{seed}.png' for name in scenes for seed in range(distinct)]
    for png in pngs:
        name, seed = png.stem.rsplit('_', 1)
        cv2.imwrite(str(png), render_scene(name, seed=int(seed)).depth_mm)
    bags = [folder / 'bags' / f'bag{i}' for i in range(count)]
    for i, bag in enumerate(bags):
        source = FrameSource([Frame(1_700_000_000_000_000_000 + n * 33_333_333,
                                    pngs[(i + n) % len(pngs)]) for n in range(frames)],
                             KINECT_V2_SD, 'the Kinect v2 SD defaults')
        write_frames(source, bag, BagOptions(with_color=False, progress=False))
    return bags


def _warm_up() -> None:
    """Import the bag processing and load the compiled kernels (what a first task pays)."""
    from obstacle_detection.fleet import bags  # noqa: F401 - the import is the work
    from obstacle_detection.fleet.cluster import limit_threads

    limit_threads()
    Detector().warm_up()


def _cpu_s(fleet: Any) -> float:
    """CPU seconds used so far by this process (client, scheduler) and the workers."""
    used = time.process_time()
    if fleet.distributed:
        used += sum(fleet.client.run(time.process_time).values())
    return used


def run_fleet(scenes: tuple[str, ...], distinct: int, bags: int, frames: int,
              max_workers: int) -> list[dict]:
    """Time bag_process's many-bag run in this process, then on 1..max_workers workers."""
    from obstacle_detection.fleet import bags as fleet_bags
    from obstacle_detection.fleet.cluster import open_fleet
    from obstacle_detection.ros.parameters import ALL_PARAMS

    values = {**{spec.name: spec.default for spec in ALL_PARAMS}, 'compute_threads': 1}
    results = []
    with tempfile.TemporaryDirectory(prefix='benchmark_fleet_') as folder:
        inputs = _write_bags(Path(folder), scenes, distinct, bags, frames)
        for workers in range(max_workers + 1):
            label = f'{workers} worker{"s" if workers > 1 else ""}' if workers else 'one process'
            print(f'# bag_process, {label} ...', file=sys.stderr, flush=True)
            jobs = [fleet_bags.BagJob(bag, Path(folder) / f'out{workers}' / bag.name, values,
                                      'defaults', "the node's defaults") for bag in inputs]
            with open_fleet(workers=workers, tasks=bags) as fleet:
                if fleet.distributed:
                    fleet.client.run(_warm_up)
                else:
                    _warm_up()
                cpu, began = _cpu_s(fleet), time.perf_counter()
                outcomes = fleet_bags.process_bags(jobs, fleet, progress=False)
                wall, cpu = time.perf_counter() - began, _cpu_s(fleet) - cpu
            failed = [o.error for o in outcomes if o.error is not None]
            if failed:
                raise RuntimeError(failed[0])
            total = fleet_bags.merged(Path(), Path(), outcomes)
            results.append({'label': label,
                            'workers': workers, 'frames': total.processed, 'wall_s': wall,
                            'fps': total.processed / wall, 'pipeline_ms': total.ms_per_frame,
                            'cpu_ms': cpu * 1e3 / total.processed})
    return results


def format_fleet(results: list[dict]) -> str:
    """Return one line per run: frames/s, the speed-up, pipeline and CPU time per frame."""
    one = results[0]['fps']
    return '\n'.join(f"{r['label']:>12}: {r['fps']:6.1f} frames/s, x{r['fps'] / one:.2f} one "
                     f"process ({r['wall_s']:.1f} s); pipeline {r['pipeline_ms']:.1f} ms/frame; "
                     f"CPU {r['cpu_ms']:.1f} ms/frame (every process)" for r in results)


def format_table(results: list[dict]) -> str:
    """Return a fixed-width table: one row per stage, one column pair per configuration."""
    lines = ['stage          ' + ''.join(f'{r["label"]:>22}' for r in results),
             '               ' + f'{"median ms":>12}{"p90 ms":>10}' * len(results)]
    for stage in results[0]['stages']:
        lines.append(f'{stage:<15}' + ''.join(f"{r['stages'][stage]['median_ms']:>12.2f}"
                                              f"{r['stages'][stage]['p90_ms']:>10.2f}"
                                              for r in results))
    lines.append('fps (wall)     ' + ''.join(f"{r['fps']:>22.1f}" for r in results))
    if 'voxels_median' in results[0]:
        lines.append('voxels (median)' + ''.join(f"{r['voxels_median']:>22.0f}"
                                                 for r in results))
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print the table and one JSON line."""
    parser = argparse.ArgumentParser(prog='benchmark', description=__doc__.split('\n\n')[0])
    parser.add_argument('--frames', type=tool_support.int_in(1), default=100,
                        help='frames per configuration')
    parser.add_argument('--preset', choices=sorted(PRESETS), default='corridor',
                        help='parameters: corridor (the default, robot level) or a seed '
                             'table [default: corridor]')
    parser.add_argument('--scenes', default=','.join(DEFAULT_SCENES),
                        help='comma-separated scene names')
    parser.add_argument('--sizes', default=','.join(SIZES), help='comma-separated sizes')
    parser.add_argument('--kernels', default='5,17', help='comma-separated median kernels K')
    parser.add_argument('--distinct', type=tool_support.int_in(1), default=3,
                        help='distinct seeds rendered per scene (frames cycle over them)')
    parser.add_argument('--rate', type=float, default=0.0, metavar='HZ',
                        help='start a frame every 1/HZ s, sleeping in between, as a camera '
                             'paces the node (0 = back to back, the default)')
    parser.add_argument('--threads', type=tool_support.int_in(1, 8), default=1,
                        help='compute_threads of the detector; above 1 the process is not '
                             'pinned to one CPU [default: 1]')
    parser.add_argument('--fusion', action='store_true',
                        help="time the fused costmap's update and to_costmap per frame "
                             '(pinned; the size, kernel, rate and thread options are ignored)')
    parser.add_argument('--fleet', type=tool_support.int_in(0), default=0, metavar='N',
                        help='time bag_process over --bags bags of --frames frames in one '
                             'process and on local Dask clusters of 1..N workers (not pinned)')
    parser.add_argument('--bags', type=tool_support.int_in(1), default=8,
                        help='bags of --fleet [default: 8]')
    args = parser.parse_args(argv)
    if not (0.0 <= args.rate <= 1000.0):
        parser.error('--rate must be in [0, 1000] Hz (0 = back to back)')
    sizes = args.sizes.split(',')
    unknown = [s for s in sizes if s not in SIZES]
    if unknown:
        parser.error(f'unknown size(s) {unknown}; choose from {list(SIZES)}')
    scenes = tuple(args.scenes.split(','))
    kernels = [int(k) for k in args.kernels.split(',')]
    if args.fleet:   # not pinned: the workers would inherit this process's one CPU
        print(f'# load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs', flush=True)
        results = run_fleet(scenes, args.distinct, args.bags, args.frames, args.fleet)
        print(format_fleet(results))
        print('JSON ' + json.dumps({'results': results}))
        return 0
    if args.threads == 1 or args.fusion:
        pinned = tool_support.pin_one_cpu()
    else:
        cv2.setNumThreads(1)
        pinned = 'not pinned; BLAS/OpenMP/OpenCV threads = 1'
    path = (f'numba kernels (compute_threads {args.threads})' if jit_enabled() else
            'numpy/scipy path (numba missing or OBSTACLE_DETECTION_NO_JIT=1)')
    pinning = f'{pinned}; k-d tree workers = 1; {path}'

    print(f'# {pinning}', flush=True)
    if args.fusion:
        results = [run_fusion(args.frames, args.preset)]
        what = 'scene drive_past_boxes, fused costmap'
    else:
        results = []
        for size_label in sizes:
            for kernel in kernels:
                print(f'# {size_label} K={kernel}: {args.frames} frames ...', file=sys.stderr,
                      flush=True)
                results.append(run_config(scenes, size_label, kernel, args.frames, args.preset,
                                          args.distinct, args.rate, args.threads))
        pace = f'one frame every {1e3 / args.rate:.1f} ms' if args.rate else 'back to back'
        what = f'scenes {", ".join(scenes)}, {pace}'
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f'# preset {args.preset}, {what}, {args.frames} frames each; '
          f'{platform.processor() or platform.machine()}, Python {platform.python_version()}, '
          f'numpy {np.__version__}, OpenCV {cv2.__version__}')
    print(format_table(results))
    print(f'peak memory (max RSS): {peak_mib:.0f} MiB')
    print('JSON ' + json.dumps({'pinning': pinning, 'peak_rss_mib': round(peak_mib, 1),
                                'results': results}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
