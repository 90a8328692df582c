#!/usr/bin/env python3
"""Measure one node frame's time and peak memory over a grid of parameter points (docs/budget.md).

Each point runs in a fresh process: the node's configuration is built from the ROS values
(``ros.config.build_config``, the budget check bypassed), the kernels are compiled or loaded
at the defaults (same median K), then three frames (``--frames``) of each scene go through
what the node does with a frame: the pipeline, the output messages (with the clearing cloud),
the fused costmap, and their serialisation (what a publish does). Time: the median over the
frames of the CPU time of the thread running them (wall time is in the JSON; on a shared
machine it is that plus waiting for a CPU); memory: the process's peak resident memory during
the frames above what it held before them (VmHWM reset through /proc/self/clear_refs). The
heavier of the scenes is kept. Prints one ``JSON`` line
per point; ``--fit`` finds the coefficients of ``pipeline.params.frame_budget`` from saved
output, ``--table`` prints docs/budget.md's table (measure beside this tree's estimate)::

    .venv/bin/python test/budget_bench.py > grid.txt       # the grid of docs/budget.md
    .venv/bin/python test/budget_bench.py --point costmap_resolution_m=0.01 >> grid.txt
    .venv/bin/python test/budget_bench.py --fit grid.txt
    .venv/bin/python test/budget_bench.py --table grid.txt

Not a test (pytest does not collect it). A few seconds a point, most of it start-up.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: Scenes every point is measured on: indoor (walls near) and outdoor (rows of trees far away).
SCENES = ('corridor', 'orchard')
FRAMES = 3

#: The grid of docs/budget.md: each term alone, then combinations (the issue's sets among them).
GRID: tuple[dict, ...] = (
    {},
    {'median_kernel': 17},
    {'median_kernel': 31},
    {'costmap_resolution_m': 0.01},
    {'costmap_length_m': 20.0, 'costmap_width_m': 20.0, 'costmap_resolution_m': 0.01},
    {'costmap_length_m': 30.0, 'costmap_width_m': 30.0, 'costmap_resolution_m': 0.01},
    {'costmap_length_m': 50.0, 'costmap_width_m': 50.0, 'costmap_resolution_m': 0.01},
    {'costmap_length_m': 50.0, 'costmap_width_m': 50.0, 'costmap_resolution_m': 0.005},
    {'fuse': True, 'fused_size_m': 20.0, 'fused_resolution_m': 0.02},
    {'fuse': True, 'fused_size_m': 40.0, 'fused_resolution_m': 0.02},
    {'normal_neighbours': 50, 'validation_neighbours': 50},
    {'normal_neighbours': 100, 'validation_neighbours': 100},
    {'normal_neighbours': 400, 'validation_neighbours': 400},
    {'voxel_x_m': 0.01, 'voxel_y_m': 0.01, 'voxel_z_m': 0.01},
    {'voxel_x_m': 0.005, 'voxel_y_m': 0.005, 'voxel_z_m': 0.005},
    {'voxel_x_m': 0.002, 'voxel_y_m': 0.002, 'voxel_z_m': 0.002},
    {'voxel_x_m': 0.01, 'voxel_y_m': 0.01, 'voxel_z_m': 0.01, 'max_range_m': 6.0},
    {'voxel_x_m': 0.1, 'voxel_y_m': 0.1, 'voxel_z_m': 0.1, 'max_range_m': 20.0,
     'lateral_limit_m': 10.0},
    {'max_range_m': 6.0, 'lateral_limit_m': 4.0},
    {'max_range_m': 20.0, 'lateral_limit_m': 10.0},
    {'voxel_x_m': 0.005, 'voxel_y_m': 0.005, 'voxel_z_m': 0.005,
     'normal_neighbours': 50, 'validation_neighbours': 50},
    {'voxel_x_m': 0.01, 'voxel_y_m': 0.01, 'voxel_z_m': 0.01, 'max_range_m': 6.0,
     'normal_neighbours': 30, 'validation_neighbours': 30},
    {'clearing_stride_px': 1},
    {'robot_level': False, 'refine_floor': False, 'median_kernel': 17},
    {'robot_level': False, 'voxel_x_m': 0.005, 'voxel_y_m': 0.005, 'voxel_z_m': 0.005},
    {'median_kernel': 1},
    {'median_kernel': 9},
    {'robot_level': False},
    {'voxel_x_m': 0.003, 'voxel_y_m': 0.003, 'voxel_z_m': 0.003},
    {'voxel_x_m': 0.05, 'voxel_y_m': 0.05, 'voxel_z_m': 0.05, 'max_range_m': 20.0,
     'lateral_limit_m': 10.0},
    {'voxel_x_m': 0.005, 'voxel_y_m': 0.005, 'voxel_z_m': 0.05},
    {'max_range_m': 4.0, 'normal_neighbours': 200, 'validation_neighbours': 200},
    {'costmap_length_m': 10.0, 'costmap_width_m': 10.0, 'costmap_resolution_m': 0.005},
    {'fuse': True, 'fused_size_m': 30.0, 'fused_resolution_m': 0.02,
     'costmap_length_m': 10.0, 'costmap_width_m': 10.0, 'costmap_resolution_m': 0.01},
    {'normal_neighbours': 200, 'validation_neighbours': 200, 'voxel_x_m': 0.005,
     'voxel_y_m': 0.005, 'voxel_z_m': 0.005},
    {'voxel_x_m': 0.003, 'voxel_y_m': 0.003, 'voxel_z_m': 0.003, 'max_range_m': 4.0},
)


def _child(point: dict, frames: int = FRAMES) -> dict:
    """Measure one point in this process (see the module docstring)."""
    import ctypes
    import gc
    import statistics
    import time

    from rclpy.serialization import serialize_message

    from obstacle_detection.pipeline.detector import Detector
    from obstacle_detection.pipeline.fusion import FusedGrid
    from obstacle_detection.pipeline import clearing
    from obstacle_detection.pipeline.params import DetectorParams, frame_budget
    from obstacle_detection.ros.config import build_config, node_budget
    from obstacle_detection.ros.conversions import (costmap_to_occupancy_grid,
                                                    result_to_messages)
    from obstacle_detection.ros.parameters import ALL_PARAMS
    from obstacle_detection.sim.scenes import render_scene

    values = {spec.name: spec.default for spec in ALL_PARAMS}
    values.update(point)
    config = build_config(values, check_budget=False)
    detector = config.detector
    Detector(DetectorParams(median_kernel=detector.params.median_kernel)).warm_up()
    rendered = [render_scene(name, seed=0) for name in SCENES]
    from builtin_interfaces.msg import Time
    stamp = Time(sec=1, nanosec=0)

    def status(key: str) -> int:
        for line in Path('/proc/self/status').read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1]) * 1024
        raise KeyError(key)

    out = {'point': point, 'scenes': {}}
    for name, frame in zip(SCENES, rendered):
        params = detector.params.replace(camera_height_m=frame.height_m,
                                         camera_pitch_rad=frame.pitch_rad,
                                         camera_roll_rad=frame.roll_rad)
        det = Detector(params)
        fused = FusedGrid(config.fusion) if config.fusion is not None else None
        gc.collect()
        ctypes.CDLL('libc.so.6').malloc_trim(0)
        base = status('VmRSS')
        Path('/proc/self/clear_refs').write_text('5')
        times, walls, voxels = [], [], 0
        for _ in range(frames):
            start, cpu = time.perf_counter(), time.thread_time()
            result = det.process(frame.depth_mm, frame.intrinsics)
            msgs = result_to_messages(
                result, stamp=stamp, cloud_frame_id='b', costmap_frame_id='b',
                image_frame_id='c', with_ground=config.publish_ground,
                clearing_points=clearing.clearing_cloud(
                    result, stride_px=config.clearing_stride_px,
                    range_m=config.clearing_range_m) if config.publish_clearing else None)
            if fused is not None:
                fused.update(result.costmap, (0.0, 0.0, 0.0), pose_stamp_s=1.0)
                msgs['fused'] = costmap_to_occupancy_grid(fused.to_costmap(), stamp=stamp,
                                                          frame_id='odom')
            for msg in msgs.values():
                serialize_message(msg)
            walls.append((time.perf_counter() - start) * 1e3)
            times.append((time.thread_time() - cpu) * 1e3)
            voxels = int(result.voxel_points.shape[0])
            del result, msgs
        out['scenes'][name] = {'ms': statistics.median(times), 'first_ms': times[0],
                               'wall_ms': statistics.median(walls),
                               'mib': (status('VmHWM') - base) / 2**20, 'voxels': voxels}
    budget = frame_budget(detector.params, **node_budget(values))
    out['ms'] = max(s['ms'] for s in out['scenes'].values())
    out['mib'] = max(s['mib'] for s in out['scenes'].values())
    out['estimate_ms'] = budget.ms
    out['estimate_mib'] = budget.mib
    out['terms'] = budget.terms
    return out


def measure(point: dict, frames: int = FRAMES) -> dict:
    """Measure one point in a fresh process (``frames`` frames a scene); return its row."""
    env = dict(os.environ, OMP_NUM_THREADS='1', OPENBLAS_NUM_THREADS='1')
    proc = subprocess.run([sys.executable, __file__, '--child', json.dumps(point),
                           '--frames', str(frames)],
                          capture_output=True, text=True, env=env, cwd=REPO, check=False)
    for line in proc.stdout.splitlines():
        if line.startswith('JSON '):
            return json.loads(line[5:])
    return {'point': point, 'error': (proc.stderr.strip().splitlines() or ['?'])[-1]}


def _value(text: str) -> object:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return {'true': True, 'false': False}.get(text.lower(), text)


def _rows(paths: list[str]) -> list[dict]:
    rows = []
    for path in paths:
        rows += [json.loads(line[5:]) for line in Path(path).read_text().splitlines()
                 if line.startswith('JSON ')]
    return [row for row in rows if 'error' not in row]


def _terms(rows: list[dict]) -> tuple[list[str], list[list[float]], list[object]]:
    """(term names, each row's terms, each row's budget) with this tree's estimate."""
    from obstacle_detection.pipeline.params import BUDGET_MS, frame_budget
    from obstacle_detection.ros.config import build_config, node_budget
    from obstacle_detection.ros.parameters import ALL_PARAMS

    names, table, budgets = list(BUDGET_MS), [], []
    for row in rows:
        values = {spec.name: spec.default for spec in ALL_PARAMS}
        values.update(row['point'])
        config = build_config(values, check_budget=False)
        budget = frame_budget(config.detector.params, **node_budget(values))
        table.append([budget.terms[name] for name in names])
        budgets.append(budget)
    return names, table, budgets


def fit(paths: list[str]) -> None:
    """Print the coefficients with the smallest largest ratio estimate / measure (LP bisection)."""
    import numpy as np
    from scipy.optimize import linprog

    rows = _rows(paths)
    names, table, _ = _terms(rows)
    terms = np.array(table, float)
    for key in ('ms', 'mib'):
        measured = np.array([row[key] for row in rows])
        low, high, best = 1.0, 8.0, None
        for _ in range(30):   # feasible: measured / r <= terms @ c <= r * measured, c >= 0
            r = 0.5 * (low + high)
            found = linprog(np.zeros(len(names)), A_ub=np.vstack([terms, -terms]),
                            b_ub=np.concatenate([r * measured, -measured / r]),
                            bounds=[(0, None)] * len(names), method='highs')
            if found.status == 0:
                high, best = r, found.x
            else:
                low = r
        print(f'{key}: within a factor of {high:.2f}:',
              {name: float(f'{c:.2g}') for name, c in zip(names, best) if c > 0})


def table(paths: list[str]) -> None:
    """Print the Markdown table of docs/budget.md: measure and this tree's estimate."""
    rows = _rows(paths)
    _, _, budgets = _terms(rows)
    print('| set (on the defaults) | ms | estimate | ratio | MiB | estimate | ratio | refused |')
    print('| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |')
    for row, budget in zip(rows, budgets):
        label = ', '.join(f'{k}={v}' for k, v in row['point'].items()) or 'defaults'
        print(f'| {label} | {row["ms"]:.1f} | {budget.ms:.1f} | {budget.ms / row["ms"]:.2f} | '
              f'{row["mib"]:.1f} | {budget.mib:.1f} | {budget.mib / row["mib"]:.2f} | '
              f'{"yes" if budget.problem() else ""} |')


def main(argv: list[str] | None = None) -> int:
    """Measure the points (or fit, or tabulate saved measures); print JSON lines."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--point', action='append', default=[], metavar='K=V[,K=V...]',
                        help='measure this point instead of the grid (repeatable)')
    parser.add_argument('--fit', nargs='+', metavar='OUTPUT',
                        help="fit the coefficients to the JSON lines of earlier runs' output")
    parser.add_argument('--table', nargs='+', metavar='OUTPUT',
                        help="print docs/budget.md's table from earlier runs' output")
    parser.add_argument('--frames', type=int, default=FRAMES,
                        help=f'frames a scene and point [default: {FRAMES}]')
    parser.add_argument('--child', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child is not None:
        print('JSON ' + json.dumps(_child(json.loads(args.child), args.frames)))
        return 0
    if args.fit or args.table:
        (fit if args.fit else table)(args.fit or args.table)
        return 0
    points = [dict((k, _value(v)) for k, v in (kv.split('=', 1) for kv in text.split(',')))
              for text in args.point] or list(GRID)
    for point in points:
        print('JSON ' + json.dumps(measure(point, args.frames)), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
