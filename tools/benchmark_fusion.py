#!/usr/bin/env python3
"""Time the fused costmap: one FusedGrid.update (and to_costmap) per frame, on one thread.

The detector's costmaps of every ``--step``-th frame of 'drive_past_boxes' are fused at their
odometry poses ``--passes`` times, pinned to one CPU as tools/benchmark.py is. Prints median and
p90 milliseconds and one JSON line.
"""

from __future__ import annotations

import os

for _var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ[_var] = '1'

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from typing import Sequence  # noqa: E402

import numpy as np  # noqa: E402

from obstacle_detection.evaluation import runner as evaluation  # noqa: E402
from obstacle_detection.cli import support as tool_support  # noqa: E402
from obstacle_detection.pipeline.fusion import FusedGrid, FusionParams  # noqa: E402
from obstacle_detection.sim.sequences import SceneSequence  # noqa: E402

PROG = 'benchmark_fusion'


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n\n')[0])
    parser.add_argument('--passes', type=int, default=20,
                        help='times the recorded frames are fused [default: 20]')
    parser.add_argument('--step', type=int, default=5,
                        help='use every STEP-th frame of the sequence [default: 5]')
    parser.add_argument('--size-m', type=float, default=4.0,
                        help='fused grid side [m] [default: 4]')
    parser.add_argument('--resolution-m', type=float, default=0.05,
                        help='fused grid cell [m] [default: 0.05]')
    return parser


def _ms(values: list[float]) -> dict[str, float]:
    array = np.asarray(values)
    return {'median': round(float(np.median(array)), 4),
            'p90': round(float(np.percentile(array, 90)), 4)}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    try:
        if args.passes < 1 or args.step < 1:
            raise tool_support.ToolError(
                f'--passes={args.passes} and --step={args.step} must be >= 1', usage=True)
        try:
            fusion = FusionParams(size_m=args.size_m, resolution_m=args.resolution_m)
        except ValueError as exc:
            raise tool_support.ToolError(str(exc), usage=True) from None
        params = evaluation.load_params_file(tool_support.package_file('params/corridor.yaml'))
    except (ValueError, OSError) as exc:
        return tool_support.report_error(PROG, exc)
    pinning = tool_support.pin_one_cpu()
    from obstacle_detection.evaluation.video import observe_sequence

    sequence = SceneSequence('drive_past_boxes')
    print(f'{PROG}: running the detector on {len(sequence)} frames...', file=sys.stderr,
          flush=True)
    observations = list(observe_sequence(sequence, params))[::args.step]
    updates, outputs, totals = [], [], []
    for _ in range(args.passes):
        grid = FusedGrid(fusion)
        for obs in observations:
            start = time.perf_counter()
            grid.update(obs.costmap, obs.pose_odom)
            middle = time.perf_counter()
            grid.to_costmap()
            end = time.perf_counter()
            updates.append((middle - start) * 1e3)
            outputs.append((end - middle) * 1e3)
            totals.append((end - start) * 1e3)
    frame = observations[0].costmap
    print(f'{pinning}; Python {platform.python_version()}, numpy {np.__version__}')
    print(f'per-frame costmap {frame.width} x {frame.height} cells at '
          f'{frame.resolution_m:g} m; fused grid {fusion.cells} x {fusion.cells} at '
          f'{fusion.resolution_m:g} m; {len(totals)} frames')
    print('| step [ms] | median | p90 |')
    print('| --- | --- | --- |')
    for name, values in (('update (scroll, sample, splat, log-odds)', updates),
                         ('to_costmap (states for the OccupancyGrid)', outputs),
                         ('total', totals)):
        stats = _ms(values)
        print(f"| {name} | {stats['median']:.3f} | {stats['p90']:.3f} |")
    print(json.dumps({'frames': len(totals), 'fused_cells': fusion.cells,
                      'update_ms': _ms(updates), 'to_costmap_ms': _ms(outputs),
                      'total_ms': _ms(totals), 'pinning': pinning}, sort_keys=True))
    return tool_support.EXIT_OK


if __name__ == '__main__':
    sys.exit(main())
