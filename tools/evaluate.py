#!/usr/bin/env python3
"""Score the obstacle detector against ground truth: per scenario and overall.

Scores a scenario suite (``--suite seed|robot``) and/or labelled folders; ``--real DIR`` scores
unlabelled real frames by their height above the floor, ``--sequence NAME`` the fused costmap
over a scene sequence. Prints a table and one JSON line (the last line of stdout, or ``--json
FILE``); docs/accuracy.md has the examples. ``--workers``/``--scheduler`` run it on Dask.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from obstacle_detection.cli.evaluation_args import (REAL_FRAMES, add_common_arguments,
                                                   base_params, frame_sources, parse_assignment)
from obstacle_detection.cli import support as tool_support
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.fleet import scoring
from obstacle_detection.fleet.cluster import (Fleet, add_fleet_arguments, fleet_options,
                                              open_fleet)
from obstacle_detection.labels import (CELL_FREE, CELL_OCCUPIED, GT_NO_RETURN, GT_OBSTACLE,
                                       GT_TRAVERSABLE, LABEL_OBSTACLE)
from obstacle_detection.pipeline.params import DetectorParams, Intrinsics
from obstacle_detection.sim.sequences import SEQUENCE_NAMES

#: Real frames: floor pixels lie within FLOOR_BAND_M of the fitted floor; standing pixels
#: STANDING_M above it up to the robot height.
FLOOR_BAND_M = 0.02
STANDING_M = 0.05


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
    parser.add_argument('--causes', action='store_true',
                        help='also count the false-alarm cells of each scenario by cause '
                             '(docs/accuracy.md)')
    parser.add_argument('--real', type=Path, metavar='DIR',
                        help='instead, score the real frames of DIR (tum_office/, '
                             'tum_fr2_desk/, dining_room/) by height above the fitted floor')
    parser.add_argument('--quiet', action='store_true', help='no per-frame progress lines')
    add_fleet_arguments(parser)
    video = parser.add_argument_group('the fused costmap over scene sequences (--sequence)')
    video.add_argument('--sequence', action='append', choices=(*SEQUENCE_NAMES, 'all'),
                       help='instead, score the fused costmap over this scene sequence '
                            "(repeatable; 'all': every one); docs/accuracy.md says what counts")
    video.add_argument('--fusion', action='append', type=parse_assignment, default=[],
                       metavar='KEY=NUMBER',
                       help='a FusionParams field (size_m, resolution_m, hit_log_odds, '
                            'miss_log_odds, min_log_odds, max_log_odds, occupied_log_odds, '
                            'free_log_odds, max_jump_m, max_jump_deg); repeatable')
    video.add_argument('--seed', type=int, default=0, help='sequence seed [default: 0]')
    video.add_argument('--frames', type=int, metavar='N',
                       help='only the first N frames of each sequence')
    video.add_argument('--no-odometry', action='store_true',
                       help='fuse every frame in place (as without odometry)')
    video.add_argument('--exact-odometry', action='store_true',
                       help='odometry without drift or noise (the true poses)')
    video.add_argument('--sheet', type=Path, metavar='PNG',
                       help='write a contact sheet of per-frame and fused grids over time')
    video.add_argument('--sheet-frames', type=int, default=4, metavar='N',
                       help='moments per sequence on the sheet [default: 4]')
    return parser


@tool_support.command('evaluate')
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    params = base_params(args)
    if args.real is not None:
        return _score_real_frames(args.real, params)
    if args.sequence:
        return _score_sequences(args, params)
    sources = frame_sources(args)
    refiner = None
    if args.refiner is not None:
        from obstacle_detection.pipeline.refine import LogisticRefiner
        refiner = LogisticRefiner.load(args.refiner)
    if args.pictures is not None or args.causes:
        if args.workers or args.scheduler:
            raise tool_support.ToolError('--pictures and --causes work in this process: '
                                         'leave out --workers/--scheduler', usage=True)
        args.workers = 0
    with open_fleet(**fleet_options(args), tasks=len(sources)) as fleet:
        return _evaluate(args, params, sources, refiner, fleet)


def _evaluate(args: Any, params: DetectorParams, sources: Any, refiner: Any,
              fleet: Fleet) -> int:
    """Score, print the tables and the JSON line (main's work, where ``fleet`` says)."""
    total = sum(count for _, count, _ in sources)
    callbacks = []
    if not args.quiet:
        callbacks.append(_progress(total, 'evaluate'))
    if args.pictures is not None:
        callbacks.append(_picture_writer(args.pictures, params))
    causes: dict[str, Counter] = {}
    if args.causes:
        callbacks.append(lambda frame, result, score: causes.setdefault(
            frame.scenario, Counter()).update(false_alarm_causes(frame, result, params)))
    frames = itertools.chain.from_iterable(frames for _, _, frames in sources)
    label = _label(args)
    refiner_name = str(args.refiner) if args.refiner else None
    if fleet.distributed:
        print(f'evaluate: {len(sources)} sequences on {fleet.description}',
              file=sys.stderr, flush=True)
        report = scoring.evaluate_on_fleet(fleet, sources, params, label=label,
                                           refiner=refiner, refiner_name=refiner_name,
                                           progress=not args.quiet)
    else:
        def on_frame(*frame_result_score: Any) -> None:
            for callback in callbacks:
                callback(*frame_result_score)

        report = evaluation.evaluate_frames(frames, params, label=label, refiner=refiner,
                                            refiner_name=refiner_name, on_frame=on_frame)
    out = sys.stderr if args.json == '-' else sys.stdout
    print(f'parameters: {label}; {report.overall.frames} frames in {report.seconds:.1f} s',
          file=out)
    print(evaluation.format_table(report), file=out)
    if report.overall.robot is not None:
        print('\nrobot level (issue 9):', file=out)
        print(evaluation.format_robot_table(report), file=out)
    if refiner is not None:
        print(f'\nrefined by {args.refiner} (seed 4.5 logistic regression):', file=out)
        print(evaluation.format_table(report, refined=True), file=out)
    if args.causes:
        causes['overall'] = sum(causes.values(), Counter())
        print('\nfalse-alarm cells by cause:', file=out)
        for name, counts in causes.items():
            if counts:
                print(f'{name:<24} ' + ', '.join(f'{n} {k}' for k, n in counts.most_common()),
                      file=out)
    _write_json(args.json, report.as_dict())
    return 0


def _score_sequences(args: Any, params: DetectorParams) -> int:
    """Print the fused and per-frame scores of the sequences, the JSON line; the sheet."""
    from obstacle_detection.evaluation import video
    from obstacle_detection.pipeline.fusion import FusionParams
    from obstacle_detection.sim.sequences import PERFECT_ODOMETRY, OdometryModel, SceneSequence

    for name, value, low in (('--frames', args.frames, 1), ('--seed', args.seed, 0),
                             ('--sheet-frames', args.sheet_frames, 1)):
        if value is not None and value < low:   # one error line, no usage block
            raise tool_support.ToolError(f'argument {name}: {value} must be >= {low}',
                                         usage=True)
    try:
        fusion = FusionParams(**{key: float(value) for key, value in args.fusion})
    except (TypeError, ValueError) as exc:
        raise tool_support.ToolError(f'argument --fusion: {exc}', usage=True) from None
    if args.sheet is not None and args.sheet.suffix.lower() != '.png':
        raise tool_support.ToolError(args.sheet, 'the contact sheet must be a .png file')
    reports = []
    for name in SEQUENCE_NAMES if 'all' in args.sequence else args.sequence:
        def progress(index: int, total: int, name: str = name) -> None:
            if not args.quiet and (index + 1 == total or (index + 1) % 30 == 0):
                print(f'evaluate: {name} frame {index + 1}/{total}', file=sys.stderr,
                      flush=True)

        sequence = SceneSequence(name, seed=args.seed, odometry=PERFECT_ODOMETRY
                                 if args.exact_odometry else OdometryModel())
        reports.append(video.evaluate_sequence(
            sequence, params, fusion, stop=args.frames, use_odometry=not args.no_odometry,
            sheet_frames=args.sheet_frames if args.sheet is not None else 0,
            on_frame=progress))
    out = sys.stderr if args.json == '-' else sys.stdout
    print(f'parameters: {_label(args)}; fusion: {fusion}', file=out)
    print(video.format_table(reports), file=out)
    if args.sheet is not None:
        from obstacle_detection.viz import pictures

        pictures.write_png(args.sheet, video.contact_sheet(reports, fusion))
        print(f'contact sheet: {args.sheet}', file=out)
    _write_json(args.json, {'fusion': fusion.__dict__,
                            'sequences': [r.as_dict() for r in reports]})
    return 0


def _label(args: Any) -> str:
    return args.preset + ''.join(f' + {path}' for path in args.params_file)


def _write_json(path: str | None, data: dict) -> None:
    """Print ``data`` as the last line of stdout, or write it to ``path`` ('-': print)."""
    line = json.dumps(data, sort_keys=True)
    if path in (None, '-'):
        print(line)
    else:
        Path(path).write_text(line + '\n', encoding='utf-8')


def false_alarm_causes(frame: evaluation.LabelledFrame, result: Any,
                       base: DetectorParams) -> Counter:
    """Count the false-alarm cells of one frame by what marked them (docs/accuracy.md).

    A voxel more than a step above its local ground (``high``), below the step down (``low``),
    a ``ledge`` or a ``drop`` edge; with the truth of its pixels: obstacle ``O``, traversable
    ``F``, no return ``X``; `` far``: no true obstacle within one cell.
    """
    from obstacle_detection.evaluation.metrics import grow_cells
    from obstacle_detection.pipeline import traversal
    from obstacle_detection.pipeline.normals import slope_obstacles

    params = frame.params(base)
    truth = evaluation.truth_costmap(frame, params)
    steep = slope_obstacles(result.voxel_normals, params.cos_max_slope)
    trav = traversal.traversable_ground(result.voxel_points, steep, params)
    kind = np.where(trav.ledge & ~trav.is_obstacle, 'ledge',
                    np.where(result.voxel_height_m < -params.max_step_down_m, 'low', 'high'))
    pixel_voxel, labels = result.pixel_voxel.reshape(-1), frame.truth_labels.reshape(-1)
    tags = np.full(kind.shape, '', object)
    for tag, label in (('O', GT_OBSTACLE), ('F', GT_TRAVERSABLE), ('X', GT_NO_RETURN)):
        has = np.zeros(kind.shape, bool)
        has[pixel_voxel[(pixel_voxel >= 0) & (labels == label)]] = True
        tags[has] += tag
    alarm = (result.costmap.data == CELL_OCCUPIED) & (truth == CELL_FREE)
    near = grow_cells(truth == CELL_OCCUPIED, 1)
    marked = result.voxel_is_obstacle
    causes: dict[tuple[int, int], set] = {}
    for points, names in ((result.voxel_points[marked],
                           [f'{k}/{t}' for k, t in zip(kind[marked], tags[marked])]),
                          (result.drop_points, ['drop'] * result.drop_points.shape[0])):
        row, col, inside = result.costmap.cell_of(points)
        for r, c, ok, name in zip(row, col, inside, names):
            if ok and alarm[r, c]:
                causes.setdefault((r, c), set()).add(name)
    return Counter('+'.join(sorted(names)) + ('' if near[cell] else ' far')
                   for cell, names in causes.items())


def _score_real_frames(folder: Path, params: DetectorParams) -> int:
    """Print per real frame the floor pixels marked (lower is better), standing ones marked."""
    from obstacle_detection.evaluation.datasets import read_depth_png
    from obstacle_detection.pipeline.depth import decode_depth

    totals = np.zeros(4, np.int64)
    for name, files, scale, intrinsics in REAL_FRAMES:
        for file in files:
            path = folder / name / file
            try:
                depth = decode_depth(read_depth_png(path), depth_scale=scale)
                *counts, mount = real_frame_counts(depth, intrinsics, params)
            except (OSError, ValueError) as exc:   # named with its path
                raise tool_support.ToolError(
                    str(exc) if str(path) in str(exc) else f'{path}: {exc}') from None
            totals += counts
            print(f'{name}/{file}: floor marked {counts[1]}/{counts[0]} '
                  f'({100.0 * counts[1] / max(counts[0], 1):.2f} %), standing marked '
                  f'{counts[3]}/{counts[2]} ({100.0 * counts[3] / max(counts[2], 1):.1f} %)'
                  f'  [{mount}]')
    print(f'total: floor marked {100.0 * totals[1] / max(totals[0], 1):.2f} % of '
          f'{totals[0]} px, standing marked {100.0 * totals[3] / max(totals[2], 1):.1f} % of '
          f'{totals[2]} px')
    return 0


def real_frame_counts(depth_m: np.ndarray, intrinsics: Intrinsics, params: DetectorParams,
                      ) -> tuple[int, int, int, int, str]:
    """Return (floor, floor marked, standing, standing marked, mount text) of one frame.

    The mount is fitted to the floor; only pixels inside the region of interest count.
    """
    from obstacle_detection.pipeline import geometry
    from obstacle_detection.pipeline.detector import Detector
    from obstacle_detection.pipeline.mount import estimate_mount

    est = estimate_mount(depth_m, intrinsics)
    p = params.replace(camera_height_m=est.height_m, camera_pitch_rad=est.pitch_rad,
                       camera_roll_rad=est.roll_rad)
    result = Detector(p).process(depth_m, intrinsics)
    rays = geometry.ground_rays(depth_m.shape, intrinsics, p)
    d = depth_m.reshape(-1)
    x, y = d * rays[0], d * rays[1]
    z = d * rays[2] + np.float32(p.camera_height_m)
    inside = (d > 0) & (x >= p.min_range_m) & (x <= p.max_range_m) & (
        np.abs(y) <= p.lateral_limit_m)
    marked = result.labels.reshape(-1) == LABEL_OBSTACLE
    on_floor = inside & (np.abs(z) <= FLOOR_BAND_M)
    standing = inside & (z >= STANDING_M) & (z <= p.robot_height_m)
    mount = (f'h {est.height_m:.2f} m, pitch {est.pitch_deg:.1f} deg, '
             f'roll {est.roll_deg:.1f} deg; {result.floor.summary()}')
    return (int(on_floor.sum()), int((on_floor & marked).sum()), int(standing.sum()),
            int((standing & marked).sum()), mount)


def _picture_writer(folder: Path, base: DetectorParams) -> Any:
    from obstacle_detection.viz import pictures

    def on_frame(frame: evaluation.LabelledFrame, result: Any,
                 score: evaluation.FrameScore) -> None:
        name = f'{frame.scenario}_{frame.frame_id}'.replace(' ', '_').replace('/', '_')
        caption = (f'{frame.scenario} {frame.frame_id}: cell F1 '
                   f'{evaluation.format_score(score.cell.f1)}, pixel F1 '
                   f'{evaluation.format_score(score.pixel.f1)}')
        pictures.write_png(folder / f'{name}.png', pictures.side_by_side(
            result, frame.params(base), caption=caption, truth_labels=frame.truth_labels))
    return on_frame


if __name__ == '__main__':
    sys.exit(main())
