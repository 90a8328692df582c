#!/usr/bin/env python3
"""Train the seed's section 4.5 logistic refiner and compare it with the rule-based result.

``--train-frames`` frames, evenly spread over the suite, train the model; on the held-out
frames the pixel and cell scores of the rule-based and the refined result are printed, then
the coefficients. The model (JSON) is for ``tools/evaluate.py --refiner`` and the node::

    python tools/train_refiner.py --preset table_4_3 --train-frames 20 --out refiner_t43.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

from obstacle_detection.cli.progress import Progress
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.evaluation.metrics import Confusion, format_score
from obstacle_detection.pipeline.refine import LogisticRefiner
from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.evaluation_args import (add_common_arguments, base_params,
                                                   frame_sources)


def split_frames(frames: Sequence[evaluation.LabelledFrame], train_count: int,
                 ) -> tuple[list[evaluation.LabelledFrame], list[evaluation.LabelledFrame]]:
    """(train, held out): ``train_count`` frames evenly spread, the rest held out, in order."""
    if not 1 <= train_count < len(frames):
        raise ValueError(f'--train-frames={train_count} must be between 1 and the number of '
                         f'frames minus one ({len(frames) - 1})')
    chosen = {id(f) for f in evaluation.subsample(frames, train_count)}
    train = [f for f in frames if id(f) in chosen]
    held_out = [f for f in frames if id(f) not in chosen]
    return train, held_out


def comparison_table(rule_pixel: Confusion, rule_cell: Confusion, refined_pixel: Confusion,
                     refined_cell: Confusion) -> str:
    """Rule-based vs refined on held-out frames, one row each."""
    head = (f'{"":<12} {"accuracy":>9} {"precision":>9} {"recall":>9} {"F1":>9} | '
            f'{"cell F1":>8} {"cell IoU":>8} {"cell FA":>8}')
    rows = [head, '-' * len(head)]
    for name, pixel, cell in (('rule-based', rule_pixel, rule_cell),
                              ('refined', refined_pixel, refined_cell)):
        rows.append(f'{name:<12} {format_score(pixel.accuracy):>9} '
                    f'{format_score(pixel.precision):>9} {format_score(pixel.recall):>9} '
                    f'{format_score(pixel.f1):>9} | {format_score(cell.f1):>8} '
                    f'{format_score(cell.iou):>8} {format_score(cell.false_alarm_rate):>8}')
    return '\n'.join(rows)


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog='train_refiner',
                                     description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawTextHelpFormatter)
    add_common_arguments(parser)
    parser.add_argument('--train-frames', type=int, default=10, metavar='N',
                        help='frames used for training (the seed: 10) [default: 10]')
    parser.add_argument('--max-pixels', type=int, default=20000, metavar='M',
                        help='training pixels drawn per frame [default: 20000]')
    parser.add_argument('--l2', type=float, default=1e-3,
                        help='L2 penalty on the standardised coefficients [default: 1e-3]')
    parser.add_argument('--seed', type=int, default=0, help='pixel sampling seed [default: 0]')
    parser.add_argument('--out', type=Path, default=Path('refiner.json'),
                        help='model file to write [default: refiner.json]')
    return parser


@tool_support.command('train_refiner')
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    params = base_params(args)
    started = time.perf_counter()
    frames = [f for _, _, source in frame_sources(args) for f in source]
    train, held_out = split_frames(frames, args.train_frames)
    print(f'{len(frames)} frames rendered in {time.perf_counter() - started:.1f} s: '
          f'{len(train)} for training, {len(held_out)} held out', file=sys.stderr)
    x, y = evaluation.collect_training_samples(
        train, params, max_pixels_per_frame=args.max_pixels, seed=args.seed)
    model = LogisticRefiner.fit(x, y, l2=args.l2, preset=args.preset, train_frames=len(train),
                                train_scenarios=sorted({f.scenario for f in train}))
    model.save(args.out)
    with Progress(len(held_out), 'scoring the held-out frames') as bar:
        report = evaluation.evaluate_frames(held_out, params, refiner=model,
                                            refiner_name=str(args.out),
                                            on_frame=lambda *_: bar.update())
    overall = report.overall
    print(f'parameters: {args.preset}; trained on {len(train)} frames '
          f'({y.size} pixels, {int(y.sum())} obstacle); model: {args.out}')
    print(f'\nheld-out frames: {overall.frames}')
    print(comparison_table(overall.pixel, overall.cell, overall.refined_pixel or Confusion(),
                           overall.refined_cell or Confusion()))
    print('\nper scenario, rule-based:')
    print(evaluation.format_table(report))
    print('\nper scenario, refined:')
    print(evaluation.format_table(report, refined=True))
    data = model.to_dict()
    print('\ncoefficients (on standardised slope and gradient; e_k are 0/1):')
    print(f'  intercept {data["intercept"]:+.3f}')
    for name, value in data['coefficients'].items():
        print(f'  {name:<16} {value:+.3f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
