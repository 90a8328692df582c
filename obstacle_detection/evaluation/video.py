"""Scores of the fused costmap over a sequence, side by side with the per-frame costmap.

What is measured: docs/accuracy.md, "Scores of the fused costmap over a sequence".
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from obstacle_detection.labels import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN
from . import metrics
from obstacle_detection.pipeline.costmap import Costmap, build_costmap
from obstacle_detection.pipeline.fusion import FusedGrid, FusionParams, frame_evidence
from .metrics import Confusion
from .runner import points_roi
from obstacle_detection.pipeline.params import DetectorParams
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.sim.scenes import scene_params
from obstacle_detection.sim.sequences import SceneSequence

#: The blind zone of the memory score: ahead of the robot, x in [0, 0.5) m, |y| <= 0.3 m.
BLIND_ZONE_X_M = (0.0, 0.5)
BLIND_ZONE_HALF_WIDTH_M = 0.3

#: Flicker counts a cell only when no cell within STILL_RADIUS_CELLS changed its truth in the
#: last STILL_FRAMES frames (nothing moved or appeared near it).
STILL_RADIUS_CELLS = 2
STILL_FRAMES = 10

#: The issue's targets [frames at 30 Hz]: a new obstacle marked, a vacated cell cleared.
MARK_BUDGET_FRAMES = 3
CLEAR_BUDGET_FRAMES = 10


#: The two grids scored: the fused one and the per-frame one moved into odom.
_GRIDS = ('fused', 'per_frame')


class RunTracker:
    """Runs of frames per cell (truth occupied, or vacated) and when each grid reacted.

    Only steady runs (the detector supported the reaction in the run's first ``budget`` frames)
    are scored.
    """

    def __init__(self, size: int, names: tuple[str, ...], budget: int) -> None:
        self.names = names
        self.budget = int(budget)
        self.onset = np.full(size, -1, np.int64)
        self.support = np.zeros(size, np.int64)
        self.first = {n: np.full(size, -1, np.int64) for n in names}
        self.eligible = {n: np.zeros(size, bool) for n in names}
        self.counts: dict[str, list[int]] = {n: [] for n in names}
        self.missed = {n: 0 for n in names}
        self.steady_runs = 0
        self.unsteady_runs = 0

    def _close(self, ended: np.ndarray, t: int) -> None:
        length = t - self.onset
        steady = ended & (self.support >= np.minimum(length, self.budget))
        long_enough = steady & (length >= self.budget)
        self.steady_runs += int(np.count_nonzero(steady))
        self.unsteady_runs += int(np.count_nonzero(ended & ~steady))
        for name in self.names:
            got = steady & self.eligible[name] & (self.first[name] >= 0)
            self.counts[name].extend((self.first[name][got] - self.onset[got] + 1).tolist())
            self.missed[name] += int(np.count_nonzero(
                long_enough & self.eligible[name] & (self.first[name] < 0)))
            self.first[name][ended] = -1
        self.onset[ended] = -1
        self.support[ended] = 0

    def step(self, t: int, in_run: np.ndarray, start: np.ndarray,
             reacted: dict[str, np.ndarray], supported: np.ndarray,
             eligible: dict[str, np.ndarray] | None = None) -> None:
        """Close runs that ended, open new ones at frame t, record first reactions."""
        self._close(~in_run & (self.onset >= 0), t)
        start = start & in_run & (self.onset < 0)
        self.onset[start] = t
        for name in self.names:
            self.eligible[name][start] = True if eligible is None else eligible[name][start]
            new = in_run & (self.onset >= 0) & (self.first[name] < 0) & reacted[name]
            self.first[name][new] = t
        counting = in_run & (self.onset >= 0) & (t - self.onset < self.budget) & supported
        self.support[counting] += 1

    def finish(self, t_end: int) -> None:
        """Close every open run at the end of the sequence (frame ``t_end``, excluded)."""
        self._close(self.onset >= 0, t_end)

    def report(self) -> dict[str, Any]:
        """Per grid: stats of frames until the reaction and steady runs missed; run counts."""
        out: dict[str, Any] = {n: {**_stats(self.counts[n]), 'missed': self.missed[n]}
                               for n in self.names}
        out['steady_runs'] = self.steady_runs
        out['unsteady_runs'] = self.unsteady_runs
        return out


def _stats(values: list[int]) -> dict[str, float]:
    """Count, median, 90th percentile and maximum of frame counts (NaN when empty)."""
    if not values:
        return {'runs': 0, 'median': math.nan, 'p90': math.nan, 'max': math.nan}
    array = np.asarray(values)
    return {'runs': int(array.size), 'median': float(np.median(array)),
            'p90': float(np.percentile(array, 90)), 'max': float(array.max())}


@dataclass
class SequenceReport:
    """Scores of one sequence (see the module docstring); ``as_dict`` for JSON."""

    name: str
    frames: int
    fused_area: Confusion
    per_frame_area: Confusion
    per_frame: Confusion
    fused_view: Confusion
    flicker_fused: list[float]
    flicker_per_frame: list[float]
    mark: dict[str, Any]
    clear: dict[str, Any]
    blind: dict[str, int]
    fusion_ms: list[float]
    resets: int = 0
    in_place: int = 0
    sheet: np.ndarray | None = None

    def as_dict(self) -> dict[str, Any]:
        """Flat JSON-ready numbers (NaN becomes None)."""
        def num(value: float) -> float | None:
            return None if value is None or (isinstance(value, float) and math.isnan(value)) \
                else round(float(value), 4)

        def nums(values: dict[str, Any]) -> dict[str, Any]:
            return {k: num(v) if isinstance(v, float) else v for k, v in values.items()}

        def flick(values: list[float]) -> dict[str, float | None]:
            arr = np.asarray(values) if values else np.zeros(1)
            return {'mean_pct': num(100 * arr.mean()), 'p90_pct': num(100 * np.percentile(
                arr, 90)), 'max_pct': num(100 * arr.max())}

        out: dict[str, Any] = {'sequence': self.name, 'frames': self.frames}
        for key in ('fused_area', 'per_frame_area', 'per_frame', 'fused_view'):
            out[key] = nums(getattr(self, key).as_dict())
        out['flicker_fused'] = flick(self.flicker_fused)
        out['flicker_per_frame'] = flick(self.flicker_per_frame)
        for key, runs in (('frames_to_mark', self.mark), ('frames_to_clear', self.clear)):
            out[key] = {grid: nums(stats) if isinstance(stats, dict) else stats
                        for grid, stats in runs.items()}
        cells = self.blind['cells']
        out['blind_zone'] = {'cell_frames': cells, **{
            key: num(self.blind[key] / cells if cells else math.nan)
            for key in ('fused', 'per_frame', 'fused_near', 'per_frame_near')}}
        ms = np.asarray(self.fusion_ms) if self.fusion_ms else np.full(1, math.nan)
        out['fusion_ms'] = {'median': num(float(np.median(ms))),
                            'p90': num(float(np.percentile(ms, 90)))}
        out['odometry'] = {'resets': self.resets, 'in_place_frames': self.in_place}
        return out


class _Lattice:
    """A fixed odom window on the fused grid's lattice that holds the whole trajectory."""

    def __init__(self, poses: list[tuple[float, float, float]], fusion: FusionParams,
                 margin_m: float) -> None:
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        res = fusion.resolution_m
        reach = fusion.size_m / 2 + margin_m
        lo = np.floor((poses[:, :2].min(axis=0) - reach) / res).astype(int)
        hi = np.ceil((poses[:, :2].max(axis=0) + reach) / res).astype(int)
        self.origin_cell = (int(lo[0]), int(lo[1]))
        self.shape = (int(hi[1] - lo[1]), int(hi[0] - lo[0]))   # (ny, nx)
        self.res = res
        xs = (lo[0] + np.arange(self.shape[1]) + 0.5) * res
        ys = (lo[1] + np.arange(self.shape[0]) + 0.5) * res
        self.centre_x, self.centre_y = np.meshgrid(xs, ys)

    def window(self, origin_cell: tuple[int, int], n: int) -> tuple[slice, slice]:
        """(rows, cols) of a fused window with that origin cell and side."""
        c0 = origin_cell[0] - self.origin_cell[0]
        r0 = origin_cell[1] - self.origin_cell[1]
        return slice(r0, r0 + n), slice(c0, c0 + n)

    def evidence_grid(self, costmap: Costmap, pose: tuple[float, float, float]) -> np.ndarray:
        """Move a per-frame costmap into the lattice: (ny, nx) int8 CELL_* values."""
        hit, miss = frame_evidence(costmap, pose, self.origin_cell,
                                   (self.shape[1], self.shape[0]), self.res)
        grid = np.full(self.shape, CELL_UNKNOWN, dtype=np.int8)
        grid[miss] = CELL_FREE
        grid[hit] = CELL_OCCUPIED
        return grid

    def blind_zone(self, pose: tuple[float, float, float]) -> np.ndarray:
        """(ny, nx) bool: cells whose centre is in the blind zone of a robot at ``pose``."""
        dx, dy = self.centre_x - pose[0], self.centre_y - pose[1]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        ahead, left = c * dx + s * dy, -s * dx + c * dy
        return (ahead >= BLIND_ZONE_X_M[0]) & (ahead < BLIND_ZONE_X_M[1]) & \
            (np.abs(left) <= BLIND_ZONE_HALF_WIDTH_M)


#: Outline of the truth's obstacles in the contact sheet's panels.
TRUTH_OUTLINE_RGB = (230, 120, 0)


def _to_odom(pose: tuple[float, float, float], x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(M, 2) odom x, y [m] of base-frame x, y, at ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    x, y = np.ravel(x).astype(np.float64), np.ravel(y).astype(np.float64)
    return np.stack([pose[0] + c * x - s * y, pose[1] + s * x + c * y], axis=1)


def _panel(grid: np.ndarray, truth: np.ndarray, pose: tuple[float, float, float],
           origin_xy_m: tuple[float, float], res: float, scale: int) -> np.ndarray:
    """Draw a window of CELL_* values from above, truth obstacles outlined, the robot."""
    from obstacle_detection.viz.overlay import ROBOT_RGB, costmap_pixel_of, render_costmap

    costmap = Costmap(grid, res, origin_xy_m)
    image = render_costmap(costmap, scale=scale)
    mask = (truth == CELL_OCCUPIED).T[::-1, ::-1]
    mask = np.repeat(np.repeat(mask, scale, axis=0), scale, axis=1).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(image, contours, -1, TRUTH_OUTLINE_RGB, 1)
    col, row = costmap_pixel_of(costmap, pose[0], pose[1], scale=scale)
    # the robot: a disc on its base origin and a line along its heading (+x)
    centre = np.array([col, row])
    nose = centre + 5 * scale * np.array([-math.sin(pose[2]), -math.cos(pose[2])])
    cv2.line(image, tuple(int(v) for v in centre.round()), tuple(int(v) for v in nose.round()),
             ROBOT_RGB, 2, cv2.LINE_AA)
    cv2.circle(image, tuple(int(v) for v in centre.round()), max(3, scale + 1), ROBOT_RGB, -1,
               cv2.LINE_AA)
    return image


@dataclass(frozen=True)
class Observation:
    """One frame of a sequence: true and odometry poses, the costmap, the truth."""

    index: int
    pose_true: tuple[float, float, float]
    pose_odom: tuple[float, float, float] | None
    costmap: Costmap
    truth_obstacle: np.ndarray
    truth_traversable: np.ndarray
    truth_costmap: np.ndarray


def observe_sequence(sequence: SceneSequence, base: DetectorParams, *,
                     stop: int | None = None,
                     on_frame: Callable[[int, int], None] | None = None,
                     ) -> Iterator[Observation]:
    """Render the frames [0, stop) of ``sequence`` and run the detector on each."""
    total = len(sequence) if stop is None else max(1, min(stop, len(sequence)))
    detector: Detector | None = None
    for index in range(total):
        sf = sequence.frame(index)
        params = scene_params(sf.frame, base)
        if detector is None or detector.params != params:
            detector = Detector(params)
        result = detector.process(sf.frame.depth_mm, sf.frame.intrinsics)
        points = sf.frame.points_ground
        obstacle, traversable = metrics.truth_points(points, sf.frame.labels,
                                                     points_roi(points, params))
        truth = build_costmap(obstacle, traversable, params).data
        yield Observation(index=index, pose_true=sf.pose_true,
                          pose_odom=sf.pose_odom, costmap=result.costmap,
                          truth_obstacle=obstacle, truth_traversable=traversable,
                          truth_costmap=truth)
        if on_frame is not None:
            on_frame(index, total)


class _Scorer:
    """The scores of one sequence, frame by frame (:func:`score_sequence`)."""

    def __init__(self, observations: Sequence[Observation], fusion: FusionParams,
                 sheet_frames: int) -> None:
        total = len(observations)
        self.fusion = fusion
        self.lattice = _Lattice([o.pose_true for o in observations]
                                + [o.pose_odom for o in observations if o.pose_odom is not None],
                                fusion, margin_m=1.0)
        self.grid = FusedGrid(fusion)
        self.truth_area = np.full(self.lattice.shape, CELL_UNKNOWN, dtype=np.int8)
        self.conf = {k: Confusion() for k in ('fused_area', 'per_frame_area', 'per_frame',
                                              'fused_view')}
        self.flicker: dict[str, list[float]] = {'fused': [], 'per_frame': []}
        self.mark = RunTracker(self.truth_area.size, _GRIDS, MARK_BUDGET_FRAMES)
        self.clear = RunTracker(self.truth_area.size, _GRIDS, CLEAR_BUDGET_FRAMES)
        self.blind = {'cells': 0, 'fused': 0, 'per_frame': 0, 'fused_near': 0,
                      'per_frame_near': 0}
        self.fusion_ms: list[float] = []
        self.resets = self.in_place = 0
        self.previous: dict[str, np.ndarray] = {}
        self.last_change = np.full(self.lattice.shape, -STILL_FRAMES - 1, dtype=np.int64)
        self.sheet_at = set(np.linspace(0, total - 1, sheet_frames).round().astype(int)
                            .tolist()) if sheet_frames > 0 else set()
        self.thumbs: list[np.ndarray] = []
        self.labels: list[str] = []

    def add(self, step: int, obs: Observation, rate_hz: float) -> None:
        """Fuse one observation and score both grids on it."""
        lattice, grid = self.lattice, self.grid
        start = time.perf_counter()
        update = grid.update(obs.costmap, obs.pose_odom)
        self.fusion_ms.append((time.perf_counter() - start) * 1e3)
        self.resets += update.reset
        self.in_place += update.in_place
        # truth: this frame's cells in odom overwrite the area seen so far
        pose = obs.pose_true
        seen = metrics.truth_grid(_to_odom(pose, *obs.truth_obstacle[:, :2].T),
                                  _to_odom(pose, *obs.truth_traversable[:, :2].T),
                                  (lattice.origin_cell[0] * lattice.res,
                                   lattice.origin_cell[1] * lattice.res),
                                  lattice.res, lattice.shape)
        truth_prev = self.truth_area.copy()
        self.truth_area[seen != CELL_UNKNOWN] = seen[seen != CELL_UNKNOWN]
        # both grids on the lattice
        rows, cols = lattice.window(grid.origin_cell, self.fusion.cells)
        fused_world = np.full(lattice.shape, CELL_UNKNOWN, dtype=np.int8)
        states = grid.cell_states()
        fused_world[rows, cols] = states
        worlds = {'fused': fused_world,
                  'per_frame': lattice.evidence_grid(obs.costmap, update.pose)}
        truth_window = self.truth_area[rows, cols]
        self._confusions(obs, update.pose, states, worlds['per_frame'][rows, cols],
                         truth_window)
        self._flicker(step, truth_prev, worlds)
        self._runs(step, truth_prev, worlds, rows, cols)
        self._blind_zone(obs, worlds)
        self.previous = worlds
        if step in self.sheet_at:
            pair = [_panel(g, truth_window, update.pose, grid.origin_xy_m,
                           self.fusion.resolution_m, 3)
                    for g in (worlds['per_frame'][rows, cols], states)]
            gap = np.full((pair[0].shape[0], 8, 3), 255, np.uint8)
            self.thumbs.append(np.hstack([pair[0], gap, pair[1]]))
            self.labels.append(f't = {obs.index / rate_hz:.1f} s (frame {obs.index}): '
                               f'per-frame | fused')

    def _confusions(self, obs: Observation, pose: tuple[float, float, float],
                    states: np.ndarray, per_frame_window: np.ndarray,
                    truth_window: np.ndarray) -> None:
        """F1 counts: both grids on the area seen so far, and on the frame's own view."""
        conf = self.conf
        conf['fused_area'] += metrics.cell_confusion(states, truth_window)
        conf['per_frame_area'] += metrics.cell_confusion(per_frame_window, truth_window)
        conf['per_frame'] += metrics.cell_confusion(obs.costmap.data, obs.truth_costmap)
        xs, ys = obs.costmap.cell_centres()
        bx, by = np.meshgrid(xs, ys)
        fused_view = self.grid.values_at(_to_odom(pose, bx, by)).reshape(bx.shape)
        conf['fused_view'] += metrics.cell_confusion(fused_view, obs.truth_costmap)

    def _flicker(self, step: int, truth_prev: np.ndarray,
                 worlds: dict[str, np.ndarray]) -> None:
        """Cells whose occupied state changed while nothing moved nearby."""
        moved = metrics.grow_cells(self.truth_area != truth_prev, STILL_RADIUS_CELLS)
        self.last_change[moved] = step
        previous = self.previous
        if not previous:
            return
        static = step - self.last_change > STILL_FRAMES
        per_frame = worlds['per_frame']
        for key, was_known in (
                ('fused', previous['fused'] != CELL_UNKNOWN),
                ('per_frame', (previous['per_frame'] != CELL_UNKNOWN)
                 & (per_frame != CELL_UNKNOWN))):
            now = worlds[key]
            changed = (now == CELL_OCCUPIED) != (previous[key] == CELL_OCCUPIED)
            known = int(np.count_nonzero(now != CELL_UNKNOWN))
            self.flicker[key].append(np.count_nonzero(changed & static & was_known)
                                     / max(known, 1))

    def _runs(self, step: int, truth_prev: np.ndarray, worlds: dict[str, np.ndarray],
              rows: slice, cols: slice) -> None:
        """Frames until marked / cleared, over runs inside the fused window only."""
        truth_area = self.truth_area
        in_window = np.zeros(self.lattice.shape, dtype=bool)
        in_window[rows, cols] = True
        occupied_truth = ((truth_area == CELL_OCCUPIED) & in_window).reshape(-1)
        marked = {k: (worlds[k] == CELL_OCCUPIED).reshape(-1) for k in _GRIDS}
        self.mark.step(step, occupied_truth, occupied_truth, marked, marked['per_frame'])
        vacated = ((truth_area == CELL_FREE) & (truth_prev == CELL_OCCUPIED)).reshape(-1)
        was_marked = {k: (self.previous[k] == CELL_OCCUPIED).reshape(-1) if self.previous
                      else np.zeros(truth_area.size, bool) for k in _GRIDS}
        self.clear.step(step, ((truth_area == CELL_FREE) & in_window).reshape(-1), vacated,
                        {k: ~v for k, v in marked.items()},
                        (worlds['per_frame'] == CELL_FREE).reshape(-1), eligible=was_marked)

    def _blind_zone(self, obs: Observation, worlds: dict[str, np.ndarray]) -> None:
        """Obstacle cells just ahead of the robot (true pose) that each grid keeps."""
        zone = self.lattice.blind_zone(obs.pose_true) & (self.truth_area == CELL_OCCUPIED)
        self.blind['cells'] += int(np.count_nonzero(zone))
        for key in _GRIDS:
            marked_here = worlds[key] == CELL_OCCUPIED
            self.blind[key] += int(np.count_nonzero(zone & marked_here))
            near = metrics.grow_cells(marked_here, 1)
            self.blind[key + '_near'] += int(np.count_nonzero(zone & near))

    def report(self, name: str, total: int) -> SequenceReport:
        """Close the runs and return the scores."""
        self.mark.finish(total)
        self.clear.finish(total)
        sheet = None
        if self.thumbs:
            from obstacle_detection.viz.pictures import tile
            sheet = tile(self.thumbs, columns=4, labels=self.labels)
        return SequenceReport(
            name=name, frames=total, **self.conf, flicker_fused=self.flicker['fused'],
            flicker_per_frame=self.flicker['per_frame'], mark=self.mark.report(),
            clear=self.clear.report(), blind=self.blind, fusion_ms=self.fusion_ms,
            resets=self.resets, in_place=self.in_place, sheet=sheet)


def score_sequence(name: str, observations: Sequence[Observation],
                   fusion: FusionParams | None = None, *, rate_hz: float = 30.0,
                   sheet_frames: int = 0) -> SequenceReport:
    """Fuse the observations' costmaps in order and score per-frame and fused grids.

    sheet_frames: when > 0, draw a contact sheet of that many moments.
    """
    fusion = fusion if fusion is not None else FusionParams()
    scorer = _Scorer(observations, fusion, sheet_frames)
    for step, obs in enumerate(observations):
        scorer.add(step, obs, rate_hz)
    return scorer.report(name, len(observations))


def evaluate_sequence(sequence: SceneSequence, base: DetectorParams,
                      fusion: FusionParams | None = None, *, stop: int | None = None,
                      sheet_frames: int = 0,
                      on_frame: Callable[[int, int], None] | None = None) -> SequenceReport:
    """Observe ``sequence`` (:func:`observe_sequence`) and score it (:func:`score_sequence`)."""
    observations = list(observe_sequence(sequence, base, stop=stop, on_frame=on_frame))
    return score_sequence(sequence.name, observations, fusion, rate_hz=sequence.rate_hz,
                          sheet_frames=sheet_frames)


def contact_sheet(reports: Sequence[SequenceReport], fusion: FusionParams) -> np.ndarray:
    """Stack the reports' sheets one under the other, with a title and a legend (RGB)."""
    from obstacle_detection.viz import pictures
    from obstacle_detection.viz.overlay import FREE_RGB, OCCUPIED_RGB, ROBOT_RGB, UNKNOWN_RGB

    drawn = [r for r in reports if r.sheet is not None]
    width = max(r.sheet.shape[1] for r in drawn)
    rows = [np.pad(r.sheet, ((0, 0), (0, width - r.sheet.shape[1]), (0, 0)),
                   constant_values=255) for r in drawn]
    legend = pictures.legend(
        f'each pair: per-frame costmap moved into odom | fused costmap; a {fusion.size_m:g} m '
        f'x {fusion.size_m:g} m window around the robot, north-up in odom (x up, y left), '
        f'{fusion.resolution_m * 100:g} cm cells', [
            ('box', OCCUPIED_RGB, 'occupied'), ('box', FREE_RGB, 'free'),
            ('box', UNKNOWN_RGB, 'unknown'),
            ('line', TRUTH_OUTLINE_RGB, "the truth's obstacles seen so far"),
            ('triangle', ROBOT_RGB, 'robot (a disc, a line along its heading)')], width)
    names = ', '.join(r.name for r in drawn)
    return pictures.titled(np.vstack(rows), f'Per-frame and fused costmaps over time: {names}',
                           below=legend)


def format_table(reports: list[SequenceReport]) -> str:
    """Per-frame and fused side by side, one block of rows per sequence (Markdown)."""
    from .metrics import format_score

    def pct(value: float | None) -> str:
        return '-' if value is None else f'{value:.2f} %'

    def frames(stats: dict[str, Any]) -> str:
        if not stats['runs']:
            return '-'
        return (f"{stats['median']:g} / {stats['p90']:g} / {stats['max']:g}"
                f" ({stats['missed']} missed)")

    def share(value: float | None) -> str:
        return format_score(math.nan if value is None else value)

    lines = ['| sequence | score | per-frame | fused |', '| --- | --- | --- | --- |']
    for r in reports:
        d = r.as_dict()
        mark, clear, blind = d['frames_to_mark'], d['frames_to_clear'], d['blind_zone']
        rows = [
            ('cell F1, area seen so far', format_score(r.per_frame_area.f1),
             format_score(r.fused_area.f1)),
            ("cell F1, the frame's own view", format_score(r.per_frame.f1),
             format_score(r.fused_view.f1)),
            ('flicker, % of seen cells a frame: mean / max',
             f"{pct(d['flicker_per_frame']['mean_pct'])} / "
             f"{pct(d['flicker_per_frame']['max_pct'])}",
             f"{pct(d['flicker_fused']['mean_pct'])} / {pct(d['flicker_fused']['max_pct'])}"),
            (f"frames until marked: median / p90 / max ({mark['steady_runs']} cells)",
             frames(mark['per_frame']), frames(mark['fused'])),
            (f"frames until cleared: median / p90 / max ({clear['steady_runs']} cells)",
             frames(clear['per_frame']), frames(clear['fused'])),
            (f"blind zone: obstacle cells marked (within 1 cell), {blind['cell_frames']} "
             f"cell-frames", f"{share(blind['per_frame'])} ({share(blind['per_frame_near'])})",
             f"{share(blind['fused'])} ({share(blind['fused_near'])})"),
            ('fusion [ms a frame]: median / p90', '-',
             f"{d['fusion_ms']['median']:.2f} / {d['fusion_ms']['p90']:.2f}"),
        ]
        for label, per_frame, fused in rows:
            lines.append(f'| {r.name} | {label} | {per_frame} | {fused} |')
    return '\n'.join(lines)
