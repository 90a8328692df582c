#!/usr/bin/env python3
"""Benchmark the detection pipeline: per-stage and total milliseconds, frames per second.

Rendered scenes (three seeds each), cycled over for every frame size x median kernel K, on one
thread pinned to one CPU. Prints a table and one line starting with ``JSON `` (docs/speed.md)::

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
import time  # noqa: E402

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


def run_config(scenes: tuple[str, ...], size_label: str, kernel: int, frames: int,
               preset: str, rate_hz: float = 0.0) -> dict:
    """Time ``frames`` frames of one configuration; return the statistics.

    rate_hz > 0: a frame starts every 1 / rate_hz s (sleeping in between, never catching up
    on a late frame); 0: back to back.
    """
    (width, height), intr = SIZES[size_label]
    rendered = []
    for name in scenes:
        for seed in range(3):   # frames cycle over three seeds per scene
            frame = render_scene(name, seed=seed, intrinsics=intr, size=(width, height))
            params = scene_params(frame, PRESETS[preset](median_kernel=kernel))
            rendered.append((frame, Detector(params)))
    rendered[0][1].warm_up()  # numba kernels compiled or loaded before timing
    rendered[0][1].process(rendered[0][0].depth_mm, rendered[0][0].intrinsics)
    per_stage = {stage: [] for stage in (*STAGES, NEW_TOTAL, 'total')}
    voxels = []
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
    wall = time.perf_counter() - wall_start
    stats = {row: {'median_ms': float(np.median(v)), 'p90_ms': float(np.percentile(v, 90))}
             for row, v in per_stage.items()}
    return {
        'label': f'{size_label} K={kernel}', 'size': size_label, 'kernel': kernel,
        'preset': preset, 'frames': frames, 'scenes': list(scenes), 'stages': stats,
        'fps': frames / wall, 'rate_hz': rate_hz,
        'voxels_median': float(np.median(voxels)),
    }


def format_table(results: list[dict]) -> str:
    """Return a fixed-width table: one row per stage, one column pair per configuration."""
    lines = ['stage          ' + ''.join(f'{r["label"]:>22}' for r in results),
             '               ' + f'{"median ms":>12}{"p90 ms":>10}' * len(results)]
    for stage in results[0]['stages']:
        lines.append(f'{stage:<15}' + ''.join(f"{r['stages'][stage]['median_ms']:>12.2f}"
                                              f"{r['stages'][stage]['p90_ms']:>10.2f}"
                                              for r in results))
    lines.append('fps (wall)     ' + ''.join(f"{r['fps']:>22.1f}" for r in results))
    lines.append('voxels (median)' + ''.join(f"{r['voxels_median']:>22.0f}" for r in results))
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
    parser.add_argument('--rate', type=float, default=0.0, metavar='HZ',
                        help='start a frame every 1/HZ s, sleeping in between, as a camera '
                             'paces the node (0 = back to back, the default)')
    args = parser.parse_args(argv)
    if not (0.0 <= args.rate <= 1000.0):
        parser.error('--rate must be in [0, 1000] Hz (0 = back to back)')
    sizes = args.sizes.split(',')
    unknown = [s for s in sizes if s not in SIZES]
    if unknown:
        parser.error(f'unknown size(s) {unknown}; choose from {list(SIZES)}')
    scenes = tuple(args.scenes.split(','))
    kernels = [int(k) for k in args.kernels.split(',')]
    pinning = f'{tool_support.pin_one_cpu()}; k-d tree workers = 1; ' + (
        'numba kernels' if jit_enabled() else
        'numpy/scipy path (numba missing or OBSTACLE_DETECTION_NO_JIT=1)')
    print(f'# {pinning}', flush=True)
    results = []
    for size_label in sizes:
        for kernel in kernels:
            print(f'# {size_label} K={kernel}: {args.frames} frames ...', file=sys.stderr,
                  flush=True)
            results.append(run_config(scenes, size_label, kernel, args.frames, args.preset,
                                      args.rate))
    pace = f'one frame every {1e3 / args.rate:.1f} ms' if args.rate else 'back to back'
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f'# preset {args.preset}, scenes {", ".join(scenes)}, {pace}, {args.frames} frames '
          f'each; {platform.processor() or platform.machine()}, '
          f'Python {platform.python_version()}, '
          f'numpy {np.__version__}, OpenCV {cv2.__version__}')
    print(format_table(results))
    print(f'peak memory (max RSS): {peak_mib:.0f} MiB')
    print('JSON ' + json.dumps({'pinning': pinning, 'peak_rss_mib': round(peak_mib, 1),
                                'results': results}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
