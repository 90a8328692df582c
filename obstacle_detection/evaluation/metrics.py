"""Accuracy against ground truth: pixel and costmap-cell confusion counts (plain numpy).

What counts is stated in ``runner.SCORE_DEFINITIONS`` and docs/accuracy.md.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from obstacle_detection.labels import (CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN, GT_ABOVE_ROBOT,
                                       GT_NO_RETURN, GT_OBSTACLE, GT_TRAVERSABLE, LABEL_GROUND,
                                       LABEL_OBSTACLE)



def _ratio(num: int, den: int) -> float:
    return num / den if den > 0 else math.nan


@dataclass(frozen=True)
class Confusion:
    """Binary confusion counts, obstacle = positive. Add two with ``+`` to pool frames."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    def __post_init__(self) -> None:
        for name in ('tp', 'fp', 'fn', 'tn'):
            value = getattr(self, name)
            if value < 0:
                raise ValueError(f'confusion count {name}={value!r} must be >= 0')

    def __add__(self, other: 'Confusion') -> 'Confusion':
        return Confusion(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn,
                         self.tn + other.tn)

    @property
    def total(self) -> int:
        """Number of evaluated samples."""
        return self.tp + self.fp + self.fn + self.tn

    @property
    def precision(self) -> float:
        """Precision tp / (tp + fp); NaN when nothing was predicted positive."""
        return _ratio(self.tp, self.tp + self.fp)

    @property
    def recall(self) -> float:
        """Recall tp / (tp + fn); NaN when the truth has no positive."""
        return _ratio(self.tp, self.tp + self.fn)

    @property
    def f1(self) -> float:
        """F1 score 2 tp / (2 tp + fp + fn); NaN without any positive or prediction."""
        return _ratio(2 * self.tp, 2 * self.tp + self.fp + self.fn)

    @property
    def iou(self) -> float:
        """IoU tp / (tp + fp + fn), the Jaccard index of the positive class."""
        return _ratio(self.tp, self.tp + self.fp + self.fn)

    @property
    def false_alarm_rate(self) -> float:
        """False-alarm rate fp / (fp + tn): the share of true negatives predicted positive."""
        return _ratio(self.fp, self.fp + self.tn)

    @property
    def accuracy(self) -> float:
        """(tp + tn) / total."""
        return _ratio(self.tp + self.tn, self.total)

    def scores(self) -> dict[str, float]:
        """All ratios by name (precision, recall, f1, iou, false_alarm_rate, accuracy)."""
        return {'precision': self.precision, 'recall': self.recall, 'f1': self.f1,
                'iou': self.iou, 'false_alarm_rate': self.false_alarm_rate,
                'accuracy': self.accuracy}

    def as_dict(self) -> dict[str, float]:
        """Return counts and scores in one flat dict (JSON-ready; NaN stays NaN)."""
        return {'tp': self.tp, 'fp': self.fp, 'fn': self.fn, 'tn': self.tn, **self.scores()}


def confusion(predicted: np.ndarray, truth: np.ndarray,
              evaluated: np.ndarray | None = None) -> Confusion:
    """Confusion counts of two bool arrays of one shape over ``evaluated`` (None = all)."""
    predicted = np.asarray(predicted, dtype=bool)
    truth = np.asarray(truth, dtype=bool)
    if predicted.shape != truth.shape:
        raise ValueError(
            f'predicted shape {predicted.shape} differs from truth shape {truth.shape}')
    if evaluated is not None:
        evaluated = np.asarray(evaluated, dtype=bool)
        if evaluated.shape != truth.shape:
            raise ValueError(
                f'evaluated mask shape {evaluated.shape} differs from truth shape {truth.shape}')
        predicted = predicted[evaluated]
        truth = truth[evaluated]
    tp = int(np.count_nonzero(predicted & truth))
    fp = int(np.count_nonzero(predicted & ~truth))
    fn = int(np.count_nonzero(~predicted & truth))
    tn = int(predicted.size - tp - fp - fn)
    return Confusion(tp, fp, fn, tn)


def pixel_evaluated(pipeline_labels: np.ndarray, truth_labels: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels the pixel-level scores count (truth saw a surface, pipeline called)."""
    pipeline_labels = np.asarray(pipeline_labels)
    truth_labels = np.asarray(truth_labels)
    if pipeline_labels.shape != truth_labels.shape:
        raise ValueError(f'pipeline labels shape {pipeline_labels.shape} differs from truth '
                         f'labels shape {truth_labels.shape}')
    called = (pipeline_labels == LABEL_GROUND) | (pipeline_labels == LABEL_OBSTACLE)
    return called & (truth_labels != GT_NO_RETURN)


def pixel_confusion(pipeline_labels: np.ndarray, truth_labels: np.ndarray) -> Confusion:
    """Pixel confusion of obstacle pixels: pipeline ``LABEL_*`` against truth ``GT_*``."""
    evaluated = pixel_evaluated(pipeline_labels, truth_labels)
    return confusion(np.asarray(pipeline_labels) == LABEL_OBSTACLE,
                     np.asarray(truth_labels) == GT_OBSTACLE, evaluated)


def cell_confusion(predicted_grid: np.ndarray, truth_grid: np.ndarray) -> Confusion:
    """Costmap-cell confusion of two ``CELL_*`` grids; unknown truth cells are skipped."""
    predicted_grid = np.asarray(predicted_grid)
    truth_grid = np.asarray(truth_grid)
    if predicted_grid.shape != truth_grid.shape:
        raise ValueError(f'predicted grid shape {predicted_grid.shape} differs from truth grid '
                         f'shape {truth_grid.shape}')
    return confusion(predicted_grid == CELL_OCCUPIED, truth_grid == CELL_OCCUPIED,
                     truth_grid != CELL_UNKNOWN)


def truth_points(points_ground: np.ndarray, truth_labels: np.ndarray, roi: np.ndarray,
                 marked: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Split true points (H, W, 3) into (obstacle (O, 3), traversable (T, 3)) float32 [m].

    Only finite points in ``roi``; ``GT_ABOVE_ROBOT`` counts as traversable; ``marked`` pixels
    (a drop's edge) count as obstacles whatever their label.
    """
    flat = np.asarray(points_ground, dtype=np.float32).reshape(-1, 3)
    labels = np.asarray(truth_labels).reshape(-1)
    keep = np.asarray(roi, dtype=bool).reshape(-1) & np.isfinite(flat).all(axis=1)
    is_obstacle = labels == GT_OBSTACLE
    if marked is not None:
        is_obstacle = is_obstacle | (np.asarray(marked, dtype=bool).reshape(-1)
                                     & (labels != GT_NO_RETURN))
    obstacle = flat[keep & is_obstacle]
    traversable = flat[keep & ~is_obstacle
                       & ((labels == GT_TRAVERSABLE) | (labels == GT_ABOVE_ROBOT))]
    return obstacle, traversable


def truth_grid(obstacle_points: np.ndarray, traversable_points: np.ndarray,
               origin_xy_m: tuple[float, float], resolution_m: float, shape: tuple[int, int],
               ) -> np.ndarray:
    """Rasterise true points into a (ny, nx) int8 ``CELL_*`` grid, binned as the costmap."""
    if resolution_m <= 0.0 or not math.isfinite(resolution_m):
        raise ValueError(f'resolution_m={resolution_m!r} must be a positive number')
    ny, nx = shape
    grid = np.full((ny, nx), CELL_UNKNOWN, dtype=np.int8)
    for points, value in ((traversable_points, CELL_FREE), (obstacle_points, CELL_OCCUPIED)):
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        ix = np.floor((points[:, 0] - origin_xy_m[0]) / resolution_m)
        iy = np.floor((points[:, 1] - origin_xy_m[1]) / resolution_m)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        grid[iy[inside].astype(np.intp), ix[inside].astype(np.intp)] = value
    return grid


def format_score(value: float, digits: int = 3) -> str:
    """Return a ratio as text, '-' when not defined (NaN)."""
    return '-' if value is None or math.isnan(value) else f'{value:.{digits}f}'


def point_cells(points: np.ndarray, origin_xy_m: tuple[float, float], resolution_m: float,
                shape: tuple[int, int]) -> np.ndarray:
    """(ny, nx) bool: the grid cells that points (M, 3) or (M, 2) [m] fall in."""
    if resolution_m <= 0.0 or not math.isfinite(resolution_m):
        raise ValueError(f'resolution_m={resolution_m!r} must be a positive number')
    ny, nx = shape
    cells = np.zeros((ny, nx), dtype=bool)
    points = np.asarray(points, dtype=np.float64)
    points = points.reshape(-1, points.shape[-1] if points.ndim > 1 else 3)
    ix = np.floor((points[:, 0] - origin_xy_m[0]) / resolution_m)
    iy = np.floor((points[:, 1] - origin_xy_m[1]) / resolution_m)
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    cells[iy[inside].astype(np.intp), ix[inside].astype(np.intp)] = True
    return cells


def occupied_share(predicted_grid: np.ndarray, cells: np.ndarray, *,
                   tolerance_cells: int = 0) -> tuple[int, int]:
    """(cells marked, cells): how many are occupied, within ``tolerance_cells`` (Chebyshev)."""
    occupied = np.asarray(predicted_grid) == CELL_OCCUPIED
    cells = np.asarray(cells, dtype=bool)
    if occupied.shape != cells.shape:
        raise ValueError(f'grid shape {occupied.shape} differs from cells shape {cells.shape}')
    if tolerance_cells > 0:
        k = int(tolerance_cells)
        padded = np.pad(occupied, k)
        grown = np.zeros_like(occupied)
        ny, nx = occupied.shape
        for dy in range(2 * k + 1):
            for dx in range(2 * k + 1):
                grown |= padded[dy:dy + ny, dx:dx + nx]
        occupied = grown
    return int(np.count_nonzero(occupied & cells)), int(np.count_nonzero(cells))


def grow_cells(mask: np.ndarray, cells: int) -> np.ndarray:
    """(ny, nx) bool: the cells within ``cells`` cells (Chebyshev distance) of a True cell."""
    mask = np.asarray(mask, dtype=bool)
    if cells <= 0:
        return mask.copy()
    k = int(cells)
    padded = np.pad(mask, k)
    grown = np.zeros_like(mask)
    ny, nx = mask.shape
    for dy in range(2 * k + 1):
        for dx in range(2 * k + 1):
            grown |= padded[dy:dy + ny, dx:dx + nx]
    return grown


@dataclass(frozen=True)
class TolerantCells:
    """Costmap-cell counts with a tolerance of ``cells`` cells (issue 22); add to pool frames."""

    hit_truth: int = 0
    truth: int = 0
    hit_marked: int = 0
    marked: int = 0
    far_alarms: int = 0
    free: int = 0

    def __add__(self, other: 'TolerantCells') -> 'TolerantCells':
        return TolerantCells(*(a + b for a, b in zip(dataclasses.astuple(self),
                                                     dataclasses.astuple(other))))

    @property
    def recall(self) -> float:
        """Share of the occupied truth cells found within the tolerance."""
        return _ratio(self.hit_truth, self.truth)

    @property
    def precision(self) -> float:
        """Share of the marked cells with a true obstacle within the tolerance."""
        return _ratio(self.hit_marked, self.marked)

    @property
    def f1(self) -> float:
        """Harmonic mean of the tolerant precision and recall (NaN when undefined)."""
        p, r = self.precision, self.recall
        return 2 * p * r / (p + r) if p + r > 0 else math.nan

    @property
    def far_alarm_rate(self) -> float:
        """Share of the free truth cells marked with no true obstacle within the tolerance."""
        return _ratio(self.far_alarms, self.free)


def tolerant_cells(predicted_grid: np.ndarray, truth_grid: np.ndarray, *,
                   cells: int = 1) -> TolerantCells:
    """Cell counts where a mark within ``cells`` cells of a true obstacle counts (and back)."""
    predicted = np.asarray(predicted_grid) == CELL_OCCUPIED
    truth_grid = np.asarray(truth_grid)
    if predicted.shape != truth_grid.shape:
        raise ValueError(f'predicted grid shape {predicted.shape} differs from truth grid '
                         f'shape {truth_grid.shape}')
    occupied = truth_grid == CELL_OCCUPIED
    free = truth_grid == CELL_FREE
    scored = truth_grid != CELL_UNKNOWN
    near_truth = grow_cells(occupied, cells)
    marked = predicted & scored
    return TolerantCells(
        hit_truth=int(np.count_nonzero(occupied & grow_cells(predicted, cells))),
        truth=int(np.count_nonzero(occupied)),
        hit_marked=int(np.count_nonzero(marked & near_truth)),
        marked=int(np.count_nonzero(marked)),
        far_alarms=int(np.count_nonzero(predicted & free & ~near_truth)),
        free=int(np.count_nonzero(free)))


def free_share(predicted_grid: np.ndarray, cells: np.ndarray) -> tuple[int, int]:
    """(cells free, cells) of a set of cells: how many are ``CELL_FREE`` in the grid."""
    free = np.asarray(predicted_grid) == CELL_FREE
    cells = np.asarray(cells, dtype=bool)
    if free.shape != cells.shape:
        raise ValueError(f'grid shape {free.shape} differs from cells shape {cells.shape}')
    return int(np.count_nonzero(free & cells)), int(np.count_nonzero(cells))


def surface_gap_points(points_ground: np.ndarray, object_ids: np.ndarray, mask: np.ndarray,
                       *, step_m: float, max_gap_m: float) -> np.ndarray:
    """Points (M, 3) [m] filling gaps between neighbouring samples of one surface.

    Neighbour pixels in ``mask`` on the same object, more than ``step_m`` and at most
    ``max_gap_m`` apart, get the segment between them sampled ``step_m`` apart.
    """
    if not (0.0 < step_m <= max_gap_m and math.isfinite(max_gap_m)):
        raise ValueError(f'need 0 < step_m={step_m!r} <= max_gap_m={max_gap_m!r}')
    points = np.asarray(points_ground, dtype=np.float64)
    ids = np.asarray(object_ids)
    mask = np.asarray(mask, dtype=bool) & (ids >= 0)
    starts, ends = [], []
    for a, b in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                 ((slice(None, -1), slice(None)), (slice(1, None), slice(None)))):
        pair = mask[a] & mask[b] & (ids[a] == ids[b])
        pa, pb = points[a][pair], points[b][pair]
        with np.errstate(invalid='ignore'):
            gap = np.linalg.norm(pb - pa, axis=1)
        keep = (gap > step_m) & (gap <= max_gap_m)
        starts.append(pa[keep])
        ends.append(pb[keep])
    start, end = np.concatenate(starts), np.concatenate(ends)
    if start.shape[0] == 0:
        return np.zeros((0, 3))
    # count - 1 inner points per segment: spacing gap / count <= max_gap_m / count <= step_m
    count = int(math.ceil(max_gap_m / step_m))
    fractions = np.arange(1, count) / count
    dense = start[:, None, :] + fractions[None, :, None] * (end - start)[:, None, :]
    return dense.reshape(-1, 3)
