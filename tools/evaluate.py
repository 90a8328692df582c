#!/usr/bin/env python3
"""Score the obstacle detector against ground truth: per scenario and overall.

Scores a scenario suite (``--suite seed|robot``); ``--real DIR`` scores
unlabelled real frames by their height above the floor, ``--sequence NAME`` the fused costmap
over a scene sequence; ``--train-refiner OUT`` fits the seed's section 4.5 logistic refiner on
some frames and scores it on the others. Prints a table and one JSON line (the last line of
stdout, or ``--json FILE``); docs/accuracy.md has the examples. ``--workers``/``--scheduler``
run it on Dask.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from obstacle_detection.cli.evaluation_args import (REAL_FRAMES, SUITE_TEXT,
                                                   add_common_arguments, base_params,
                                                   frame_sources)
from obstacle_detection.cli import support as tool_support
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.fleet import scoring
from obstacle_detection.fleet.cluster import (TaskError, add_fleet_arguments, fleet_options,
                                              open_fleet, run_tasks)
from obstacle_detection.pipeline.params import DetectorParams
from obstacle_detection.sim.sequences import SEQUENCE_NAMES


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(
        prog='evaluate', description=__doc__.split('\n\n')[0],
        epilog='what the scores count: docs/accuracy.md',
        formatter_class=argparse.RawTextHelpFormatter)
    add_common_arguments(parser)
    refiner = parser.add_mutually_exclusive_group()
    refiner.add_argument('--refiner', type=Path, metavar='MODEL',
                         help='also score the seed-4.5 logistic refinement of this model '
                              '(JSON from --train-refiner)')
    refiner.add_argument('--train-refiner', type=Path, metavar='OUT',
                         help='fit the seed-4.5 refiner on --train-frames frames spread evenly, '
                              'save it to OUT (JSON), score it on the other frames')
    parser.add_argument('--train-frames', type=int, default=10, metavar='N',
                        help='frames the refiner is fitted on (the seed: 10) [default: 10]')
    parser.add_argument('--max-pixels', type=int, default=20000, metavar='M',
                        help='training pixels drawn per frame [default: 20000]')
    parser.add_argument('--l2', type=float, default=1e-3,
                        help='L2 penalty on the standardised coefficients [default: 1e-3]')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the scene sequences (--sequence) or of the training '
                             'pixels drawn (--train-refiner) [default: 0]')
    parser.add_argument('--json', metavar='FILE',
                        help="write the JSON report to FILE instead of printing it as the last "
                             "line ('-': print only the JSON line, table to stderr)")
    parser.add_argument('--real', type=Path, metavar='DIR',
                        help='instead, score the real frames of DIR (tum_office/, '
                             'tum_fr2_desk/, dining_room/) by height above the fitted floor')
    parser.add_argument('--quiet', action='store_true', help='no progress lines')
    add_fleet_arguments(parser)
    video = parser.add_argument_group('the fused costmap over scene sequences (--sequence)')
    video.add_argument('--sequence', action='append', choices=(*SEQUENCE_NAMES, 'all'),
                       help='instead, score the fused costmap over this scene sequence '
                            "(repeatable; 'all': every one); docs/accuracy.md says what counts")
    video.add_argument('--frames', type=int, metavar='N',
                       help='only the first N frames of each sequence')
    video.add_argument('--exact-odometry', action='store_true',
                       help='odometry without drift or noise (the true poses)')
    video.add_argument('--sheet', type=Path, metavar='PNG',
                       help='write a contact sheet of per-frame and fused grids at 8 moments '
                            'of each sequence')
    return parser


@tool_support.command('evaluate')
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    params = base_params(args)
    if args.real is not None:
        return _score_real_frames(args, params)
    if args.sequence:
        return _score_sequences(args, params)
    sources = frame_sources(args)
    refiner = None
    if args.refiner is not None:
        from obstacle_detection.pipeline.refine import LogisticRefiner
        refiner = LogisticRefiner.load(args.refiner)
    if args.train_refiner is not None:
        sources, refiner = _train_refiner(args, params, sources)
    label = _label(args)
    refiner_name = str(args.refiner or args.train_refiner) if refiner is not None else None
    with open_fleet(**fleet_options(args), tasks=len(sources),
                    work_s=scoring.work_seconds(sources)) as fleet:
        if not args.quiet:
            print(f'evaluate: {len(sources)} sequences in {fleet.description}', file=sys.stderr,
                  flush=True)
        report = scoring.evaluate_on_fleet(fleet, sources, params, label=label,
                                           refiner=refiner, refiner_name=refiner_name,
                                           progress=not args.quiet)
    out = sys.stderr if args.json == '-' else sys.stdout
    print(f'suite: {SUITE_TEXT[args.suite]}; parameters: {label}; {report.overall.frames} '
          f'frames in {report.seconds:.1f} s', file=out)
    print(evaluation.format_table(report), file=out)
    if report.overall.robot is not None:
        print('\nrobot table (objects found, drops, passable free, 1-cell F1):', file=out)
        print(evaluation.format_robot_table(report), file=out)
    if refiner is not None:
        print(f'\nrefined by {refiner_name} (seed 4.5 logistic regression):', file=out)
        print(evaluation.format_table(report, refined=True), file=out)
    _write_json(args.json, report.as_dict())
    return 0


def _train_refiner(args: Any, params: DetectorParams, sources: Any) -> tuple[list, Any]:
    """Fit the refiner on ``--train-frames`` frames spread evenly, save it, print it.

    Return the other frames (held out) as the one source to score, and the model.
    """
    from obstacle_detection.pipeline.refine import LogisticRefiner, training_samples

    frames = [f for _, _, source in sources for f in source]
    if not 1 <= args.train_frames < len(frames) or args.max_pixels < 1:
        raise tool_support.ToolError(f'--train-frames={args.train_frames} must be in 1..'
                                     f'{len(frames) - 1} (the frames less one), --max-pixels='
                                     f'{args.max_pixels} >= 1', usage=True)
    chosen = {id(f) for f in evaluation.subsample(frames, args.train_frames)}
    train = [f for f in frames if id(f) in chosen]
    held_out = [f for f in frames if id(f) not in chosen]
    rng, xs, ys = np.random.default_rng(args.seed), [], []
    for frame, _, result, prev_mask in evaluation.detect_frames(train, params):
        x, y = training_samples(result, frame.truth_labels, prev_mask)
        if y.size > args.max_pixels:   # drawn without replacement
            pick = rng.choice(y.size, size=args.max_pixels, replace=False)
            x, y = x[pick], y[pick]
        xs.append(x)
        ys.append(y)
    x, y = np.concatenate(xs), np.concatenate(ys)
    model = LogisticRefiner.fit(x, y, l2=args.l2, preset=args.preset, train_frames=len(train),
                                train_scenarios=sorted({f.scenario for f in train}))
    model.save(args.train_refiner)
    data = model.to_dict()
    out = sys.stderr if args.json == '-' else sys.stdout
    print(f'refiner fitted on {len(train)} frames ({y.size} pixels, {int(y.sum())} obstacle), '
          f'saved to {args.train_refiner}; scored on the {len(held_out)} others', file=out)
    print('coefficients (standardised slope and gradient; e_k are 0/1): '
          f'intercept {data["intercept"]:+.3f}, ' + ', '.join(
              f'{name} {value:+.3f}' for name, value in data['coefficients'].items()), file=out)
    return [('held out', len(held_out), held_out)], model


def _score_sequences(args: Any, params: DetectorParams) -> int:
    """Print the fused and per-frame scores of the sequences, the JSON line; the sheet."""
    from obstacle_detection.evaluation import video
    from obstacle_detection.pipeline.fusion import FusionParams
    from obstacle_detection.sim.sequences import SceneSequence

    for name, value, low in (('--frames', args.frames, 1), ('--seed', args.seed, 0)):
        if value is not None and value < low:   # one error line, no usage block
            raise tool_support.ToolError(f'argument {name}: {value} must be >= {low}',
                                         usage=True)
    fusion = FusionParams()
    if args.sheet is not None and args.sheet.suffix.lower() != '.png':
        raise tool_support.ToolError(args.sheet, 'the contact sheet must be a .png file')
    names = SEQUENCE_NAMES if 'all' in args.sequence else args.sequence
    tasks = [(name, args.seed, args.exact_odometry, params, fusion, args.frames,
              8 if args.sheet is not None else 0) for name in names]
    frames = sum(min(len(SceneSequence(name)), args.frames or len(SceneSequence(name)))
                 for name in names)
    with open_fleet(**fleet_options(args), tasks=len(tasks),
                    work_s=frames * scoring.SEQUENCE_FRAME_S) as fleet:
        if not args.quiet:
            print(f'evaluate: {len(tasks)} sequence{"s" if len(tasks) != 1 else ""} '
                  f'({frames} frames) in {fleet.description}', file=sys.stderr, flush=True)
        if fleet.distributed:   # one task per sequence
            reports = run_tasks(fleet, scoring.score_video_sequence, tasks, label='sequences',
                                progress=not args.quiet)
        else:   # here, with a line every 30 frames
            reports = [scoring.score_video_sequence(*task, on_frame=functools.partial(
                _sequence_progress, args.quiet, task[0])) for task in tasks]
    out = sys.stderr if args.json == '-' else sys.stdout
    print(f'parameters: {_label(args)}; fusion: {_fusion_text(fusion)}', file=out)
    print(video.format_table(reports), file=out)
    if args.sheet is not None:
        from obstacle_detection.viz import pictures

        pictures.write_png(args.sheet, video.contact_sheet(reports, fusion))
        print(f'contact sheet: {args.sheet}', file=out)
    _write_json(args.json, {'fusion': fusion.__dict__,
                            'sequences': [r.as_dict() for r in reports]})
    return 0


def _fusion_text(fusion: Any) -> str:
    """Return the fused costmap's settings in words (FusionParams, docs/fused_costmap.md)."""
    return (f'a {fusion.size_m:g} m window at {fusion.resolution_m:g} m a cell; log-odds '
            f'{fusion.hit_log_odds:+g} a hit, {fusion.miss_log_odds:+g} a miss, kept in '
            f'[{fusion.min_log_odds:g}, {fusion.max_log_odds:g}]; occupied from '
            f'{fusion.occupied_log_odds:g}, free below {fusion.free_log_odds:g}; an odometry '
            f'jump over {fusion.max_jump_m:g} m or {fusion.max_jump_deg:g} deg in one frame '
            're-anchors the map')


def _sequence_progress(quiet: bool, name: str, index: int, total: int) -> None:
    if not quiet and (index + 1 == total or (index + 1) % 30 == 0):
        print(f'evaluate: {name} frame {index + 1}/{total}', file=sys.stderr, flush=True)


def _label(args: Any) -> str:
    return args.preset + ''.join(f' + {path}' for path in args.params_file)


def _write_json(path: str | None, data: dict) -> None:
    """Print ``data`` as the last line of stdout, or write it to ``path`` ('-': print)."""
    line = json.dumps(data, sort_keys=True)
    if path in (None, '-'):
        print(line)
    else:
        Path(path).write_text(line + '\n', encoding='utf-8')


def _score_real_frames(args: Any, params: DetectorParams) -> int:
    """Print per real frame the floor pixels marked (lower is better), standing ones marked.

    The frames are read here and scored as tasks (``--workers``/``--scheduler``); the JSON
    report holds the counts per frame and in total.
    """
    from obstacle_detection.evaluation.datasets import read_depth_png
    from obstacle_detection.pipeline.depth import decode_depth

    frames = []
    for name, files, scale, intrinsics in REAL_FRAMES:
        for file in files:
            path = args.real / name / file
            try:
                frames.append((f'{name}/{file}', path, decode_depth(read_depth_png(path),
                                                                    depth_scale=scale),
                               intrinsics))
            except (OSError, ValueError) as exc:   # named with its path
                raise tool_support.ToolError(
                    str(exc) if str(path) in str(exc) else f'{path}: {exc}') from None
    with open_fleet(**fleet_options(args), tasks=len(frames),
                    work_s=len(frames) * scoring.REAL_FRAME_S) as fleet:
        if not args.quiet:
            print(f'evaluate: {len(frames)} real frames in {fleet.description}',
                  file=sys.stderr, flush=True)
        results = run_tasks(fleet, scoring.real_frame_counts,
                            [(depth, intrinsics, params) for _, _, depth, intrinsics in frames],
                            label='real frames', progress=not args.quiet, return_errors=True)
    out = sys.stderr if args.json == '-' else sys.stdout
    totals = np.zeros(4, np.int64)
    rows = []
    for (name, path, _, _), result in zip(frames, results):
        if isinstance(result, TaskError):
            raise tool_support.ToolError(path, result.reason)
        *counts, mount = result
        totals += counts
        rows.append({'frame': name, 'floor': counts[0], 'floor_marked': counts[1],
                     'standing': counts[2], 'standing_marked': counts[3], 'mount': mount})
        print(f'{name}: floor marked {counts[1]}/{counts[0]} '
              f'({100.0 * counts[1] / max(counts[0], 1):.2f} %), standing marked '
              f'{counts[3]}/{counts[2]} ({100.0 * counts[3] / max(counts[2], 1):.1f} %)'
              f'  [{mount}]', file=out)
    floor_pct = 100.0 * totals[1] / max(totals[0], 1)
    standing_pct = 100.0 * totals[3] / max(totals[2], 1)
    print(f'total: floor marked {floor_pct:.2f} % of {totals[0]} px, standing marked '
          f'{standing_pct:.1f} % of {totals[2]} px', file=out)
    _write_json(args.json, {'parameters': _label(args), 'frames': rows, 'total': {
        'floor': int(totals[0]), 'floor_marked': int(totals[1]), 'standing': int(totals[2]),
        'standing_marked': int(totals[3]), 'floor_marked_pct': round(floor_pct, 4),
        'standing_marked_pct': round(standing_pct, 4)}})
    return 0


if __name__ == '__main__':
    sys.exit(main())
