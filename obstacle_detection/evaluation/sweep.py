"""The parameter sweep's grid search: score every setting of a grid, pick the best, print it."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from . import runner as evaluation
from obstacle_detection.pipeline.params import DetectorParams, frame_budget

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
    """Index of the best score, NaN aside (first in row-major order); None when all are NaN."""
    grid = np.asarray(scores, dtype=np.float64)
    if np.isnan(grid).all():
        return None
    flat = np.nanargmax(grid) if higher_is_better else np.nanargmin(grid)
    return tuple(int(i) for i in np.unravel_index(flat, grid.shape))


@dataclass
class SweepResult:
    """Scores of every setting: ``grids[scene]`` (ny, nx), NaN = invalid setting.

    A scene without obstacles in the truth (``positives``) is ranked by its false-alarm rate.
    """

    x: Axis
    y: Axis | None
    metric: str
    grids: dict[str, np.ndarray] = field(default_factory=dict)
    false_alarms: dict[str, np.ndarray] = field(default_factory=dict)
    positives: dict[str, int] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx); ny = 1 without a y axis."""
        return len(self.y.values) if self.y is not None else 1, len(self.x.values)

    def ranking(self, scene: str) -> tuple[np.ndarray, str, bool]:
        """(grid, metric name, higher is better) used to rank the settings of one scene."""
        kind, attr, higher = METRICS[self.metric]
        if self.positives.get(scene, 1) == 0 and attr != 'false_alarm_rate':
            return self.false_alarms[scene], f'{kind}_false_alarm', False
        return self.grids[scene], self.metric, higher

    def setting(self, row: int, col: int) -> dict[str, str]:
        """Return the parameter values of grid cell (row, col)."""
        out = {self.x.name: self.x.values[col]}
        if self.y is not None:
            out[self.y.name] = self.y.values[row]
        return out

    def best(self, scene: str) -> tuple[int, int] | None:
        """(row, col) of the best setting of one scene ('overall' included)."""
        grid, _, higher = self.ranking(scene)
        return best_of_grid(grid, higher_is_better=higher)


def grid_sweep(score: Callable[[list[DetectorParams]], list[list[evaluation.FrameScore]]],
               base: DetectorParams, x: Axis, y: Axis | None, metric: str = 'cell_f1', *,
               log: Callable[[str], None] = print) -> SweepResult:
    """Score every setting of the grid on ``base``: ``score(points)`` gives their frame scores.

    A value DetectorParams refuses, or a setting beyond a frame's budget, leaves its cell NaN;
    an unknown name raises (usage).
    """
    if y is not None and y.name == x.name:
        raise evaluation.EvaluationError(f'--x and --y both name {x.name!r}', usage=True)
    result = SweepResult(x, y, metric)

    def label(index: tuple[int, ...]) -> str:
        return ' '.join(f'{k}={v}' for k, v in result.setting(*index).items())

    points: dict[tuple[int, ...], DetectorParams] = {}
    for index in np.ndindex(*result.shape):
        try:
            point = evaluation.apply_overrides(base, result.setting(*index))
            problem = frame_budget(point).problem()   # docs/budget.md
            if problem is not None:
                raise ValueError(problem)
            points[index] = point
        except ValueError as exc:
            if getattr(exc, 'usage', False):
                raise
            log(f'{label(index)}: invalid ({exc})')
    if not points:
        raise ValueError('no valid setting in the grid')
    kind, attr, _ = METRICS[metric]
    for index, scores in zip(points, score(list(points.values()))):
        report = evaluation.pool_scores(scores, points[index])
        for name, summary in [*report.scenes.items(), ('overall', report.overall)]:
            confusion = getattr(summary, kind)
            for grids, value in ((result.grids, getattr(confusion, attr)),
                                 (result.false_alarms, confusion.false_alarm_rate)):
                grids.setdefault(name, np.full(result.shape, np.nan))[index] = value
            result.positives[name] = confusion.tp + confusion.fn
        log(f'{label(index)}: {metric} {evaluation.format_score(result.grids["overall"][index])}')
    return result


def format_grid(result: SweepResult, scene: str) -> str:
    """Return the grid of one scene as text: rows = y, columns = x; best marked '*'."""
    flat, metric, _ = result.ranking(scene)
    best = result.best(scene)
    y_name = result.y.name if result.y is not None else ''
    y_values = result.y.values if result.y is not None else ('',)
    width = max(8, *(len(v) + 2 for v in result.x.values))
    first = max(len(y_name), *(len(v) for v in y_values), len(result.x.name) + 3) + 1
    lines = [f'{scene}: {metric}',
             f'{y_name + " / " + result.x.name if y_name else result.x.name:<{first}}'
             + ''.join(f'{v:>{width}}' for v in result.x.values)]
    for row, y_value in enumerate(y_values):
        cells = []
        for col in range(len(result.x.values)):
            mark = '*' if best == (row, col) else ' '
            cells.append(f'{evaluation.format_score(flat[row, col]) + mark:>{width}}')
        lines.append(f'{y_value:<{first}}' + ''.join(cells))
    return '\n'.join(lines)
