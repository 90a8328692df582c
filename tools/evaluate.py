#!/usr/bin/env python3
"""Score the obstacle detector against ground truth: per scenario and overall.

Runs the pipeline over labelled frames, a committed scenario suite (scene generator, fixed
seeds: ``--suite seed``, scenarios.json, scored against the seed's slope-only truth, or
``--suite robot``, scenarios_robot.json, scored against the robot-level truth of issue 9
with time-of-flight sensor artefacts, which adds a table of objects found, passable surfaces
left free and drops marked) and/or labelled folders (``depth/*.png`` 16-bit mm,
``labels/*.png`` 8-bit 0/1/2/3, ``intrinsics.yaml`` with the camera mount), and prints a table
for people and one JSON line for machines (the last line of stdout, or ``--json FILE``).

Examples::

    python tools/evaluate.py                                  # suite, seed Table 4.2
    python tools/evaluate.py --preset table_4_3 --scene corridor --scene people
    python tools/evaluate.py --params-file params/corridor.yaml --refiner refiner.json
    python tools/evaluate.py --folder recordings/lab_run --pictures /tmp/pics
    python tools/evaluate.py --suite robot --params-file params/corridor.yaml  # issue 9
    python tools/evaluate.py --suite robot --params-file params/corridor.yaml \
        --beside-seed table_4_2 --beside-seed table_4_3
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path
from typing import Any, Iterable, Sequence

if __package__ in (None, ''):  # run as a script: make the repository root importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from obstacle_detection.evaluation import runner as evaluation  # noqa: E402
from obstacle_detection.cli import support as tool_support
from obstacle_detection.pipeline.params import PRESETS, DetectorParams  # noqa: E402

SUITES = evaluation.SUITES
DEFAULT_SCENARIOS = SUITES['seed']


def parse_assignment(text: str) -> tuple[str, str]:
    """``key=value`` -> (key, value); argparse type for ``--set``."""
    key, sep, value = text.partition('=')
    if not sep or not key.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f'expected key=value, got {text!r}')
    return key.strip(), value.strip()


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    """Frame-source and parameter options shared by evaluate, sweep and train_refiner."""
    parser.add_argument('--suite', choices=sorted(SUITES), default='seed',
                        help="committed scenario suite: 'seed' (scenarios.json, the "
                             "seed's slope-only truth) or 'robot' (scenarios_robot.json, "
                             'robot-level truth, time-of-flight noise) [default: seed]')
    parser.add_argument('--scenarios', type=Path, default=None,
                        help='scenario list (JSON) instead of the suite\'s')
    parser.add_argument('--truth', choices=sorted(evaluation.TRUTH_KINDS),
                        help="score against this truth instead of the scenarios' own")
    parser.add_argument('--scene', action='append', metavar='NAME',
                        help='evaluate only this scenario (repeatable) [default: all]')
    parser.add_argument('--folder', action='append', type=Path, metavar='DIR',
                        help='a labelled folder (depth/, labels/, intrinsics.yaml); '
                             'repeatable; given alone, the suite is skipped unless --scene')
    parser.add_argument('--max-frames', type=int, metavar='N',
                        help='at most N frames per scenario/folder, evenly spread')
    parser.add_argument('--preset', choices=sorted(PRESETS), default='table_4_2',
                        help='base parameters: seed Table 4.2 or 4.3 [default: table_4_2]')
    parser.add_argument('--params-file', type=Path, metavar='YAML', action='append',
                        default=[], help='node parameter file applied on top of the preset; '
                                         'repeatable, merged in order')
    parser.add_argument('--set', action='append', type=parse_assignment, default=[],
                        metavar='KEY=VALUE',
                        help='override one parameter (field name, theta_deg, N, N1, K, '
                             'voxel_m, ...); repeatable')


def base_params(args: argparse.Namespace) -> DetectorParams:
    """Preset, then parameter file, then ``--set`` overrides (ValueError on a bad one)."""
    params = PRESETS[args.preset]()
    files = args.params_file if isinstance(args.params_file, list) else (
        [] if args.params_file is None else [args.params_file])
    for path in files:  # several files apply in order, as ROS merges them
        params = evaluation.load_params_file(path, params)
    if args.set:
        try:
            params = evaluation.apply_overrides(params, dict(args.set))
        except ValueError as exc:
            raise tool_support.UsageError(f'argument --set: {exc}') from None
    return params


#: Errors about the command line rather than a file: exit 2 (tool_support).
USAGE_PREFIXES = ('unknown scenario', 'unknown parameter', '--')


def report_error(prog: str, exc: Exception) -> int:
    """Print the error line; unknown names and bad option values are usage errors (2)."""
    if not isinstance(exc, (OSError, tool_support.UsageError)) and \
            str(exc).startswith(USAGE_PREFIXES):
        exc = tool_support.UsageError(str(exc))
    return tool_support.report_error(prog, exc)


def frame_sources(args: argparse.Namespace,
                  ) -> list[tuple[str, int, Iterable[evaluation.LabelledFrame]]]:
    """(name, frame count, lazy frames) for each scenario and folder selected by the options."""
    sources: list[tuple[str, int, Iterable[evaluation.LabelledFrame]]] = []
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f'--max-frames={args.max_frames} must be >= 1')
    if args.scene or not args.folder:
        path = args.scenarios if args.scenarios is not None else SUITES[args.suite]
        scenarios = evaluation.select_scenarios(evaluation.load_scenarios(path), args.scene)
        rules = base_params(args)
        for scenario in scenarios:
            count = scenario.frame_count
            if args.max_frames is not None:
                count = min(count, args.max_frames)
            sources.append((scenario.name, count,
                            _lazy(evaluation.scenario_frames, scenario,
                                  max_frames=args.max_frames, rules=rules,
                                  truth=args.truth)))
    for folder in args.folder or []:
        count = len(evaluation.subsample(sorted((folder / 'depth').glob('*.png')),
                                         args.max_frames))
        sources.append((folder.name, count,
                        _lazy(evaluation.load_labelled_folder, folder,
                              max_frames=args.max_frames)))
    return sources


class _lazy:
    """An iterable that calls ``function(*args, **kwargs)`` only when iterated."""

    def __init__(self, function: Any, *args: Any, **kwargs: Any) -> None:
        self._call = (function, args, kwargs)

    def __iter__(self) -> Any:
        function, args, kwargs = self._call
        return iter(function(*args, **kwargs))


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
        prog='evaluate.py', description=__doc__.split('\n\n')[0],
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
                        help='also score this preset on the seed suite (scenarios.json, '
                             'slope-only truth) and print its overall row beside; repeatable')
    return parser


def seed_suite_rows(presets: Sequence[str], max_frames: int | None,
                    ) -> list[tuple[str, evaluation.SceneSummary]]:
    """Overall summaries of the seed suite for each preset (frames rendered once)."""
    frames = [frame for scenario in evaluation.load_scenarios(SUITES['seed'])
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
    except (ValueError, OSError) as exc:
        return report_error('evaluate.py', exc)
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
        report = evaluation.evaluate_frames(
            frames, params, label=label, refiner=refiner,
            refiner_name=str(args.refiner) if args.refiner else None, on_frame=on_frame)
    except (ValueError, OSError) as exc:
        return report_error('evaluate.py', exc)
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
            rows = seed_suite_rows(args.beside_seed, args.max_frames)
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
