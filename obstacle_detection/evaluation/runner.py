"""Run the detector over labelled frames and score it: the scenario suite runner of the tools.

Frames come from the scene generator (``scenarios.json``, ``scenarios_robot.json``). What
counts: :mod:`.metrics`.
"""

from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from obstacle_detection.labels import (CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN, GT_NO_RETURN,
                                       GT_OBSTACLE, GT_TRAVERSABLE)
from obstacle_detection.pipeline import geometry
from obstacle_detection.sim.noise import NOISE_MODELS
from . import EvaluationError
from . import metrics
from .camera import scaled_intrinsics
from .metrics import Confusion, TolerantCells, format_score
from obstacle_detection.pipeline.params import (KINECT_V2_SD, KINECT_V2_SD_SIZE, PRESETS,
                                                DetectorParams, Intrinsics)

#: The committed suites: the seed's (slope-only truth) and the robot-level one (issue 9).
SUITES = {'seed': Path(__file__).resolve().parent / 'scenarios.json',
          'robot': Path(__file__).resolve().parent / 'scenarios_robot.json'}


# --------------------------------------------------------------------------------------------
# Labelled frames


@dataclass
class LabelledFrame:
    """One depth frame with per-pixel ground truth (``GT_*``) and true points [m]."""

    scenario: str
    frame_id: str
    depth: np.ndarray
    intrinsics: Intrinsics
    truth_labels: np.ndarray
    truth_points: np.ndarray
    height_m: float
    pitch_rad: float
    roll_rad: float
    sequence_key: str | None = None  # frames sharing a key form a time sequence, in order
    truth: str = 'seed'  # 'seed': slope-only labels; 'robot': robot-level labels (issue 9)
    object_ids: np.ndarray | None = None   # (H, W) int16 primitive hit, -1 none (generator)
    object_names: tuple[str, ...] = ()     # name per primitive id ('' = unnamed)
    drop_edge: np.ndarray | None = None    # (H, W) bool reachable ground at a drop's edge
    hit_labels: np.ndarray | None = None   # (H, W) GT_* of the surface hit, returned or not

    def params(self, base: DetectorParams) -> DetectorParams:
        """Return ``base`` with this frame's camera mount."""
        return base.replace(camera_height_m=float(self.height_m),
                            camera_pitch_rad=float(self.pitch_rad),
                            camera_roll_rad=float(self.roll_rad))


@dataclass(frozen=True)
class Scenario:
    """One entry of the scenario suite; mount keys ``height_m``, ``pitch_deg``, ``roll_deg``."""

    name: str
    scene: str
    seeds: tuple[int, ...] = (0,)
    frames: tuple[int, ...] | None = None
    mount: tuple[tuple[str, float], ...] = ()
    description: str = ''
    truth: str = 'seed'
    noise: str = 'kinect_v2'

    @property
    def is_sequence(self) -> bool:
        """True when the scenario is a time sequence (frame indices given)."""
        return self.frames is not None

    @property
    def frame_count(self) -> int:
        """Number of frames the scenario renders."""
        return len(self.seeds) * (len(self.frames) if self.frames is not None else 1)

    def render_kwargs(self) -> dict[str, float]:
        """Keyword arguments of ``scenes.render_scene`` for the mount overrides."""
        return {k.replace('_deg', '_rad'): math.radians(v) if k.endswith('_deg') else float(v)
                for k, v in self.mount}


def scenario_from_dict(entry: dict[str, Any]) -> Scenario:
    """Build a :class:`Scenario` from one entry of a scenario list (JSON).

    ``frames``: a list or ``{"start", "stop", "step"}``; ``mount``: an object.
    """
    frames = entry.get('frames')
    if isinstance(frames, dict):
        frames = range(frames.get('start', 0), frames['stop'], frames.get('step', 1))
    return Scenario(**{**entry, 'seeds': tuple(entry.get('seeds', [0])),
                       'frames': None if frames is None else tuple(frames),
                       'mount': tuple(sorted(entry.get('mount', {}).items()))})


def load_scenarios(path: str | Path) -> list[Scenario]:
    """Read a scenario list: ``{"scenarios": [...]}`` with the default truth and noise."""
    data = json.loads(Path(path).read_text(encoding='utf-8'))
    defaults = {k: data[k] for k in ('truth', 'noise') if k in data}
    return [scenario_from_dict({**defaults, **e}) for e in data['scenarios']]


def select_scenarios(scenarios: Sequence[Scenario], names: Iterable[str] | None,
                     ) -> list[Scenario]:
    """Return the scenarios named (all when ``names`` is None); ValueError for an unknown name."""
    by_name = {s.name: s for s in scenarios}
    unknown = [name for name in names or () if name not in by_name]
    if unknown:
        raise EvaluationError(f'unknown scenario {unknown[0]!r}; known: {", ".join(by_name)}',
                              usage=True)
    return list(scenarios) if names is None else [by_name[name] for name in names]


def scenario_frames(scenario: Scenario, *, max_frames: int | None = None,
                    size: tuple[int, int] | None = None, rules: Any = None,
                    ) -> Iterator[LabelledFrame]:
    """Render the frames of one scenario with the scene generator.

    max_frames: at most this many, evenly spread; size: (width, height) [px] with the Kinect v2
    intrinsics scaled; rules: the robot-level truth's.
    """
    # the generator is only needed for synthetic frames
    from obstacle_detection.sim import scenes

    jobs = [(seed, index) for seed in scenario.seeds
            for index in (scenario.frames if scenario.frames is not None else (0,))]
    jobs = subsample(jobs, max_frames)
    kwargs: dict[str, Any] = scenario.render_kwargs()
    if size is not None:
        kwargs['size'] = (int(size[0]), int(size[1]))
        kwargs['intrinsics'] = scaled_intrinsics(KINECT_V2_SD, size[0] / KINECT_V2_SD_SIZE[0])
    for seed, index in jobs:
        frame = scenes.render_scene(scenario.scene, seed=seed, frame_index=index,
                                    noise=NOISE_MODELS[scenario.noise], rules=rules,
                                    **kwargs)
        frame_id = f'seed {seed}' + (f' frame {index}' if scenario.is_sequence else '')
        yield LabelledFrame(
            scenario=scenario.name, frame_id=frame_id, depth=frame.depth_mm,
            intrinsics=frame.intrinsics,
            truth_labels=frame.labels if scenario.truth == 'robot' else frame.labels_seed,
            truth_points=frame.points_ground, height_m=frame.height_m,
            pitch_rad=frame.pitch_rad, roll_rad=frame.roll_rad,
            sequence_key=f'{scenario.name}/{seed}' if scenario.is_sequence else None,
            truth=scenario.truth, object_ids=frame.hit_index, object_names=frame.object_names,
            drop_edge=frame.drop_edge,
            hit_labels=frame.hit_labels if scenario.truth == 'robot' else None)




def subsample(items: Sequence[Any], max_items: int | None) -> list[Any]:
    """At most ``max_items`` of ``items``, evenly spread, first and order kept."""
    items = list(items)
    if max_items is None or max_items >= len(items):
        return items
    picks = np.unique(np.linspace(0, len(items) - 1, max_items).round().astype(int))
    return [items[i] for i in picks]


# --------------------------------------------------------------------------------------------
# Node parameter files


#: Short names people use on command lines and in the seed's tables.
PARAM_ALIASES = {'theta': 'max_slope_rad', 'theta_rad': 'max_slope_rad',
                 'N': 'normal_neighbours', 'N1': 'validation_neighbours', 'K': 'median_kernel',
                 'TDBG': 'tdbg_m', 'SMAR': 'smar_m'}
#: How a boolean may be written in ``--set`` (case-insensitive).
_BOOLEANS = {'true': True, '1': True, 'yes': True, 'false': False, '0': False, 'no': False}


def apply_overrides(base: DetectorParams, overrides: dict[str, Any]) -> DetectorParams:
    """Return ``base`` with parameters changed by name (values may be strings).

    Keys: a field, a seed alias, ``<field>_deg`` for ``_rad``, ``voxel``/``voxel_m``/``voxel_mm``.
    """
    fields = set(base.as_dict())
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        name = PARAM_ALIASES.get(key, key)
        if name in ('voxel', 'voxel_m', 'voxel_mm'):
            size = float(value) / (1000.0 if name == 'voxel_mm' else 1.0)
            changes.update(voxel_x_m=size, voxel_y_m=size, voxel_z_m=size)
            continue
        if name.endswith('_deg'):
            name, value = name[:-4] + '_rad', math.radians(float(value))
            name = PARAM_ALIASES.get(name, name)
        if name not in fields:
            raise EvaluationError(f'unknown parameter {key!r}', usage=True)
        current = getattr(base, name)
        if isinstance(current, bool):
            value = value if isinstance(value, bool) else _BOOLEANS.get(str(value).strip().lower())
            if value is None:
                raise ValueError(f'{key}={overrides[key]!r} must be true or false')
        elif isinstance(current, int):
            if float(value) != int(float(value)):
                raise ValueError(f'{key}={value!r} must be an integer')
            value = int(float(value))
        else:
            value = float(value)
        changes[name] = value
    return base.replace(**changes)


def load_params_file(path: str | Path, base: DetectorParams | None = None,
                     ) -> DetectorParams:
    """Detector parameters from a node parameter file, on ``base`` (default: Table 4.2)."""
    from obstacle_detection.ros.parameters import (detector_params_from_ros,
                                                   pipeline_params_to_ros, read_params_file)

    values = pipeline_params_to_ros(base if base is not None else PRESETS['table_4_2']())
    values.update({name: value for name, value in read_params_file(path).items()
                   if name in values})
    try:
        return detector_params_from_ros(values)
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from exc


# --------------------------------------------------------------------------------------------
# Scoring


def truth_roi(frame: LabelledFrame, params: DetectorParams) -> np.ndarray:
    """(H, W) bool: pixels whose true point the truth costmap counts (robot: no height band)."""
    return points_roi(frame.truth_points, params, robot=frame.truth == 'robot')


def points_roi(points_ground: np.ndarray, params: DetectorParams, *,
               robot: bool = False) -> np.ndarray:
    """(H, W) bool: finite points (H, W, 3) in the region of interest (robot: no height band)."""
    flat = points_ground.reshape(-1, 3)
    finite = np.isfinite(flat).all(axis=1)
    roi = np.zeros(flat.shape[0], dtype=bool)
    if robot:
        x, y = flat[finite, 0], flat[finite, 1]
        roi[finite] = ((x >= params.min_range_m) & (x <= params.max_range_m)
                       & (np.abs(y) <= params.lateral_limit_m))
    else:
        roi[finite] = geometry.roi_mask(flat[finite], params)
    return roi.reshape(points_ground.shape[:-1])


#: Neighbouring obstacle samples of one surface at most this far apart span it [m].
MAX_SURFACE_GAP_M = 0.5


def truth_costmap(frame: LabelledFrame, params: DetectorParams,
                  roi: np.ndarray | None = None) -> np.ndarray:
    """Truth grid (ny, nx) int8 of a frame in the costmap geometry (``build_costmap``).

    Robot-level truth also marks drop edges, leaves unscored the gaps between samples of one
    surface seen at a grazing angle, and marks a free cell where an obstacle stands whose pixels
    returned no depth (``hit_labels``).
    """
    from obstacle_detection.pipeline.costmap import build_costmap, costmap_geometry

    if roi is None:
        roi = truth_roi(frame, params)
    marked = frame.drop_edge if frame.truth == 'robot' else None
    obstacle, traversable = metrics.truth_points(frame.truth_points, frame.truth_labels, roi,
                                                 marked)
    grid = build_costmap(obstacle, traversable, params).data
    origin, nx, ny = costmap_geometry(params)
    res = params.costmap_resolution_m
    if frame.truth == 'robot':
        # A surface seen at a grazing angle (a table's underside) is sampled in sparse rows:
        # the cells between its samples are neither known free nor sampled: not scored.
        gaps = metrics.surface_gap_points(
            frame.truth_points, frame.object_ids,
            roi & (frame.truth_labels == GT_OBSTACLE), step_m=res / 2,
            max_gap_m=MAX_SURFACE_GAP_M)
        covered = metrics.point_cells(gaps, origin, res, (ny, nx))
        grid[covered & (grid != CELL_OCCUPIED)] = CELL_UNKNOWN
        # an obstacle in view whose pixels returned no depth still stands in its cells
        hidden = roi & (frame.hit_labels == GT_OBSTACLE) & (frame.truth_labels == GT_NO_RETURN)
        cells = metrics.point_cells(frame.truth_points[hidden], origin, res, (ny, nx))
        grid[cells & (grid == CELL_FREE)] = CELL_OCCUPIED
    return grid


#: A named object counts (found or missed) only with at least this many visible cells.
MIN_OBJECT_CELLS = 3
#: An object is found when at least this share of its visible cells is occupied.
FOUND_SHARE = 0.5
#: A drop is marked when at least this share of its edge cells has an occupied cell within
#: ``DROP_TOLERANCE_CELLS`` cells.
DROP_MARKED_SHARE = 0.5
DROP_TOLERANCE_CELLS = 1


@dataclass
class RobotScore:
    """Robot-level checks of one frame (issue 9), each entry ``(name, hits, cells)``.

    ``tolerant``: the cell counts with a one-cell tolerance (issue 22).
    """

    objects: list[tuple[str, int, int]] = field(default_factory=list)
    passable: list[tuple[str, int, int]] = field(default_factory=list)
    drops: list[tuple[str, int, int]] = field(default_factory=list)
    tolerant: TolerantCells = field(default_factory=TolerantCells)


def robot_score(frame: LabelledFrame, predicted_grid: np.ndarray, params: DetectorParams,
                truth_grid: np.ndarray, roi: np.ndarray) -> RobotScore:
    """Named objects found, passable surfaces left free and drops marked in one frame."""
    from obstacle_detection.pipeline.costmap import costmap_geometry

    score = RobotScore(tolerant=metrics.tolerant_cells(predicted_grid, truth_grid, cells=1))
    origin, nx, ny = costmap_geometry(params)
    res = params.costmap_resolution_m
    seen = roi & (frame.truth_labels != GT_NO_RETURN)
    names = frame.object_names
    occupied = predicted_grid == CELL_OCCUPIED
    near_occupied = metrics.grow_cells(occupied, DROP_TOLERANCE_CELLS)
    for name in dict.fromkeys(n for n in names if n):
        everywhere = np.isin(frame.object_ids, [i for i, n in enumerate(names) if n == name])
        mine = seen & everywhere
        obstacle = mine & (frame.truth_labels == GT_OBSTACLE)
        traversable = mine & (frame.truth_labels == GT_TRAVERSABLE)
        if (frame.drop_edge & everywhere).any():   # a drop, even with its edge out of range
            entries, pixels, hit, known = score.drops, frame.drop_edge & mine, near_occupied, True
        elif np.count_nonzero(obstacle) >= np.count_nonzero(traversable):
            entries, pixels, hit, known = score.objects, obstacle, occupied, True
        else:   # passable: its free truth cells left free
            entries, pixels = score.passable, traversable
            hit, known = predicted_grid == CELL_FREE, truth_grid == CELL_FREE
        cells = metrics.point_cells(frame.truth_points[pixels], origin, res, (ny, nx)) & known
        hits, total = metrics.cell_share(hit, cells)
        if total >= MIN_OBJECT_CELLS:
            entries.append((name, hits, total))
    return score


@dataclass
class FrameScore:
    """Scores of one frame: pixel and cell confusions, pipeline time [ms]."""

    scenario: str
    frame_id: str
    pixel: Confusion
    cell: Confusion
    total_ms: float
    refined_pixel: Confusion | None = None
    refined_cell: Confusion | None = None
    robot: RobotScore | None = None


@dataclass
class SceneSummary:
    """Pooled scores of the frames of one scenario (or of all: name 'overall')."""

    name: str
    frames: int = 0
    pixel: Confusion = field(default_factory=Confusion)
    cell: Confusion = field(default_factory=Confusion)
    total_ms: list[float] = field(default_factory=list)
    refined_pixel: Confusion | None = None
    refined_cell: Confusion | None = None
    robot: RobotScore | None = None   # every frame's robot-level entries, in order

    def add(self, score: FrameScore) -> None:
        """Pool one frame's counts."""
        self.frames += 1
        self.pixel += score.pixel
        self.cell += score.cell
        self.total_ms.append(score.total_ms)
        if score.robot is not None:
            self.robot = self.robot or RobotScore()
            tag = f'{score.scenario} {score.frame_id}'
            for kind in ('objects', 'passable', 'drops'):
                getattr(self.robot, kind).extend(
                    (f'{name} ({tag})', hits, cells)
                    for name, hits, cells in getattr(score.robot, kind))
            self.robot.tolerant += score.robot.tolerant
        if score.refined_pixel is not None and score.refined_cell is not None:
            self.refined_pixel = (self.refined_pixel or Confusion()) + score.refined_pixel
            self.refined_cell = (self.refined_cell or Confusion()) + score.refined_cell

    @property
    def mean_ms(self) -> float:
        """Mean pipeline time per frame [ms]."""
        return float(np.mean(self.total_ms)) if self.total_ms else math.nan

    def objects_found(self) -> tuple[int, int, list[str]]:
        """Return (objects found, objects counted, names of the missed ones) over the frames."""
        return _reached(self.robot.objects if self.robot else [], FOUND_SHARE)

    def passable_free(self) -> float:
        """Share of the passable named objects' free truth cells left free (NaN: none)."""
        entries = self.robot.passable if self.robot else []
        cells = sum(c for _, _, c in entries)
        return sum(h for _, h, _ in entries) / cells if cells else math.nan

    def drops_marked(self) -> tuple[int, int, list[str]]:
        """Return (drops marked, drops counted, names of the unmarked ones) over the frames."""
        return _reached(self.robot.drops if self.robot else [], DROP_MARKED_SHARE)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready scores (NaN becomes None)."""
        out: dict[str, Any] = {'frames': self.frames, 'mean_ms': self.mean_ms,
                               'pixel': self.pixel.as_dict(), 'cell': self.cell.as_dict()}
        if self.refined_pixel is not None and self.refined_cell is not None:
            out['refined'] = {'pixel': self.refined_pixel.as_dict(),
                              'cell': self.refined_cell.as_dict()}
        if self.robot is not None:
            found, counted, missed = self.objects_found()
            marked, drops, unmarked = self.drops_marked()
            out['robot'] = {'objects_found': found, 'objects': counted, 'missed': missed,
                            'passable_free': self.passable_free(), 'drops_marked': marked,
                            'drops': drops, 'unmarked': unmarked,
                            'f1_one_cell': self.robot.tolerant.f1,
                            'far_alarm_rate': self.robot.tolerant.far_alarm_rate}
        return _without_nan(out)


def _reached(entries: list[tuple[str, int, int]], share: float,
             ) -> tuple[int, int, list[str]]:
    """Return (entries with hits >= ``share`` of their cells, entries, the others' names)."""
    missed = [name for name, hits, cells in entries if hits < share * cells]
    return len(entries) - len(missed), len(entries), missed


def _without_nan(value: Any) -> Any:
    """Return ``value`` with every NaN (in nested dicts too) replaced by None."""
    if isinstance(value, dict):
        return {k: _without_nan(v) for k, v in value.items()}
    return None if isinstance(value, float) and math.isnan(value) else value


@dataclass
class Report:
    """An evaluation: per-scenario summaries in run order, the overall pool, the frames."""

    params: DetectorParams
    label: str
    scenes: dict[str, SceneSummary]
    overall: SceneSummary
    frames: list[FrameScore]
    refiner: str | None = None
    seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready report (one object; ``tools/evaluate.py`` prints it on one line)."""
        return {'label': self.label, 'params': self.params.as_dict(), 'refiner': self.refiner,
                'scenes': {n: s.as_dict() for n, s in self.scenes.items()},
                'overall': self.overall.as_dict(), 'seconds': round(self.seconds, 2)}


def pool_scores(scores: Sequence[FrameScore], params: DetectorParams, *, label: str = '',
                refiner_name: str | None = None, seconds: float = 0.0) -> Report:
    """Return the Report of frames with these scores: per scenario in run order, overall."""
    scenes: dict[str, SceneSummary] = {}
    overall = SceneSummary('overall')
    for score in scores:
        scenes.setdefault(score.scenario, SceneSummary(score.scenario)).add(score)
        overall.add(score)
    return Report(params, label, scenes, overall, list(scores), refiner_name, seconds)


def detect_frames(frames: Iterable[LabelledFrame], base: DetectorParams,
                  ) -> Iterator[tuple[LabelledFrame, DetectorParams, Any, np.ndarray | None]]:
    """Yield (frame, params, result, previous obstacle mask) for each frame, in order.

    Each frame runs with its own mount; the previous mask is the rule-based obstacle mask of
    the previous frame of the same sequence, None for a still frame or a sequence's first.
    """
    from obstacle_detection.pipeline import refine
    from obstacle_detection.pipeline.detector import Detector

    detector = functools.cache(Detector)   # one per parameter set: frames differ in mount
    key: str | None = None
    mask: np.ndarray | None = None
    for frame in frames:
        params = frame.params(base)
        result = detector(params).process(frame.depth, frame.intrinsics)
        same = frame.sequence_key is not None and key == frame.sequence_key
        yield frame, params, result, mask if same else None
        key, mask = frame.sequence_key, refine.obstacle_mask(result)


def evaluate_frames(frames: Iterable[LabelledFrame], base: DetectorParams, *,
                    label: str = '', refiner: Any = None, refiner_name: str | None = None,
                    ) -> Report:
    """Run the detector (and optionally a refiner) over frames and pool the scores."""
    from obstacle_detection.pipeline import refine

    started = time.perf_counter()
    scores: list[FrameScore] = []
    for frame, params, result, prev_mask in detect_frames(frames, base):
        roi = truth_roi(frame, params)
        grid = truth_costmap(frame, params, roi)
        score = FrameScore(frame.scenario, frame.frame_id,
                           metrics.pixel_confusion(result.labels, frame.truth_labels),
                           metrics.cell_confusion(result.costmap.data, grid),
                           float(result.timings_ms.get('total', math.nan)))
        if frame.truth == 'robot':
            score.robot = robot_score(frame, result.costmap.data, params, grid, roi)
        if refiner is not None:
            mask = refiner.predict_labels(result, prev_mask)
            refined = refine.refine_result(result, mask, params)
            score.refined_pixel = metrics.pixel_confusion(refined.labels, frame.truth_labels)
            score.refined_cell = metrics.cell_confusion(refined.costmap.data, grid)
        scores.append(score)
    return pool_scores(scores, base, label=label, refiner_name=refiner_name,
                       seconds=time.perf_counter() - started)


# --------------------------------------------------------------------------------------------
# Text output

def _table(report: Report, columns: Sequence[tuple[str, int, Callable[[Any], str]]],
           ) -> list[str]:
    """Fixed-width rows: one per scenario and 'overall'; ``columns``: (head, width, cell)."""
    width = max([len('overall')] + [len(n) for n in report.scenes]) + 1
    head = f'{"scenario":<{width}} ' + ' '.join(f'{h:>{w}}' for h, w, _ in columns)
    lines = [head, '-' * len(head)]
    for summary in [*report.scenes.values(), None, report.overall]:
        lines.append('-' * len(head) if summary is None else f'{summary.name:<{width}} '
                     + ' '.join(f'{cell(summary):>{w}}' for _, w, cell in columns))
    return lines


def _score_column(head: str, kind: str, attr: str, refined: bool = False, width: int = 7,
                  ) -> tuple[str, int, Callable[[SceneSummary], str]]:
    """Return a column of one confusion ratio (``kind`` 'pixel' or 'cell'), optionally refined."""
    def cell(summary: SceneSummary) -> str:
        confusion = getattr(summary, f'refined_{kind}' if refined else kind)
        return format_score(getattr(confusion or Confusion(), attr))
    return head, width, cell


def _percent(value: float, digits: int = 2) -> str:
    return '-' if math.isnan(value) else f'{100 * value:.{digits}f}'


def format_table(report: Report, *, refined: bool = False) -> str:
    """Return a fixed-width table: one row per scenario and an 'overall' row."""
    columns = [('frames', 6, lambda s: str(s.frames))] + [
        _score_column(head, kind, attr, refined) for head, kind, attr in (
            ('px P', 'pixel', 'precision'), ('px R', 'pixel', 'recall'),
            ('px F1', 'pixel', 'f1'), ('px FA', 'pixel', 'false_alarm_rate'),
            ('cell P', 'cell', 'precision'), ('cell R', 'cell', 'recall'),
            ('cell F1', 'cell', 'f1'), ('IoU', 'cell', 'iou'),
            ('cell FA', 'cell', 'false_alarm_rate'))]
    columns.append(('ms', 7, lambda s: f'{s.mean_ms:.1f}'))
    return '\n'.join(_table(report, columns))


def _share(reached: tuple[int, int, list[str]]) -> str:
    return f'{reached[0]}/{reached[1]}' if reached[1] else '-'


def format_robot_table(report: Report) -> str:
    """Return the robot-level table: a row per scenario, 'overall', misses, targets.

    "F1 1-cell" counts a mark within one cell of a true obstacle (and back); "FA>1 cell %" is
    the share of free cells marked with no true obstacle within one cell.
    """
    def tolerant(summary: SceneSummary) -> TolerantCells:
        return summary.robot.tolerant if summary.robot else TolerantCells()

    lines = _table(report, [
        ('frames', 6, lambda s: str(s.frames)), _score_column('cell F1', 'cell', 'f1'),
        ('F1 1-cell', 9, lambda s: format_score(tolerant(s).f1)),
        ('FA %', 6, lambda s: _percent(s.cell.false_alarm_rate)),
        ('FA>1 cell %', 11, lambda s: _percent(tolerant(s).far_alarm_rate)),
        ('objects', 8, lambda s: _share(s.objects_found())),
        ('pass %', 6, lambda s: _percent(s.passable_free(), 1)),
        ('drops', 6, lambda s: _share(s.drops_marked())),
        _score_column('px F1', 'pixel', 'f1', width=6),
        ('ms', 6, lambda s: f'{s.mean_ms:.1f}')])
    missed, unmarked = report.overall.objects_found()[2], report.overall.drops_marked()[2]
    if missed:
        lines.append('missed objects: ' + ', '.join(missed))
    if unmarked:
        lines.append('unmarked drops: ' + ', '.join(unmarked))
    return '\n'.join(lines)
