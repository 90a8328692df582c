#!/usr/bin/env python3
"""Parameter sweep: score a grid of settings on the scenario suite and draw it as a heatmap.

One or two axes; every other parameter stays at the preset. Axis names: any DetectorParams
field, a ``..._deg`` variant of a ``..._rad`` field, the seed's theta_deg, N, N1, K, TDBG, SMAR,
and voxel_m (all three voxel sizes)::

    python tools/sweep.py --x theta_deg=15,20,30,45 --y N=3,5,10,20
    python tools/sweep.py --x N1=0,4,8,12 --y K=1,5,9,17 --metric pixel_f1 --out n1_k.png

With Dask installed the grid runs on a local cluster (``--workers 0``: in this process).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.fleet import scoring
from obstacle_detection.fleet.cluster import add_fleet_arguments, fleet_options, open_fleet
from obstacle_detection.evaluation.sweep import (METRICS, SweepResult, format_grid, grid_sweep,
                                                 parse_axis)
from obstacle_detection.pipeline.params import DetectorParams
from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.evaluation_args import (SUITE_TEXT, add_common_arguments,
                                                   base_params, frame_sources)

#: Frames per scenario unless --max-frames says otherwise (a grid scores every frame per point).
DEFAULT_MAX_FRAMES = 1


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog='sweep', description=__doc__.split('\n\n')[0],
                                     epilog='what the scores count: docs/accuracy.md',
                                     formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument('--x', type=parse_axis, required=True, metavar='NAME=V1,V2,...',
                        help='first axis (columns), e.g. theta_deg=15,20,30,45')
    parser.add_argument('--y', type=parse_axis, metavar='NAME=V1,V2,...',
                        help='second axis (rows), e.g. N=3,5,10,20 [default: none]')
    parser.add_argument('--metric', choices=sorted(METRICS), default='cell_f1',
                        help='score to grid and maximise (false alarms: minimise) '
                             '[default: cell_f1]')
    # the seed suite: the sweeps tune the seed's parameters, as its figures 4.18 and 4.19 do
    add_common_arguments(parser, suite='seed', max_frames=DEFAULT_MAX_FRAMES)
    parser.add_argument('--out', type=Path, default=Path('out') / 'sweep.png',
                        help='heatmap PNG (one panel per scenario + overall) '
                             '[default: out/sweep.png]')
    parser.add_argument('--json', type=Path, metavar='FILE', help='also write the grids as JSON')
    add_fleet_arguments(parser)
    return parser


def _log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _print_result(args: argparse.Namespace, result: SweepResult, frame_count: int) -> None:
    """Print the grids and the best setting per scenario."""
    scenes = list(result.grids)
    frames = ('every frame' if args.max_frames is None else
              f'{args.max_frames} frame{"s" if args.max_frames != 1 else ""} per scenario '
              f'(--max-frames {args.max_frames}'
              + (', the default of sweep; evaluate scores every frame)'
                 if args.max_frames == DEFAULT_MAX_FRAMES else ')'))
    print(f'suite: {SUITE_TEXT[args.suite]}, {frames}; parameters: {args.preset}; '
          f'{frame_count} frames; '
          f'{"higher" if METRICS[args.metric][2] else "lower"} is better; * = best')
    print(format_grid(result, 'overall'))
    print()
    print('best setting per scenario:')
    width = max(len(s) for s in scenes)
    for scene in scenes:
        best = result.best(scene)
        if best is None:
            print(f'  {scene:<{width}}  (no valid score)')
            continue
        grid, metric, _ = result.ranking(scene)
        setting = ', '.join(f'{k}={v}' for k, v in result.setting(*best).items())
        note = ' (no obstacle in the truth)' if metric != args.metric else ''
        print(f'  {scene:<{width}}  {setting}: {metric} '
              f'{evaluation.format_score(grid[best])}{note}')


def _json(args: argparse.Namespace, result: SweepResult, frame_count: int) -> dict:
    """Return the grids (rows y, columns x) and best settings as the ``--json`` document."""
    return {'metric': args.metric, 'preset': args.preset, 'frames': frame_count,
            'x': {'name': args.x.name, 'values': list(args.x.values)},
            'y': {'name': args.y.name, 'values': list(args.y.values)} if args.y else None,
            'grids': {s: np.where(np.isnan(g), None, g).tolist()
                      for s, g in result.grids.items()},
            'best': {s: result.setting(*b) if (b := result.best(s)) else None
                     for s in result.grids}}


@tool_support.command('sweep')
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    sources = frame_sources(args)

    def score(points: list[DetectorParams]) -> list[list[evaluation.FrameScore]]:
        with open_fleet(**fleet_options(args), tasks=len(points) * len(sources),
                        work_s=scoring.work_seconds(sources, len(points))) as fleet:
            _log(f'{len(points)} settings x {len(sources)} scenarios on {fleet.description}')
            return scoring.score_points(fleet, sources, points, label='sweep')

    result = grid_sweep(score, base_params(args), args.x, args.y, args.metric, log=_log)
    frame_count = sum(count for _, count, _ in sources)
    _print_result(args, result, frame_count)
    _write_heatmaps(args, result)
    print(f'heatmap: {args.out}')
    if args.json:
        args.json.write_text(json.dumps(_json(args, result, frame_count)) + '\n',
                             encoding='utf-8')
    return 0


def _write_heatmaps(args: argparse.Namespace, result: SweepResult) -> None:
    """One heatmap panel per scenario and overall, tiled into ``args.out``."""
    from obstacle_detection.viz import pictures

    panels = []
    for scene in result.grids:
        flat, metric, higher = result.ranking(scene)
        best = result.best(scene)
        title = f'{scene}: {metric}' + ('' if higher else ' (colour: 1 - it)')
        panels.append(pictures.heatmap(
            flat if higher else 1.0 - flat, list(args.x.values),
            list(args.y.values) if args.y else [''], title=title, x_name=args.x.name,
            y_name=args.y.name if args.y else '', best=best,
            values=flat))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    grid = pictures.tile(panels, columns=3)
    axes = args.x.name + (f' x {args.y.name}' if args.y else '')
    frames = ('every frame' if args.max_frames is None else
              f'{args.max_frames} frame{"s" if args.max_frames != 1 else ""} per scenario')
    scale = pictures.colour_bar(grid.shape[1], 'colour: the score, on one scale 0 to 1 in every '
                                'panel; a rate to minimise (false alarms) as 1 - it, so yellow is '
                                'better everywhere')
    pictures.write_png(args.out, pictures.titled(
        grid, f'sweep of {axes}: {args.metric} per scenario ({args.suite} suite, {frames}, '
              f'preset {args.preset}); red box: the best setting', below=scale))


if __name__ == '__main__':
    sys.exit(main())
