#!/usr/bin/env python3
"""Parameter sweep: score a grid of settings on the scenario suite and draw it as a heatmap.

The seed chose theta, N, N1 and K "by trial" (figures 4.18 and 4.19 show three values each);
this tool makes the trial a command. Choose one or two axes, every other parameter stays at
the preset (plus ``--params-file`` / ``--set``)::

    python tools/sweep.py --x theta_deg=15,20,30,45 --y N=3,5,10,20
    python tools/sweep.py --x N1=0,4,8,12 --y K=1,5,9,17 --metric pixel_f1 --out n1_k.png
    python tools/sweep.py --x voxel_m=0.015,0.025,0.04 --scene corridor --strip x
    python tools/sweep.py --x theta_deg=20,30,45 --y N=5,10 --also N1=0,7,12 --also K=7,17

``--also`` makes a full small grid over more parameters: the grid shown is the best over
them, and the best setting per scenario names every parameter.

Axis names: any DetectorParams field, a ``..._deg`` variant of a ``..._rad`` field, the seed's
names theta_deg, N, N1, K, TDBG, SMAR, and voxel_m (all three voxel sizes). The grid of the
chosen metric is printed (overall, and per scenario with ``--per-scene``), the best setting per
scenario is named, and a PNG heatmap per scenario plus overall is saved (``--out``).
Frames are subsampled (``--max-frames``, default 1 per scenario) and rendered once.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline.params import DetectorParams
from obstacle_detection.cli.evaluation_args import (add_common_arguments, base_params,
                                                   frame_sources, report_error)

#: metric name -> (confusion kind, score attribute, higher is better)
METRICS: dict[str, tuple[str, str, bool]] = {
    'cell_f1': ('cell', 'f1', True),
    'cell_iou': ('cell', 'iou', True),
    'cell_precision': ('cell', 'precision', True),
    'cell_recall': ('cell', 'recall', True),
    'cell_false_alarm': ('cell', 'false_alarm_rate', False),
    'pixel_f1': ('pixel', 'f1', True),
    'pixel_precision': ('pixel', 'precision', True),
    'pixel_recall': ('pixel', 'recall', True),
    'pixel_false_alarm': ('pixel', 'false_alarm_rate', False),
}


@dataclass(frozen=True)
class Axis:
    """One sweep axis: a parameter name (as typed) and its values (as typed)."""

    name: str
    values: tuple[str, ...]


def parse_axis(text: str) -> Axis:
    """``name=v1,v2,...`` -> Axis (argparse type)."""
    name, sep, values = text.partition('=')
    items = tuple(v.strip() for v in values.split(',') if v.strip())
    if not sep or not name.strip() or not items:
        raise argparse.ArgumentTypeError(f'expected name=v1,v2,..., got {text!r}')
    for value in items:
        try:
            float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f'{name}: {value!r} is not a number') from None
    return Axis(name.strip(), items)


def best_of_grid(scores: np.ndarray, *, higher_is_better: bool = True,
                 ) -> tuple[int, ...] | None:
    """Index of the best finite score of a grid (2-D: (row, col)).

    Ties go to the first in row-major order; None when no score is finite.
    """
    grid = np.asarray(scores, dtype=np.float64)
    if grid.ndim < 1:
        raise ValueError(f'scores must be a grid, got shape {grid.shape}')
    finite = np.isfinite(grid)
    if not finite.any():
        return None
    fill = -np.inf if higher_is_better else np.inf
    masked = np.where(finite, grid, fill)
    flat = int(np.argmax(masked) if higher_is_better else np.argmin(masked))
    return tuple(int(i) for i in np.unravel_index(flat, grid.shape))


def project(scores: np.ndarray, *, higher_is_better: bool = True) -> np.ndarray:
    """(ny, nx): the best score over the axes after the first two (NaN where all are NaN)."""
    grid = np.asarray(scores, dtype=np.float64)
    if grid.ndim == 2:
        return grid
    flat = grid.reshape(grid.shape[0], grid.shape[1], -1)
    fill = -np.inf if higher_is_better else np.inf
    masked = np.where(np.isfinite(flat), flat, fill)
    best = masked.max(axis=2) if higher_is_better else masked.min(axis=2)
    return np.where(np.isfinite(best), best, np.nan)


@dataclass
class SweepResult:
    """Scores of every setting: ``grids[scene]`` (ny, nx, *extra) float, NaN = invalid setting.

    Axis order: rows = y (one row when there is no y axis), columns = x, then the ``also``
    axes of a full grid. false_alarms[scene]: the false-alarm rate of the metric's kind (pixel
    or cell) per setting; positives[scene]: obstacle pixels/cells in the truth. A scene without
    any (an empty floor) has no meaningful F1 or recall, so it is ranked by its false-alarm rate.
    """

    x: Axis
    y: Axis | None
    metric: str
    grids: dict[str, np.ndarray]
    false_alarms: dict[str, np.ndarray] = field(default_factory=dict)
    positives: dict[str, int] = field(default_factory=dict)
    also: tuple[Axis, ...] = ()

    @property
    def shape(self) -> tuple[int, ...]:
        """Grid shape (ny, nx, *extra)."""
        return grid_shape(self.x, self.y, self.also)

    def ranking(self, scene: str) -> tuple[np.ndarray, str, bool]:
        """(grid, metric name, higher is better) used to rank the settings of one scene."""
        kind, attr, higher = METRICS[self.metric]
        if self.positives.get(scene, 1) == 0 and attr != 'false_alarm_rate':
            return self.false_alarms[scene], f'{kind}_false_alarm', False
        return self.grids[scene], self.metric, higher

    def setting(self, *index: int) -> dict[str, str]:
        """Return the parameter values of grid cell ``index`` = (row, col, *extra)."""
        return setting_of(self.x, self.y, self.also, tuple(index))

    def best(self, scene: str) -> tuple[int, ...] | None:
        """Index (row, col, *extra) of the best setting of one scene ('overall' included)."""
        grid, _, higher = self.ranking(scene)
        return best_of_grid(grid, higher_is_better=higher)


def grid_shape(x: Axis, y: Axis | None, also: Sequence[Axis] = ()) -> tuple[int, ...]:
    """(ny, nx, *extra) of a sweep; ny = 1 without a y axis."""
    return (len(y.values) if y is not None else 1, len(x.values),
            *(len(a.values) for a in also))


def setting_of(x: Axis, y: Axis | None, also: Sequence[Axis], index: tuple[int, ...],
               ) -> dict[str, str]:
    """``{name: value}`` of grid cell ``index`` = (row, col, *extra)."""
    out = {x.name: x.values[index[1]]}
    if y is not None:
        out[y.name] = y.values[index[0]]
    for axis, k in zip(also, index[2:]):
        out[axis.name] = axis.values[k]
    return out


def settings_params(base: DetectorParams, x: Axis, y: Axis | None, *index: int,
                    also: Sequence[Axis] = ()) -> DetectorParams:
    """Return ``base`` with grid cell ``index``'s setting applied (ValueError when invalid)."""
    return evaluation.apply_overrides(base, setting_of(x, y, also, tuple(index)))


def run_sweep(frames: Sequence[evaluation.LabelledFrame], base: DetectorParams, x: Axis,
              y: Axis | None, metric: str = 'cell_f1', *, also: Sequence[Axis] = (),
              log: Any = None) -> SweepResult:
    """Evaluate every setting of the grid on ``frames`` (already rendered)."""
    if metric not in METRICS:
        raise ValueError(f'unknown metric {metric!r}; known: {", ".join(METRICS)}')
    kind, attr, _ = METRICS[metric]
    also = tuple(also)
    names = [x.name] + ([y.name] if y is not None else []) + [a.name for a in also]
    if len(set(names)) != len(names):
        raise ValueError(f'an axis is given twice: {", ".join(names)}')
    shape = grid_shape(x, y, also)
    total = int(np.prod(shape))
    scenes = list(dict.fromkeys(f.scenario for f in frames)) + ['overall']
    grids = {s: np.full(shape, np.nan) for s in scenes}
    false_alarms = {s: np.full(shape, np.nan) for s in scenes}
    positives: dict[str, int] = {}
    for i, index in enumerate(np.ndindex(*shape), start=1):
        label = ' '.join(f'{k}={v}' for k, v in setting_of(x, y, also, index).items())
        started = time.perf_counter()
        try:
            params = settings_params(base, x, y, *index, also=also)
        except ValueError as exc:
            if log:
                log(f'[{i}/{total}] {label}: invalid ({exc})')
            continue
        report = evaluation.evaluate_frames(frames, params)
        for name, summary in [*report.scenes.items(), ('overall', report.overall)]:
            confusion = getattr(summary, kind)
            grids[name][index] = getattr(confusion, attr)
            false_alarms[name][index] = confusion.false_alarm_rate
            positives[name] = confusion.tp + confusion.fn
        if log:
            log(f'[{i}/{total}] {label}: {metric} '
                f'{evaluation.format_score(grids["overall"][index])} '
                f'({time.perf_counter() - started:.1f} s)')
    return SweepResult(x, y, metric, grids, false_alarms, positives, also)


def format_grid(result: SweepResult, scene: str) -> str:
    """Return the grid of one scene as text: rows = y values, columns = x values; best marked '*'.

    With ``also`` axes each cell shows the best score over them.
    """
    grid, metric, higher = result.ranking(scene)
    flat = project(grid, higher_is_better=higher)
    best = result.best(scene)
    y_name = result.y.name if result.y is not None else ''
    y_values = result.y.values if result.y is not None else ('',)
    width = max(8, *(len(v) + 2 for v in result.x.values))
    first = max(len(y_name), *(len(v) for v in y_values), len(result.x.name) + 3) + 1
    title = f'{scene}: {metric}'
    if result.also:
        title += f' (best over {", ".join(a.name for a in result.also)})'
    lines = [title,
             f'{y_name + " / " + result.x.name if y_name else result.x.name:<{first}}'
             + ''.join(f'{v:>{width}}' for v in result.x.values)]
    for row, y_value in enumerate(y_values):
        cells = []
        for col in range(len(result.x.values)):
            mark = '*' if best is not None and best[:2] == (row, col) else ' '
            cells.append(f'{evaluation.format_score(flat[row, col]) + mark:>{width}}')
        lines.append(f'{y_value:<{first}}' + ''.join(cells))
    return '\n'.join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog='sweep.py', description=__doc__.split('\n\n')[0],
                                     epilog=evaluation.SCORE_DEFINITIONS,
                                     formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument('--x', type=parse_axis, required=True, metavar='NAME=V1,V2,...',
                        help='first axis (columns), e.g. theta_deg=15,20,30,45')
    parser.add_argument('--y', type=parse_axis, metavar='NAME=V1,V2,...',
                        help='second axis (rows), e.g. N=3,5,10,20 [default: none]')
    parser.add_argument('--also', type=parse_axis, action='append', default=[],
                        metavar='NAME=V1,V2,...',
                        help='more axes for a full grid (repeatable); the printed grid and '
                             'the heatmap show the best over them, the best settings name them')
    parser.add_argument('--metric', choices=sorted(METRICS), default='cell_f1',
                        help='score to grid and maximise (false alarms: minimise) '
                             '[default: cell_f1]')
    add_common_arguments(parser)
    parser.set_defaults(max_frames=1)
    parser.add_argument('--per-scene', action='store_true',
                        help='print the grid of every scenario, not only the overall one')
    parser.add_argument('--out', type=Path, default=Path('sweep.png'),
                        help='heatmap PNG (one panel per scenario + overall) '
                             '[default: sweep.png]')
    parser.add_argument('--strip', choices=('x', 'y'),
                        help='also save a strip of overlays of the first frame, one per value '
                             'of this axis (the other axis at its overall best)')
    parser.add_argument('--strip-out', type=Path, default=Path('sweep_strip.png'),
                        help='strip PNG [default: sweep_strip.png]')
    parser.add_argument('--json', type=Path, metavar='FILE', help='also write the grids as JSON')
    return parser


def _log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    if args.strip == 'y' and args.y is None:
        print('sweep.py: error: --strip y needs --y', file=sys.stderr)
        return 2
    also = tuple(args.also)
    try:
        base = base_params(args)
        for axis in (args.x, args.y, *also):  # an unknown axis name fails now, not per cell
            if axis is not None:
                try:
                    evaluation.apply_overrides(base, {axis.name: axis.values[0]})
                except ValueError as exc:
                    if 'unknown parameter' in str(exc):
                        raise
        started = time.perf_counter()
        frames = [f for _, _, source in frame_sources(args) for f in source]
        if not frames:
            raise ValueError('no frames selected')
        _log(f'rendered {len(frames)} frames in {time.perf_counter() - started:.1f} s; '
             f'{int(np.prod(grid_shape(args.x, args.y, also)))} settings')
        result = run_sweep(frames, base, args.x, args.y, args.metric, also=also, log=_log)
    except (ValueError, OSError) as exc:
        return report_error('sweep.py', exc)

    scenes = list(result.grids)
    shown = scenes if args.per_scene else ['overall']
    print(f'parameters: {args.preset}; {len(frames)} frames; '
          f'{"higher" if METRICS[args.metric][2] else "lower"} is better; * = best')
    for scene in shown:
        print(format_grid(result, scene))
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

    try:
        _write_heatmaps(args, result)
        print(f'heatmap: {args.out}')
        if args.strip:
            _write_strip(args, base, frames[0], result)
            print(f'strip: {args.strip_out}')
        if args.json:
            data = {'metric': args.metric, 'preset': args.preset, 'frames': len(frames),
                    'axes': ['y', 'x'] + [f'also[{i}]' for i in range(len(also))],
                    'x': {'name': args.x.name, 'values': list(args.x.values)},
                    'y': ({'name': args.y.name, 'values': list(args.y.values)}
                          if args.y else None),
                    'also': [{'name': a.name, 'values': list(a.values)} for a in also],
                    'grids': {s: np.where(np.isnan(g), None, g).tolist()
                              for s, g in result.grids.items()},
                    'best': {s: result.setting(*b) if (b := result.best(s)) else None
                             for s in scenes}}
            args.json.write_text(json.dumps(data) + '\n', encoding='utf-8')
    except (ValueError, OSError) as exc:
        return report_error('sweep.py', exc)
    return 0


def _write_heatmaps(args: argparse.Namespace, result: SweepResult) -> None:
    """One heatmap panel per scenario and overall, tiled into ``args.out``."""
    from obstacle_detection.viz import pictures

    panels = []
    for scene in result.grids:
        grid, metric, higher = result.ranking(scene)
        flat = project(grid, higher_is_better=higher)
        best = result.best(scene)
        title = f'{scene}: {metric}' + ('' if higher else ' (colour: 1 - value)')
        if result.also:
            title += ' (best over ' + ', '.join(a.name for a in result.also) + ')'
        panels.append(pictures.heatmap(
            flat if higher else 1.0 - flat, list(args.x.values),
            list(args.y.values) if args.y else [''], title=title, x_name=args.x.name,
            y_name=args.y.name if args.y else '', best=best[:2] if best else None,
            values=flat))
    pictures.write_png(args.out, pictures.tile(panels, columns=3))


def _write_strip(args: argparse.Namespace, base: DetectorParams,
                 frame: evaluation.LabelledFrame, result: SweepResult) -> None:
    """Overlays of one frame for each value of the strip axis, the others at the best."""
    from obstacle_detection.viz import pictures
    from obstacle_detection.pipeline.detector import Detector

    best = result.best('overall') or (0,) * len(result.shape)
    images, labels = [], []
    along_x = args.strip == 'x'
    count = len(args.x.values) if along_x else len(args.y.values)
    for i in range(count):
        index = list(best)
        index[1 if along_x else 0] = i
        setting = ', '.join(f'{k}={v}' for k, v in result.setting(*index).items())
        try:
            params = frame.params(settings_params(base, args.x, args.y, *index,
                                                  also=result.also))
        except ValueError:
            continue
        detection = Detector(params).process(frame.depth, frame.intrinsics,
                                             depth_scale=frame.depth_scale)
        pixel, cell = evaluation.score_frame(frame, detection, params)
        images.append(pictures.side_by_side(detection, caption=f'{frame.scenario} '
                                            f'{frame.frame_id}: {setting}', params=params))
        labels.append(f'{setting}: cell F1 {evaluation.format_score(cell.f1)}, '
                      f'pixel F1 {evaluation.format_score(pixel.f1)}')
    if not images:
        raise ValueError('no valid setting along the strip axis')
    pictures.write_png(args.strip_out, pictures.contact_sheet(
        images, labels=labels, columns=len(images), thumb_width=420))


if __name__ == '__main__':
    sys.exit(main())
