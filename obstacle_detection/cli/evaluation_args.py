"""Command-line options shared by evaluate, sweep and pictures."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Iterable

from obstacle_detection.cli import support as tool_support
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline.params import PRESETS, DetectorParams, Intrinsics, frame_budget
from obstacle_detection.ros.parameters import params_file_problems

#: The frames of ../shared/data/real/README.md: (folder, files, units per metre, intrinsics).
REAL_FRAMES = (
    ('tum_office', ('depth.png',), 5000.0, Intrinsics(535.4, 539.2, 320.1, 247.6)),
    ('tum_fr2_desk', ('depth_1.png', 'depth_2.png'), 5000.0,
     Intrinsics(520.9, 521.0, 325.1, 249.7)),
    ('dining_room', tuple(f'depth_{i}.pgm' for i in range(1, 6)), 1000.0,
     Intrinsics(518.0, 519.0, 325.5, 253.5)),
)


def parse_assignment(text: str) -> tuple[str, str]:
    """``key=value`` -> (key, value); argparse type for ``--set``."""
    key, sep, value = text.partition('=')
    if not sep or not key.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f'expected key=value, got {text!r}')
    return key.strip(), value.strip()


#: What each suite is, as the tools' headers name it.
SUITE_TEXT = {'seed': "seed (scenarios.json, the seed's slope-only truth)",
              'robot': 'robot (scenarios_robot.json, robot-level truth)'}


def add_common_arguments(parser: argparse.ArgumentParser, *, suite: str = 'robot',
                         max_frames: int | None = None) -> None:
    """Frame-source and parameter options shared by evaluate and sweep, with their defaults."""
    parser.add_argument('--suite', choices=sorted(evaluation.SUITES), default=suite,
                        help="committed scenario suite: 'seed' (scenarios.json, the "
                             "seed's slope-only truth) or 'robot' (scenarios_robot.json, "
                             'robot-level truth, time-of-flight noise, the README\'s table) '
                             f'[default: {suite}]')
    parser.add_argument('--scene', action='append', metavar='NAME',
                        help='evaluate only this scenario (repeatable) [default: all]')
    parser.add_argument('--max-frames', type=int, metavar='N', default=max_frames,
                        help='at most N frames per scenario, evenly spread '
                             f'[default: {max_frames or "every frame"}]')
    add_parameter_arguments(parser)


def add_parameter_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the detector parameter options: ``--preset``, ``--params-file``, ``--set``."""
    parser.add_argument('--preset', choices=sorted(PRESETS), default='corridor',
                        help='base parameters: corridor (params/corridor.yaml, the node\'s '
                             'default) or the seed method, table_4_2 / table_4_3 '
                             '[default: corridor]')
    parser.add_argument('--params-file', type=Path, metavar='YAML', action='append',
                        default=[], help='node parameter file applied on top of the preset; '
                                         'repeatable, merged in order')
    parser.add_argument('--set', action='append', type=parse_assignment, default=[],
                        metavar='KEY=VALUE',
                        help='override one parameter (field name, theta_deg, N, N1, K, '
                             'voxel_m, ...); repeatable')


def base_params(args: argparse.Namespace) -> DetectorParams:
    """Preset, then parameter file, then ``--set`` overrides (ValueError on a bad one).

    A set beyond a frame's budget (``frame_budget``, docs/budget.md) is refused: from the
    parameter files, bad input (exit 1); from ``--set``, a usage error (exit 2).
    """
    params = PRESETS[args.preset]()
    for path in args.params_file:  # several files apply in order, as ROS merges them
        params = evaluation.load_params_file(path, params)
        for problem in params_file_problems(path):   # what the node would ignore, as it says
            tool_support.warn(problem)
    problem = frame_budget(params).problem()   # a combination beyond a frame's budget
    if problem is not None:
        raise tool_support.ToolError(
            ', '.join(map(str, args.params_file)) or f'--preset {args.preset}', problem)
    if args.set:
        try:
            params = evaluation.apply_overrides(params, dict(args.set))
            problem = frame_budget(params).problem()
            if problem is not None:
                raise ValueError(problem)
        except ValueError as exc:
            raise tool_support.ToolError(f'argument --set: {exc}', usage=True) from None
    return params


def frame_sources(args: argparse.Namespace,
                  ) -> list[tuple[str, int, Iterable[evaluation.LabelledFrame]]]:
    """(name, frame count, lazy frames) for each scenario selected by the options."""
    if args.max_frames is not None and args.max_frames < 1:
        raise tool_support.ToolError(f'--max-frames={args.max_frames} must be >= 1', usage=True)
    scenarios = evaluation.select_scenarios(
        evaluation.load_scenarios(evaluation.SUITES[args.suite]), args.scene)
    rules = base_params(args)
    return [(s.name, min(s.frame_count, args.max_frames or s.frame_count),
             LazyFrames(evaluation.scenario_frames, s, max_frames=args.max_frames, rules=rules))
            for s in scenarios]


class LazyFrames:
    """An iterable that calls ``function(*args, **kwargs)`` only when iterated."""

    def __init__(self, function: Any, *args: Any, **kwargs: Any) -> None:
        self._call = (function, args, kwargs)

    def __iter__(self) -> Any:
        function, args, kwargs = self._call
        return iter(function(*args, **kwargs))
