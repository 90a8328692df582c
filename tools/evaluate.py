#!/usr/bin/env python3
"""Score the obstacle detector against ground truth: per scenario and overall.

Scores a committed scenario suite (``--suite seed``: the seed's slope-only truth; ``--suite
robot``: the robot-level truth, with a table of objects found and passable surfaces left free)
and/or labelled folders (``depth/*.png``, ``labels/*.png``, ``intrinsics.yaml``); prints a table
and one JSON line (the last line of stdout, or ``--json FILE``)::

    python tools/evaluate.py --preset table_4_3 --scene corridor --scene people
    python tools/evaluate.py --suite robot --params-file params/corridor.yaml --workers 2

With Dask installed the scenarios run on a local cluster (``--workers 0``: in this process).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path
from typing import Any, Sequence

from obstacle_detection.cli import evaluation_args
from obstacle_detection.cli.evaluation_args import (SUITES, add_common_arguments, base_params,
                                                   frame_sources, report_error)
from obstacle_detection.cli import support as tool_support
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.fleet import scoring
from obstacle_detection.fleet.cluster import (Fleet, add_fleet_arguments, fleet_options,
                                              open_fleet)
from obstacle_detection.pipeline.params import PRESETS, DetectorParams


def _progress(total: int, label: str) -> Any:
    done = itertools.count(1)

    def on_frame(frame: evaluation.LabelledFrame, result: Any,
                 score: evaluation.FrameScore) -> None:
        print(f'{label} [{next(done)}/{total}] {frame.scenario} {frame.frame_id}: '
              f'cell F1 {evaluation.format_score(score.cell.f1)}, '
              f'{score.total_ms:.0f} ms', file=sys.stderr, flush=True)
    return on_frame


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(
        prog='evaluate', description=__doc__.split('\n\n')[0],
        epilog=evaluation.SCORE_DEFINITIONS, formatter_class=argparse.RawTextHelpFormatter)
    add_common_arguments(parser)
    parser.add_argument('--refiner', type=Path, metavar='MODEL',
                        help='also score the seed-4.5 logistic refinement of this model '
                             '(JSON from tools/train_refiner.py)')
    parser.add_argument('--json', metavar='FILE',
                        help="write the JSON report to FILE instead of printing it as the last "
                             "line ('-': print only the JSON line, table to stderr)")
    parser.add_argument('--pictures', type=Path, metavar='DIR',
                        help='also save one PNG per frame (depth + obstacles, costmap, '
                             'comparison with the truth)')
    parser.add_argument('--quiet', action='store_true', help='no per-frame progress lines')
    parser.add_argument('--beside-seed', action='append', choices=sorted(PRESETS), default=[],
                        metavar='PRESET',
                        help='also print the overall row of this preset on the seed suite '
                             '(repeatable)')
    add_fleet_arguments(parser)
    return parser


def seed_suite_rows(presets: Sequence[str], max_frames: int | None, fleet: Fleet | None = None,
                    ) -> list[tuple[str, evaluation.SceneSummary]]:
    """Return the seed suite's overall summary per preset (on ``fleet``: a task per scenario)."""
    scenarios = evaluation.load_scenarios(SUITES['seed'])
    if fleet is not None and fleet.distributed:
        sources = [(s.name, s.frame_count, evaluation_args.LazyFrames(
            evaluation.scenario_frames, s, max_frames=max_frames)) for s in scenarios]
        points = [PRESETS[name]() for name in presets]
        scores = scoring.score_points(fleet, sources, points, label='beside-seed')
        return [(name, evaluation.pool_scores(part, point, label=name).overall)
                for name, point, part in zip(presets, points, scores)]
    frames = [frame for scenario in scenarios
              for frame in evaluation.scenario_frames(scenario, max_frames=max_frames)]
    return [(name, evaluation.evaluate_frames(frames, PRESETS[name](), label=name).overall)
            for name in presets]


def format_seed_rows(rows: Sequence[tuple[str, evaluation.SceneSummary]]) -> str:
    """Return the seed-suite rows: preset, frames, pixel F1, cell F1, cell FA (fractions)."""
    width = max([len('preset')] + [len(name) for name, _ in rows]) + 1
    head = f'{"preset":<{width}} {"frames":>6} {"px F1":>7} {"cell F1":>7} {"cell FA":>7}'
    lines = [head, '-' * len(head)]
    for name, summary in rows:
        lines.append(f'{name:<{width}} {summary.frames:>6} '
                     f'{evaluation.format_score(summary.pixel.f1):>7} '
                     f'{evaluation.format_score(summary.cell.f1):>7} '
                     f'{evaluation.format_score(summary.cell.false_alarm_rate):>7}')
    return '\n'.join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    try:
        params = base_params(args)
        sources = frame_sources(args)
        refiner = None
        if args.refiner is not None:
            from obstacle_detection.pipeline.refine import LogisticRefiner
            refiner = LogisticRefiner.load(args.refiner)
        if args.pictures is not None:
            if args.workers or args.scheduler:
                raise tool_support.ToolError('--pictures draws in this process: leave out '
                                             '--workers/--scheduler', usage=True)
            args.workers = 0
    except (ValueError, OSError) as exc:
        return report_error('evaluate', exc)
    try:
        with open_fleet(**fleet_options(args), tasks=len(sources)) as fleet:
            return _evaluate(args, params, sources, refiner, fleet)
    except (ValueError, OSError) as exc:   # FleetError: Dask missing, no scheduler
        return report_error('evaluate', exc)
    except KeyboardInterrupt:   # nothing is written before the end
        print('evaluate.py: interrupted', file=sys.stderr)
        return 130


def _evaluate(args: Any, params: DetectorParams, sources: Any, refiner: Any,
              fleet: Fleet) -> int:
    """Score, print the tables and the JSON line (main's work, where ``fleet`` says)."""
    total = sum(count for _, count, _ in sources)
    callbacks = []
    if not args.quiet:
        callbacks.append(_progress(total, 'evaluate'))
    if args.pictures is not None:
        callbacks.append(_picture_writer(args.pictures, refiner, params))
    frames = itertools.chain.from_iterable(frames for _, _, frames in sources)
    label = args.preset + ''.join(f' + {path}' for path in args.params_file)

    def on_frame(frame: evaluation.LabelledFrame, result: Any,
                 score: evaluation.FrameScore) -> None:
        for callback in callbacks:
            callback(frame, result, score)

    try:
        if fleet.distributed:
            print(f'evaluate: {len(sources)} sequences on {fleet.description}',
                  file=sys.stderr, flush=True)
            report = scoring.evaluate_on_fleet(
                fleet, sources, params, label=label, refiner=refiner,
                refiner_name=str(args.refiner) if args.refiner else None,
                progress=not args.quiet)
        else:
            report = evaluation.evaluate_frames(
                frames, params, label=label, refiner=refiner,
                refiner_name=str(args.refiner) if args.refiner else None, on_frame=on_frame)
    except (ValueError, OSError) as exc:
        return report_error('evaluate', exc)
    table_stream = sys.stderr if args.json == '-' else sys.stdout
    print(f'parameters: {label}; {report.overall.frames} frames in {report.seconds:.1f} s',
          file=table_stream)
    print(evaluation.format_table(report), file=table_stream)
    if report.overall.robot is not None:
        print('\nrobot level (issue 9):', file=table_stream)
        print(evaluation.format_robot_table(report), file=table_stream)
    if refiner is not None:
        print(f'\nrefined by {args.refiner} (seed 4.5 logistic regression):', file=table_stream)
        print(evaluation.format_table(report, refined=True), file=table_stream)
    data = report.as_dict()
    if args.beside_seed:
        try:
            rows = seed_suite_rows(args.beside_seed, args.max_frames, fleet)
        except (ValueError, OSError) as exc:
            print(f'evaluate.py: error: {exc}', file=sys.stderr)
            return 2
        print('\nbeside it, the seed suite (scenarios.json, slope-only truth), overall:',
              file=table_stream)
        print(format_seed_rows(rows), file=table_stream)
        data['beside_seed'] = {name: summary.as_dict() for name, summary in rows}
    line = json.dumps(data, sort_keys=True)
    if args.json in (None, '-'):
        print(line)
    else:
        Path(args.json).write_text(line + '\n', encoding='utf-8')
    return 0


def _picture_writer(folder: Path, refiner: Any, base: DetectorParams) -> Any:
    from obstacle_detection.viz import pictures

    def on_frame(frame: evaluation.LabelledFrame, result: Any,
                 score: evaluation.FrameScore) -> None:
        name = f'{frame.scenario}_{frame.frame_id}'.replace(' ', '_').replace('/', '_')
        caption = (f'{frame.scenario} {frame.frame_id}: cell F1 '
                   f'{evaluation.format_score(score.cell.f1)}, pixel F1 '
                   f'{evaluation.format_score(score.pixel.f1)}')
        pictures.write_png(folder / f'{name}.png', pictures.side_by_side(
            result, caption=caption, truth_labels=frame.truth_labels,
            params=frame.params(base)))
    return on_frame


if __name__ == '__main__':
    sys.exit(main())
