#!/usr/bin/env python3
"""Robot-level suite with a one-cell tolerance, for one or more forward ranges (issue 22).

Prints per scenario and overall: cell F1, cell F1 and false alarms with a one-cell tolerance
(``metrics.tolerant_cells``), objects found and passable surfaces left free; ``--range 2,3,4``
repeats it with ``max_range_m`` and ``costmap_length_m`` at each value [m].
``--causes`` adds the false-alarm cells of each scenario by what marked them (docs/accuracy.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from collections import Counter
from typing import Sequence

import numpy as np

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.evaluation_args import parse_assignment, report_error
from obstacle_detection.evaluation import metrics, runner as evaluation
from obstacle_detection.labels import CELL_FREE, CELL_OCCUPIED, GT_NO_RETURN, GT_OBSTACLE
from obstacle_detection.labels import GT_TRAVERSABLE
from obstacle_detection.pipeline import traversal
from obstacle_detection.pipeline.normals import slope_obstacles
from obstacle_detection.pipeline.params import DetectorParams, corridor

DEFAULT_PARAMS = tool_support.package_file('params/corridor.yaml')


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog='robot_study', description=__doc__.split('\n\n')[0])
    parser.add_argument('--params-file', type=Path, default=DEFAULT_PARAMS, metavar='YAML',
                        help='node parameter file [default: params/corridor.yaml]')
    parser.add_argument('--set', action='append', type=parse_assignment, default=[],
                        metavar='KEY=VALUE', help='override one parameter; repeatable')
    parser.add_argument('--range', default='', metavar='M[,M...]',
                        help='forward ranges [m]: max_range_m and costmap_length_m each')
    parser.add_argument('--scene', action='append', metavar='NAME',
                        help='only this scenario (repeatable) [default: all]')
    parser.add_argument('--causes', action='store_true',
                        help='also count the false-alarm cells of each scenario by cause')
    return parser


def false_alarm_causes(frame: evaluation.LabelledFrame, result, params: DetectorParams,
                       truth: np.ndarray) -> Counter:
    """Count the false-alarm cells of one frame by cause (the module docstring's keys)."""
    steep = slope_obstacles(result.voxel_normals, params.cos_max_slope)
    trav = traversal.traversable_ground(result.voxel_points, steep, params)
    height = result.voxel_height_m
    kind = np.where(trav.ledge & ~trav.is_obstacle, 'ledge',
                    np.where(height < -params.max_step_down_m, 'low', 'high'))
    pixel_voxel, labels = result.pixel_voxel.reshape(-1), frame.truth_labels.reshape(-1)
    tags = np.full(kind.shape, '', object)
    for tag, label in (('O', GT_OBSTACLE), ('F', GT_TRAVERSABLE), ('X', GT_NO_RETURN)):
        has = np.zeros(kind.shape, bool)
        has[pixel_voxel[(pixel_voxel >= 0) & (labels == label)]] = True
        tags[has] += tag
    alarm = (result.costmap.data == CELL_OCCUPIED) & (truth == CELL_FREE)
    near = metrics.grow_cells(truth == CELL_OCCUPIED, 1)
    causes: dict[tuple[int, int], set] = {}
    marked = result.voxel_is_obstacle
    sources = [(result.voxel_points[marked], [f'{k}/{t}' for k, t in zip(kind[marked],
                                                                         tags[marked])]),
               (result.drop_points, ['drop'] * result.drop_points.shape[0])]
    for points, names in sources:
        row, col, inside = result.costmap.cell_of(points)
        for r, c, ok, name in zip(row, col, inside, names):
            if ok and alarm[r, c]:
                causes.setdefault((r, c), set()).add(name)
    return Counter('+'.join(sorted(names)) + ('' if near[cell] else ' far')
                   for cell, names in causes.items())


def study(params: DetectorParams, scenes: Sequence[str] | None, causes: bool = False) -> str:
    """Run the robot suite with ``params``; return the table (one row per scenario)."""
    scenarios = evaluation.select_scenarios(
        evaluation.load_scenarios(evaluation.SUITES['robot']), scenes)
    tolerant: dict[str, metrics.TolerantCells] = {}
    alarms: dict[str, Counter] = {}

    def on_frame(frame: evaluation.LabelledFrame, result, score) -> None:
        p = frame.params(params)
        truth = evaluation.truth_costmap(frame, p, evaluation.truth_roi(frame, p))
        counts = metrics.tolerant_cells(result.costmap.data, truth, cells=1)
        tolerant[frame.scenario] = tolerant.get(frame.scenario, metrics.TolerantCells()) + counts
        if causes:
            alarms.setdefault(frame.scenario, Counter()).update(
                false_alarm_causes(frame, result, p, truth))

    frames = (frame for s in scenarios for frame in evaluation.scenario_frames(s))
    report = evaluation.evaluate_frames(frames, params, on_frame=on_frame)
    total = sum(tolerant.values(), metrics.TolerantCells())
    head = (f'{"scenario":<24} {"frames":>6} {"cell F1":>7} {"F1 1-cell":>9} {"FA %":>6} '
            f'{"FA>1 cell %":>11} {"objects":>8} {"passable free":>13}')
    lines = [head, '-' * len(head)]
    for name, summary in [*report.scenes.items(), ('overall', report.overall)]:
        tol = total if name == 'overall' else tolerant[name]
        found, counted, missed = summary.objects_found()
        lines.append(
            f'{name:<24} {summary.frames:>6} {metrics.format_score(summary.cell.f1):>7} '
            f'{metrics.format_score(tol.f1):>9} '
            f'{100 * summary.cell.false_alarm_rate:>6.2f} {100 * tol.far_alarm_rate:>11.2f} '
            f'{f"{found}/{counted}":>8} {metrics.format_score(summary.passable_free()):>13}'
            + (f'  missed: {", ".join(missed)}' if missed else ''))
    if causes:
        alarms['overall'] = sum(alarms.values(), Counter())
        lines.append('false-alarm cells by cause:')
        lines += [f'{name:<24} ' + ', '.join(f'{n} {k}' for k, n in counts.most_common())
                  for name, counts in alarms.items() if counts]
    return '\n'.join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    try:
        base = evaluation.load_params_file(args.params_file, corridor())
        if args.set:
            base = evaluation.apply_overrides(base, dict(args.set))
        ranges = [float(r) for r in args.range.split(',') if r.strip()] or [None]
        for metres in ranges:
            params = base if metres is None else base.replace(max_range_m=metres,
                                                              costmap_length_m=metres)
            print(f'max_range_m {params.max_range_m:g}, costmap_length_m '
                  f'{params.costmap_length_m:g} ({args.params_file}):')
            print(study(params, args.scene, args.causes), flush=True)
    except (ValueError, OSError) as exc:
        return report_error('robot_study', exc)
    return 0


if __name__ == '__main__':
    sys.exit(main())
