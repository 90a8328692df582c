#!/usr/bin/env python3
"""Score the fused costmap over scene sequences, side by side with the per-frame costmap.

Runs the detector on every frame of each sequence (default params/corridor.yaml) and fuses the
costmaps at the odometry pose; prints a table and one JSON line (the last line of stdout, or
``--json FILE``); ``--sheet`` draws per-frame and fused grids over time::

    python tools/evaluate_video.py --sequence person_crossing --no-odometry
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.evaluation_args import parse_assignment
from obstacle_detection.pipeline.fusion import FusionParams
from obstacle_detection.sim.sequences import (PERFECT_ODOMETRY, SEQUENCE_NAMES,
                                          OdometryModel, SceneSequence)

DEFAULT_PARAMS = tool_support.package_file('params/corridor.yaml')
PROG = 'evaluate_video'


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(
        prog=PROG, description=__doc__.split('\n\n')[0],
        epilog='What is measured: docs/accuracy.md, "Scores of the fused costmap over a '
               'sequence".')
    parser.add_argument('--sequence', action='append', choices=SEQUENCE_NAMES,
                        help='evaluate only this sequence (repeatable) [default: all]')
    parser.add_argument('--params-file', type=Path, default=DEFAULT_PARAMS, metavar='YAML',
                        help='detector parameter file [default: params/corridor.yaml]')
    parser.add_argument('--fusion', action='append', type=parse_assignment, default=[],
                        metavar='KEY=NUMBER',
                        help='a FusionParams field (size_m, resolution_m, hit_log_odds, '
                             'miss_log_odds, min_log_odds, max_log_odds, occupied_log_odds, '
                             'free_log_odds, max_jump_m, max_jump_deg); repeatable')
    parser.add_argument('--seed', type=int, default=0,
                        help='sequence seed [default: 0]')
    parser.add_argument('--frames', type=int, metavar='N',
                        help='only the first N frames of each sequence')
    parser.add_argument('--no-odometry', action='store_true',
                        help='fuse every frame in place (as without odometry)')
    parser.add_argument('--exact-odometry', action='store_true',
                        help='odometry without drift or noise (the true poses)')
    parser.add_argument('--sheet', type=Path, metavar='PNG',
                        help='write a contact sheet of per-frame and fused grids over time '
                             '(the sequences one under the other)')
    parser.add_argument('--sheet-frames', type=int, default=4, metavar='N',
                        help='moments per sequence on the sheet [default: 4]')
    parser.add_argument('--json', metavar='FILE',
                        help='write the JSON report to FILE instead of printing it last')
    parser.add_argument('--quiet', action='store_true', help='no progress lines')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    try:
        for name, value, low in (('--frames', args.frames, 1), ('--seed', args.seed, 0),
                                 ('--sheet-frames', args.sheet_frames, 1)):
            if value is not None and value < low:
                raise tool_support.ToolError(f'argument {name}: {value} must be >= {low}',
                                             usage=True)
        try:
            fusion = FusionParams(**{key: float(value) for key, value in args.fusion})
        except (TypeError, ValueError) as exc:
            raise tool_support.ToolError(f'argument --fusion: {exc}', usage=True) from None
        params = evaluation.load_params_file(args.params_file)
        if args.sheet is not None and args.sheet.suffix.lower() != '.png':
            raise tool_support.ToolError(args.sheet, 'the contact sheet must be a .png file')
    except (ValueError, OSError) as exc:
        return tool_support.report_error(PROG, exc)
    from obstacle_detection.evaluation import video
    from obstacle_detection.evaluation.video import evaluate_sequence, format_table

    reports = []
    for name in args.sequence or SEQUENCE_NAMES:
        sequence = SceneSequence(name, seed=args.seed,
                                 odometry=PERFECT_ODOMETRY if args.exact_odometry
                                 else OdometryModel())

        def progress(index: int, total: int, name: str = name) -> None:
            if not args.quiet and (index + 1 == total or (index + 1) % 30 == 0):
                print(f'{PROG}: {name} frame {index + 1}/{total}', file=sys.stderr,
                      flush=True)

        reports.append(evaluate_sequence(
            sequence, params, fusion, stop=args.frames, use_odometry=not args.no_odometry,
            sheet_frames=args.sheet_frames if args.sheet is not None else 0,
            on_frame=progress))
    print(f'detector: {args.params_file}; fusion: {fusion}')
    print(format_table(reports))
    if args.sheet is not None:
        import numpy as np

        from obstacle_detection.viz import pictures
        from obstacle_detection.viz.overlay import FREE_RGB, OCCUPIED_RGB, ROBOT_RGB, UNKNOWN_RGB
        sheets = [r.sheet for r in reports if r.sheet is not None]
        width = max(s.shape[1] for s in sheets)
        rows = [np.pad(s, ((0, 0), (0, width - s.shape[1]), (0, 0)), constant_values=255)
                for s in sheets]
        names = ', '.join(r.name for r in reports if r.sheet is not None)
        legend = pictures.legend(
            f'each pair: per-frame costmap moved into odom | fused costmap; a {fusion.size_m:g} m '
            f'x {fusion.size_m:g} m window around the robot, north-up in odom (x up, y left), '
            f'{fusion.resolution_m * 100:g} cm cells', [
                ('box', OCCUPIED_RGB, 'occupied'), ('box', FREE_RGB, 'free'),
                ('box', UNKNOWN_RGB, 'unknown'),
                ('line', video.TRUTH_OUTLINE_RGB, "the truth's obstacles seen so far"),
                ('triangle', ROBOT_RGB, 'robot (a disc, a line along its heading)')], width)
        try:
            pictures.write_png(args.sheet, pictures.titled(
                np.vstack(rows), f'Per-frame and fused costmaps over time: {names}',
                below=legend))
        except OSError as exc:
            return tool_support.report_error(PROG, exc)
        print(f'contact sheet: {args.sheet}')
    line = json.dumps({'fusion': fusion.__dict__,
                       'sequences': [r.as_dict() for r in reports]}, sort_keys=True)
    if args.json is None:
        print(line)
    else:
        try:
            Path(args.json).write_text(line + '\n', encoding='utf-8')
        except OSError as exc:
            return tool_support.report_error(PROG, exc)
    return tool_support.EXIT_OK


if __name__ == '__main__':
    sys.exit(main())
