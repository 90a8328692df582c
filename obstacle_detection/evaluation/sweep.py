"""The parameter sweep's grid search: score every setting of a grid, pick the best, print it."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from . import runner as evaluation
from obstacle_detection.pipeline.params import DetectorParams

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
    """Index of the best finite score (first in row-major order), None when none is finite."""
    grid = np.asarray(scores, dtype=np.float64)
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
    """Scores of every setting: ``grids[scene]`` (ny, nx, *extra), NaN = invalid setting.

    A scene without obstacles in the truth (``positives``) is ranked by its false-alarm rate.
    """

    x: Axis
    y: Axis | None
    metric: str
    grids: dict[str, np.ndarray]
    false_alarms: dict[str, np.ndarray] = field(default_factory=dict)
    positives: dict[str, int] = field(default_factory=dict)
    also: tuple[Axis, ...] = ()

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

    def view(self, scene: str) -> tuple[np.ndarray, str, bool, str]:
        """(ny, nx) best over the extra axes, metric, higher is better, title of one scene."""
        grid, metric, higher = self.ranking(scene)
        title = f'{scene}: {metric}'
        if self.also:
            title += f' (best over {", ".join(a.name for a in self.also)})'
        return project(grid, higher_is_better=higher), metric, higher, title


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


def check_sweep(x: Axis, y: Axis | None, metric: str, also: Sequence[Axis] = ()) -> None:
    """Raise ValueError for an unknown metric or an axis given twice."""
    if metric not in METRICS:
        raise evaluation.EvaluationError(f'unknown metric {metric!r}; known: '
                                         f'{", ".join(METRICS)}', usage=True)
    names = [x.name] + ([y.name] if y is not None else []) + [a.name for a in also]
    if len(set(names)) != len(names):
        raise ValueError(f'an axis is given twice: {", ".join(names)}')


def sweep_points(base: DetectorParams, x: Axis, y: Axis | None, also: Sequence[Axis] = (),
                 ) -> list[tuple[tuple[int, ...], DetectorParams | ValueError]]:
    """Every grid cell in row-major order: (index, its parameters or why they are invalid)."""
    points: list[tuple[tuple[int, ...], DetectorParams | ValueError]] = []
    for index in np.ndindex(*grid_shape(x, y, also)):
        try:
            points.append((index, evaluation.apply_overrides(
                base, setting_of(x, y, also, tuple(index)))))
        except ValueError as exc:
            points.append((index, exc))
    return points


def empty_result(x: Axis, y: Axis | None, metric: str, scenes: Sequence[str],
                 also: Sequence[Axis] = ()) -> SweepResult:
    """Return a SweepResult of ``scenes`` (and 'overall'), every cell NaN until recorded."""
    shape = grid_shape(x, y, also)
    names = list(dict.fromkeys(scenes)) + ['overall']
    return SweepResult(x, y, metric, {s: np.full(shape, np.nan) for s in names},
                       {s: np.full(shape, np.nan) for s in names}, {}, tuple(also))


def record_report(result: SweepResult, index: tuple[int, ...],
                  report: evaluation.Report) -> None:
    """Enter one grid cell's evaluation into ``result`` (its metric per scene and overall)."""
    kind, attr, _ = METRICS[result.metric]
    for name, summary in [*report.scenes.items(), ('overall', report.overall)]:
        confusion = getattr(summary, kind)
        result.grids[name][index] = getattr(confusion, attr)
        result.false_alarms[name][index] = confusion.false_alarm_rate
        result.positives[name] = confusion.tp + confusion.fn


def point_label(result: SweepResult, index: tuple[int, ...]) -> str:
    """``theta_deg=30 N=5``: the setting of one grid cell, for log lines."""
    return ' '.join(f'{k}={v}' for k, v in result.setting(*index).items())


def run_sweep(frames: Sequence[evaluation.LabelledFrame], base: DetectorParams, x: Axis,
              y: Axis | None, metric: str = 'cell_f1', *, also: Sequence[Axis] = (),
              log: Any = None) -> SweepResult:
    """Evaluate every setting of the grid on ``frames`` (already rendered)."""
    also = tuple(also)
    check_sweep(x, y, metric, also)
    result = empty_result(x, y, metric, [f.scenario for f in frames], also)
    points = sweep_points(base, x, y, also)
    for i, (index, params) in enumerate(points, start=1):
        label = point_label(result, index)
        started = time.perf_counter()
        if isinstance(params, ValueError):
            if log:
                log(f'[{i}/{len(points)}] {label}: invalid ({params})')
            continue
        record_report(result, index, evaluation.evaluate_frames(frames, params))
        if log:
            log(f'[{i}/{len(points)}] {label}: {metric} '
                f'{evaluation.format_score(result.grids["overall"][index])} '
                f'({time.perf_counter() - started:.1f} s)')
    return result


def format_grid(result: SweepResult, scene: str) -> str:
    """Return the grid of one scene as text: rows = y, columns = x; best marked '*'."""
    flat, _, _, title = result.view(scene)
    best = result.best(scene)
    y_name = result.y.name if result.y is not None else ''
    y_values = result.y.values if result.y is not None else ('',)
    width = max(8, *(len(v) + 2 for v in result.x.values))
    first = max(len(y_name), *(len(v) for v in y_values), len(result.x.name) + 3) + 1
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
