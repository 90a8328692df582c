"""Score what Nav2's costmap makes of the detector's clouds over a sequence (test code only).

:class:`Replay` feeds each update's clouds (the newest obstacle cloud and clearing cloud, with
the robot's pose) into the ported layers of :mod:`nav2_layers`, configured by a Nav2 params
file, and compares the master grid (lethal cells) with the sequence's ground truth on one odom
lattice whose cells are the costmap's (both are multiples of the resolution from odom's
origin). Figures (``Replay.report``):

- ``f1``: lethal cells against the truth of the area seen so far (each frame's truth
  overwrites the cells it saw; a cell last seen holding the person, not seen since, is not
  known), over the window's cells whose truth is known, with one cell of
  tolerance: a lethal cell counts as right when a true obstacle lies within one cell of it, a
  true obstacle as found when a lethal cell does; pooled over the updates;
- ``ghost``: per update, lethal cells where the truth is free floor, not within one cell of a
  true obstacle (what a planner would swerve around for nothing); ``stale_lethal``: those of
  them seen free, with no true obstacle within one cell, in every frame of the last 10 at
  30 Hz (seen free floor left lethal 10 frames after its obstacle left; the one cell is the
  tolerance above: a mark beside the person counts as right, so the person standing beside
  a cell is not that cell seen free). A caller that updates slower than the frames can give
  the frames between to :meth:`Replay.see` (the STVL replays do; the VoxelLayer's 5 Hz runs
  send the node every 6th frame only and score the update frames, which is stricter);
- ``frames_to_clear``: after the person left the view (``person_in_view`` false), the frames
  at 30 Hz until no ghost is left, and ``ghost_after_10``: ghosts at the first update 10
  frames or more after;
- ``unknown_seen``: master cells NO_INFORMATION whose truth is known (what DWB refuses);
- ``kept``: of the true obstacle cells marked (within one cell) while in view, the share still
  marked (within one cell) in the updates after they left the view (not in the frame's
  truth) while inside the window, pooled over updates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import nav2_layers as nav2
import numpy as np

from obstacle_detection.evaluation import metrics
from obstacle_detection.labels import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN
from obstacle_detection.sim.sequences import PITCH_PHASES_DEG, BodyPitch

#: Sequence frame rate [Hz] and the ghost budget after the person left [frames].
RATE_HZ = 30.0
CLEAR_BUDGET_FRAMES = 10


@dataclass(frozen=True)
class UpdateInput:
    """What the costmap gets at one update, and the truth of that moment.

    index: frame index (30 Hz); pose: base in odom (x [m], y [m], yaw [rad]);
    obstacle_points (N, 3): the node's obstacles/points, base frame [m];
    clearing_points (M, 3): the node's obstacles/clearing_points, camera optical frame [m];
    truth_obstacle (O, 3), truth_free (T, 3): the frame's true points in the region of
    interest, base frame [m]; person_in_view: None when the sequence has no person;
    truth_person (P, 3): the true obstacle points on the person (a moving object: a cell it
    was last seen in, not seen since, has no known truth: the person may have left it);
    person_disc: the person's true footprint now, (x [m], y [m], radius [m]) in odom (the
    cells under it that the frame does not see have no known truth: it hides them);
    mount: (R, t) of the optical frame in base_footprint that TF gives at this instant (a
    TF following the body's true pitch); None: the replay's static URDF mount.
    """

    index: int
    pose: tuple[float, float, float]
    obstacle_points: np.ndarray
    clearing_points: np.ndarray
    truth_obstacle: np.ndarray
    truth_free: np.ndarray
    person_in_view: bool | None = None
    truth_person: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    person_disc: tuple[float, float, float] | None = None
    mount: tuple[np.ndarray, np.ndarray] | None = None


def rotation_z(yaw_rad: float) -> np.ndarray:
    """(3, 3) rotation about z by ``yaw_rad``."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _grow(mask: np.ndarray) -> np.ndarray:
    """``mask`` grown by one cell (3 x 3 neighbourhood)."""
    return cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


@dataclass
class _Counts:
    tp_pred: int = 0
    pred: int = 0
    tp_truth: int = 0
    truth: int = 0

    def f1(self) -> float:
        precision = self.tp_pred / self.pred if self.pred else math.nan
        recall = self.tp_truth / self.truth if self.truth else math.nan
        if not precision + recall > 0:
            return math.nan
        return 2 * precision * recall / (precision + recall)


@dataclass
class SequenceFigures:
    """What :meth:`Replay.report` returns for one layer over one sequence."""

    name: str
    layer: str
    updates: int
    f1: float
    f1_person: float
    ghost: list[int]
    stale_lethal_max: int
    unknown_seen_max: int
    kept: float
    kept_cells: int
    frames_to_clear: float
    ghost_after_10: float
    leave_frame: int | None
    extra: dict = field(default_factory=dict)


class Replay:
    """One Nav2 costmap (the ported layers) fed update by update, scored against the truth.

    config: the costmap configuration (:func:`nav2_layers.read_costmap`); mount: (R (3, 3),
    t (3,)) of the camera optical frame in base_footprint; poses: every pose of the run (the
    lattice holds the window around each).
    """

    def __init__(self, name: str, config: nav2.CostmapConfig,
                 mount: tuple[np.ndarray, np.ndarray], poses: list[tuple[float, float, float]],
                 layer_name: str = '') -> None:
        self.name = name
        self.layer_name = layer_name or config.layers[0].plugin.split('::')[-1]
        self.config = config
        self.layers = [nav2.make_layer(layer, config) for layer in config.layers]
        self.costmap = nav2.LayeredCostmap(config, self.layers)
        self.mount = mount
        res = config.resolution_m
        xy = np.asarray(poses, np.float64)[:, :2]
        reach = max(config.width_m, config.height_m)
        lo = np.floor((xy.min(axis=0) - reach) / res).astype(int)
        hi = np.ceil((xy.max(axis=0) + reach) / res).astype(int)
        self.lattice_cell = (int(lo[0]), int(lo[1]))
        self.shape = (int(hi[1] - lo[1]), int(hi[0] - lo[0]))
        self.res = res
        xs = (self.lattice_cell[0] + np.arange(self.shape[1]) + 0.5) * res
        ys = (self.lattice_cell[1] + np.arange(self.shape[0]) + 0.5) * res
        self.centre_x, self.centre_y = np.meshgrid(xs, ys)
        self.truth = np.full(self.shape, CELL_UNKNOWN, np.int8)
        self.marked_in_view = np.zeros(self.shape, bool)
        self.person_cells = np.zeros(self.shape, bool)
        self.free_since = np.full(self.shape, np.iinfo(np.int64).max, np.int64)
        self.counts = _Counts()
        self.counts_person = _Counts()
        self.ghost: list[int] = []
        self.ghost_frames: list[int] = []
        self.stale_max = 0
        self.unknown_max = 0
        self.kept_hits = self.kept_total = 0
        self.leave_frame: int | None = None
        self.sources = {s.name: s for layer in config.layers for s in layer.sources}

    def _truth_grid(self, inp: UpdateInput) -> tuple[np.ndarray, np.ndarray]:
        """Return the frame's truth on the lattice (CELL_*) and the cells of its person."""
        rot, t = rotation_z(inp.pose[2]), np.array([inp.pose[0], inp.pose[1], 0.0])
        origin = (self.lattice_cell[0] * self.res, self.lattice_cell[1] * self.res)
        grid = metrics.truth_grid(inp.truth_obstacle @ rot.T + t, inp.truth_free @ rot.T + t,
                                  origin, self.res, self.shape)
        person = metrics.point_cells(inp.truth_person @ rot.T + t, origin, self.res, self.shape)
        return grid, person & (grid == CELL_OCCUPIED)

    def _observations(self, inp: UpdateInput) -> dict[str, nav2.Observation]:
        """Put the clouds through 'TF': base_footprint and the optical frame into odom."""
        base_rot = rotation_z(inp.pose[2])
        base_t = np.array([inp.pose[0], inp.pose[1], 0.0])
        mount = self.mount if inp.mount is None else inp.mount
        cam_rot = base_rot @ mount[0]
        cam_t = base_t + base_rot @ mount[1]
        out = {}
        for name, source in self.sources.items():
            # marks: the VoxelLayer's obstacles/marking_points, or obstacles/points as seen
            if source.topic.lstrip('/') in ('obstacles/marking_points', 'obstacles/points'):
                out[name] = nav2.buffer_cloud(inp.obstacle_points, base_rot, base_t, source)
            elif source.topic.lstrip('/') == 'obstacles/clearing_points':
                out[name] = nav2.buffer_cloud(inp.clearing_points, cam_rot, cam_t, source)
            else:
                raise ValueError(f'{source.name}: topic {source.topic!r} is not a cloud of '
                                 'the node')
            if source.sensor_frame:
                raise ValueError(f'{source.name}: sensor_frame {source.sensor_frame!r}: '
                                 'this replay knows the clouds\' own frames only')
        return out

    def _window(self, master: np.ndarray) -> tuple[slice, slice]:
        ox, oy = self.costmap.origin_xy_m
        c0 = round(ox / self.res) - self.lattice_cell[0]
        r0 = round(oy / self.res) - self.lattice_cell[1]
        ny, nx = master.shape
        if c0 < 0 or r0 < 0 or r0 + ny > self.shape[0] or c0 + nx > self.shape[1]:
            raise ValueError('the costmap window left the scoring lattice')
        return slice(r0, r0 + ny), slice(c0, c0 + nx)

    def _note_free(self, frame_truth: np.ndarray, index: int) -> np.ndarray:
        """Update since when each cell is seen free with no true obstacle within one cell."""
        free_now = (frame_truth == CELL_FREE) & ~_grow(frame_truth == CELL_OCCUPIED)
        self.free_since = np.where(free_now, np.minimum(self.free_since, index),
                                   np.iinfo(np.int64).max)
        return free_now

    def see(self, inp: UpdateInput) -> None:
        """Take a frame between updates into the seen-free history (no costmap update)."""
        self._note_free(self._truth_grid(inp)[0], inp.index)

    def step(self, inp: UpdateInput) -> np.ndarray:
        """Run one costmap update and score it; returns the master grid (window, Nav2 costs)."""
        master = self.costmap.update(inp.pose, self._observations(inp))
        frame_truth, person_now = self._truth_grid(inp)
        seen = frame_truth != CELL_UNKNOWN
        self.truth[seen] = frame_truth[seen]
        self.person_cells[seen] = person_now[seen]
        rows, cols = self._window(master)
        lethal = np.zeros(self.shape, bool)
        lethal[rows, cols] = master == nav2.LETHAL_OBSTACLE
        in_window = np.zeros(self.shape, bool)
        in_window[rows, cols] = True
        hidden = self.person_cells & ~seen
        if inp.person_disc is not None:
            px, py, radius = inp.person_disc
            reach = radius + self.res / math.sqrt(2.0)   # cells that overlap the disc
            hidden |= (np.hypot(self.centre_x - px, self.centre_y - py) <= reach) & ~seen
        known = (self.truth != CELL_UNKNOWN) & in_window & ~hidden
        occupied = (self.truth == CELL_OCCUPIED) & known
        near_occupied = _grow(occupied)
        near_lethal = _grow(lethal)
        for counts in (self.counts, self.counts_person) if inp.person_in_view else (
                self.counts,):
            counts.pred += int(np.count_nonzero(lethal & known))
            counts.tp_pred += int(np.count_nonzero(lethal & known & near_occupied))
            counts.truth += int(np.count_nonzero(occupied))
            counts.tp_truth += int(np.count_nonzero(occupied & near_lethal))
        free = (self.truth == CELL_FREE) & known & ~near_occupied
        ghost = lethal & free
        self.ghost.append(int(np.count_nonzero(ghost)))
        self.ghost_frames.append(inp.index)
        free_now = self._note_free(frame_truth, inp.index)
        seen_free_long = free_now & (inp.index - self.free_since >= CLEAR_BUDGET_FRAMES)
        self.stale_max = max(self.stale_max, int(np.count_nonzero(ghost & seen_free_long)))
        window_unknown = np.zeros(self.shape, bool)
        window_unknown[rows, cols] = master == nav2.NO_INFORMATION
        self.unknown_max = max(self.unknown_max, int(np.count_nonzero(window_unknown & known)))
        # memory: marked while in view, then out of view
        occupied_now = frame_truth == CELL_OCCUPIED
        out_of_view = self.marked_in_view & ~seen & occupied
        self.kept_total += int(np.count_nonzero(out_of_view))
        self.kept_hits += int(np.count_nonzero(out_of_view & near_lethal))
        self.marked_in_view |= occupied_now & near_lethal
        if inp.person_in_view is False and self.leave_frame is None:
            self.leave_frame = inp.index
        elif inp.person_in_view:
            self.leave_frame = None
        return master

    def report(self) -> SequenceFigures:
        """Return the figures of the updates so far (see the module's docstring)."""
        frames_to_clear = ghost_after = math.nan
        if self.leave_frame is not None:
            after = [(f, g) for f, g in zip(self.ghost_frames, self.ghost)
                     if f >= self.leave_frame]
            clean = [f for i, (f, _) in enumerate(after) if all(g == 0 for _, g in after[i:])]
            frames_to_clear = clean[0] - self.leave_frame if clean else math.inf
            later = [g for f, g in after if f >= self.leave_frame + CLEAR_BUDGET_FRAMES]
            ghost_after = later[0] if later else math.nan
        return SequenceFigures(
            name=self.name, layer=self.layer_name, updates=len(self.ghost),
            f1=self.counts.f1(), f1_person=self.counts_person.f1(), ghost=self.ghost,
            stale_lethal_max=self.stale_max, unknown_seen_max=self.unknown_max,
            kept=self.kept_hits / self.kept_total if self.kept_total else math.nan,
            kept_cells=self.kept_total, frames_to_clear=frames_to_clear,
            ghost_after_10=ghost_after, leave_frame=self.leave_frame)


def format_table(figures: list[SequenceFigures]) -> str:
    """One Markdown row per (sequence, layer)."""
    def num(value: float, digits: int = 3) -> str:
        return '-' if value is None or (isinstance(value, float) and math.isnan(value)) \
            else (f'{value:.{digits}f}' if isinstance(value, float) and value != math.inf
                  else str(value))

    lines = ['| sequence | layer | updates | F1 (1 cell) | F1 person in view | max ghost '
             '| ghosts 10 frames after leaving | frames to clear | max stale lethal | max '
             'unknown seen | kept out of view |',
             '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
    for f in figures:
        kept = f'{num(f.kept)} ({f.kept_cells} cell-updates)' if f.kept_cells else '-'
        lines.append(f'| {f.name} | {f.layer} | {f.updates} | {num(f.f1)} | '
                     f'{num(f.f1_person)} | {max(f.ghost, default=0)} | '
                     f'{num(f.ghost_after_10, 0)} | {num(f.frames_to_clear, 0)} | '
                     f'{f.stale_lethal_max} | {f.unknown_seen_max} | {kept} |')
    return '\n'.join(lines)


def camera_mount(values: dict) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)): the camera optical frame in base_footprint, from the node's mount.

    values: the node's parameters (camera_x_m, camera_y_m, camera_height_m, camera_roll_deg,
    camera_pitch_deg, camera_yaw_deg), as a URDF would give TF.
    """
    from obstacle_detection.pipeline.geometry import mount_rotation

    rot = rotation_z(math.radians(float(values.get('camera_yaw_deg', 0.0)))) @ mount_rotation(
        math.radians(float(values.get('camera_pitch_deg', 0.0))),
        math.radians(float(values.get('camera_roll_deg', 0.0))))
    t = np.array([float(values.get('camera_x_m', 0.0)), float(values.get('camera_y_m', 0.0)),
                  float(values['camera_height_m'])])
    return rot, t


#: The held-out URDF error (issue 29): the emulated TF's camera pitched 1.5 deg more (down)
#: and 3 cm higher than the true mount, while the node's parameters are right.
URDF_ERROR = {'camera_pitch_deg': 1.5, 'camera_height_m': 0.03}


def urdf_off(values: dict, error: dict = URDF_ERROR) -> dict:
    """Return mount parameter values with ``error`` added (a URDF slightly off)."""
    return {**values, **{k: float(values[k]) + v for k, v in error.items()}}


@dataclass(frozen=True)
class Run:
    """One scored run: a rendered sequence and the URDF the emulated TF uses.

    body_pitch: the body rocking under the camera (rendered pitched; the URDF, odometry and
    truth do not see it); urdf_error: mount errors of the URDF (:func:`urdf_off`) while the
    rendering and the node's parameters keep the true mount.
    """

    name: str
    sequence: str
    body_pitch: BodyPitch | None = None
    urdf_error: dict | None = None

    @property
    def frames_key(self) -> tuple[str, BodyPitch | None]:
        """What its frames depend on: runs with the same key play the same frames."""
        return (self.sequence, self.body_pitch)


#: The held-out drive with the body pitching +-2 deg (each phase of PITCH_PHASES_DEG) and with
#: a URDF 1.5 deg / 3 cm off (the level drive's frames).
HELD_OUT_DRIVES: tuple[Run, ...] = (
    *(Run(f'drive_by_table, pitching phase {phase:.0f}', 'drive_by_table',
          body_pitch=BodyPitch(amplitude_deg=2.0, period_s=1.2, phase_deg=phase))
      for phase in PITCH_PHASES_DEG),
    Run('drive_by_table, URDF 1.5 deg / 3 cm off', 'drive_by_table', urdf_error=URDF_ERROR),
)


def person_in_view(frame: object) -> bool | None:
    """Whether a rendered frame shows its person (a Cylinder); None when it has none."""
    from obstacle_detection.sim.scenes import Cylinder

    index = [i for i, p in enumerate(frame.primitives) if isinstance(p, Cylinder)]
    if not index:
        return None
    return bool(np.any((frame.hit_index == index[0]) & (frame.depth_mm > 0)))


def person_disc(sequence_frame: object) -> tuple[float, float, float] | None:
    """Return the person's footprint (x [m], y [m], radius [m]) in odom; None if none."""
    from obstacle_detection.sim.scenes import Cylinder

    for primitive in sequence_frame.frame.primitives:
        if isinstance(primitive, Cylinder):
            return (primitive.x_m, primitive.y_m, primitive.radius_m)
    return None


def frame_truth(sequence_frame: object, params: object,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(obstacle (O, 3), floor (T, 3), person (P, 3)) true base-frame points of a frame.

    The pixels the sensor returned whose true point lies in the detector's region of interest
    (``params``): obstacle points (``GT_OBSTACLE``, up to a cell beyond the far and side
    edges), traversable floor (``GT_TRAVERSABLE``;
    surfaces above the robot are left out: a wall whose foot is hidden behind a table is not
    free floor; so is floor under a Box lower than the robot, the floor under a table top: its
    column holds an obstacle whether or not the frame sees it), and the obstacle points on the
    person (a Cylinder), if any.
    """
    from obstacle_detection.labels import GT_OBSTACLE, GT_TRAVERSABLE
    from obstacle_detection.pipeline import geometry
    from obstacle_detection.sim.scenes import Cylinder

    frame = sequence_frame.frame
    points = frame.points_ground.reshape(-1, 3)
    labels = frame.labels.reshape(-1)
    finite = np.isfinite(points).all(axis=1)
    keep = finite.copy()
    keep[finite] = geometry.roi_mask(points[finite], params)
    # obstacles a cell beyond the region's far and side edges count too: the node's region is
    # measured from where it believes the camera is (a pitching body moves it 2 cm ahead), and
    # the wall it marks at its edge is no ghost
    cell = params.costmap_resolution_m
    wide = finite.copy()
    wide[finite] = geometry.roi_mask(points[finite], params.replace(
        max_range_m=params.max_range_m + cell, lateral_limit_m=params.lateral_limit_m + cell))
    person = np.zeros(labels.shape, bool)
    index = [i for i, p in enumerate(frame.primitives) if isinstance(p, Cylinder)]
    if index:
        person = frame.hit_index.reshape(-1) == index[0]
    obstacle = wide & (labels == GT_OBSTACLE)
    free = keep & (labels == GT_TRAVERSABLE)
    free[np.flatnonzero(free)[under_boxes(points[free], sequence_frame.pose_true,
                                          frame.primitives, params.robot_height_m)]] = False
    return points[obstacle], points[free], points[obstacle & person]


def under_boxes(points: np.ndarray, pose: tuple[float, float, float], primitives: tuple,
                robot_height_m: float) -> np.ndarray:
    """Return (N,) bool: the base-frame points under an obstacle Box lower than the robot.

    The column of such a point (a table top over the floor) holds an obstacle in the scene.
    """
    from obstacle_detection.sim.scenes import Box

    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    px, py = points[:, 0].astype(np.float64), points[:, 1].astype(np.float64)
    wx, wy = x + c * px - s * py, y + s * px + c * py      # in the scene frame (odom)
    covered = np.zeros(wx.shape, bool)
    for primitive in primitives:
        if isinstance(primitive, Box) and not primitive.traversable and \
                primitive.min_m[2] < robot_height_m:
            (x0, y0, _), (x1, y1, _) = primitive.min_m, primitive.max_m
            covered |= (wx >= x0) & (wx <= x1) & (wy >= y0) & (wy <= y1)
    return covered
