"""Accuracy against ground truth: pixel and costmap-cell confusion counts (plain numpy).

What counts is stated in docs/accuracy.md ("What the scores count").
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
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

    def __add__(self, other: 'Confusion') -> 'Confusion':
        return Confusion(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn,
                         self.tn + other.tn)

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
        """F1 2 tp / (2 tp + fp + fn); NaN without any positive or prediction."""
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
        return _ratio(self.tp + self.tn, self.tp + self.fp + self.fn + self.tn)

    def as_dict(self) -> dict[str, float]:
        """Return the counts and every ratio in one flat dict (NaN stays NaN)."""
        return {**dataclasses.asdict(self), 'precision': self.precision, 'recall': self.recall,
                'f1': self.f1, 'iou': self.iou, 'false_alarm_rate': self.false_alarm_rate,
                'accuracy': self.accuracy}


def confusion(predicted: np.ndarray, truth: np.ndarray,
              evaluated: np.ndarray | None = None) -> Confusion:
    """Confusion counts of two bool arrays of one shape over ``evaluated`` (None = all)."""
    predicted = np.asarray(predicted, dtype=bool)
    truth = np.asarray(truth, dtype=bool)
    if evaluated is not None:
        predicted, truth = predicted[evaluated], truth[evaluated]
    tp = int(np.count_nonzero(predicted & truth))
    fp = int(np.count_nonzero(predicted & ~truth))
    fn = int(np.count_nonzero(~predicted & truth))
    return Confusion(tp, fp, fn, int(predicted.size - tp - fp - fn))


def pixel_confusion(pipeline_labels: np.ndarray, truth_labels: np.ndarray) -> Confusion:
    """Obstacle pixels, pipeline ``LABEL_*`` against truth ``GT_*``.

    Counted: pixels where the truth saw a surface and the pipeline called ground or obstacle.
    """
    pipeline_labels, truth_labels = np.asarray(pipeline_labels), np.asarray(truth_labels)
    called = (pipeline_labels == LABEL_GROUND) | (pipeline_labels == LABEL_OBSTACLE)
    return confusion(pipeline_labels == LABEL_OBSTACLE, truth_labels == GT_OBSTACLE,
                     called & (truth_labels != GT_NO_RETURN))


def cell_confusion(predicted_grid: np.ndarray, truth_grid: np.ndarray) -> Confusion:
    """Costmap-cell confusion of two ``CELL_*`` grids; unknown truth cells are skipped."""
    truth_grid = np.asarray(truth_grid)
    return confusion(np.asarray(predicted_grid) == CELL_OCCUPIED, truth_grid == CELL_OCCUPIED,
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
        is_obstacle |= np.asarray(marked, dtype=bool).reshape(-1) & (labels != GT_NO_RETURN)
    traversable = (labels == GT_TRAVERSABLE) | (labels == GT_ABOVE_ROBOT)
    return flat[keep & is_obstacle], flat[keep & ~is_obstacle & traversable]


def point_cells(points: np.ndarray, origin_xy_m: tuple[float, float], resolution_m: float,
                shape: tuple[int, int]) -> np.ndarray:
    """(ny, nx) bool: the grid cells that points (M, 3) or (M, 2) [m] fall in."""
    ny, nx = shape
    cells = np.zeros((ny, nx), dtype=bool)
    points = np.asarray(points, dtype=np.float64)
    points = points.reshape(-1, points.shape[-1] if points.ndim > 1 else 3)
    ix = np.floor((points[:, 0] - origin_xy_m[0]) / resolution_m)
    iy = np.floor((points[:, 1] - origin_xy_m[1]) / resolution_m)
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    cells[iy[inside].astype(np.intp), ix[inside].astype(np.intp)] = True
    return cells


def truth_grid(obstacle_points: np.ndarray, traversable_points: np.ndarray,
               origin_xy_m: tuple[float, float], resolution_m: float, shape: tuple[int, int],
               ) -> np.ndarray:
    """Rasterise true points into a (ny, nx) int8 ``CELL_*`` grid, binned as the costmap."""
    grid = np.full(shape, CELL_UNKNOWN, dtype=np.int8)
    grid[point_cells(traversable_points, origin_xy_m, resolution_m, shape)] = CELL_FREE
    grid[point_cells(obstacle_points, origin_xy_m, resolution_m, shape)] = CELL_OCCUPIED
    return grid


def format_score(value: float, digits: int = 3) -> str:
    """Return a ratio as text, '-' when not defined (NaN)."""
    return '-' if value is None or math.isnan(value) else f'{value:.{digits}f}'


def grow_cells(mask: np.ndarray, cells: int) -> np.ndarray:
    """(ny, nx) bool: the cells within ``cells`` cells (Chebyshev distance) of a True cell."""
    mask = np.asarray(mask, dtype=bool)
    if cells <= 0 or not mask.any():
        return mask.copy()
    kernel = np.ones((2 * cells + 1, 2 * cells + 1), np.uint8)
    return cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)


def cell_share(hit: np.ndarray, cells: np.ndarray) -> tuple[int, int]:
    """(cells hit, cells): how many of a set of cells are True in ``hit`` (both (ny, nx))."""
    return int(np.count_nonzero(hit & cells)), int(np.count_nonzero(cells))


@dataclass(frozen=True)
class TolerantCells:
    """Costmap-cell counts with a tolerance of a few cells (issue 22); add to pool frames."""

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
    occupied = truth_grid == CELL_OCCUPIED
    free = truth_grid == CELL_FREE
    near_truth = grow_cells(occupied, cells)
    marked = predicted & (truth_grid != CELL_UNKNOWN)
    return TolerantCells(
        hit_truth=int(np.count_nonzero(occupied & grow_cells(predicted, cells))),
        truth=int(np.count_nonzero(occupied)),
        hit_marked=int(np.count_nonzero(marked & near_truth)),
        marked=int(np.count_nonzero(marked)),
        far_alarms=int(np.count_nonzero(predicted & free & ~near_truth)),
        free=int(np.count_nonzero(free)))


def surface_gap_points(points_ground: np.ndarray, object_ids: np.ndarray, mask: np.ndarray,
                       *, step_m: float, max_gap_m: float) -> np.ndarray:
    """Points (M, 3) [m] filling gaps between neighbouring samples of one surface.

    Neighbour pixels in ``mask`` on the same object, more than ``step_m`` and at most
    ``max_gap_m`` apart, get the segment between them sampled ``step_m`` apart.
    """
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
