"""The fused local costmap: per-frame costmaps accumulated as log-odds in the odometry frame.

The rules, the defaults and their measurement: docs/fused_costmap.md.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..labels import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN
from .costmap import Costmap

#: Largest window side [cells]: 2000 x 2000 float32 log-odds are 16 MB.
MAX_CELLS_PER_SIDE = 2000

#: Odometry poses a PoseBuffer keeps.
POSE_CAPACITY = 256
#: A pose: base frame in odom, (x [m], y [m], yaw [rad]).
Pose = tuple[float, float, float]


@dataclass(frozen=True)
class FusionParams:
    """Parameters of the fused costmap (docs/fused_costmap.md); ValueError when out of range."""

    size_m: float = 4.0
    resolution_m: float = 0.05
    hit_log_odds: float = 1.0
    miss_log_odds: float = -0.4
    min_log_odds: float = -1.0
    max_log_odds: float = 2.4
    occupied_log_odds: float = 0.5
    free_log_odds: float = -0.2
    max_jump_m: float = 0.5
    max_jump_deg: float = 45.0

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value):
                raise ValueError(f'FusionParams: {name}={value!r} must be a finite number')
        rules = [(f'{name} > 0', getattr(self, name) > 0.0) for name in (
            'size_m', 'resolution_m', 'hit_log_odds', 'max_log_odds', 'max_jump_m',
            'max_jump_deg')]
        rules += [(f'{name} < 0', getattr(self, name) < 0.0)
                  for name in ('miss_log_odds', 'min_log_odds')]
        rules += [('resolution_m must not exceed size_m', self.resolution_m <= self.size_m),
                  ('min_log_odds <= free_log_odds < 0',
                   self.min_log_odds <= self.free_log_odds < 0.0),
                  ('0 < occupied_log_odds <= max_log_odds',
                   0.0 < self.occupied_log_odds <= self.max_log_odds),
                  ('max_jump_deg <= 180', self.max_jump_deg <= 180.0)]
        for rule, holds in rules:
            if not holds:
                raise ValueError(f'FusionParams: {rule} does not hold in {self}')
        if self.cells > MAX_CELLS_PER_SIDE:
            raise ValueError(f'FusionParams: size_m={self.size_m!r} at resolution_m='
                             f'{self.resolution_m!r} is {self.cells} cells a side, more than '
                             f'{MAX_CELLS_PER_SIDE}')

    @property
    def cells(self) -> int:
        """Cells per side of the window."""
        return max(1, int(math.ceil(self.size_m / self.resolution_m - 1e-9)))

    def frames_to_mark(self) -> int:
        """Frames of hits that mark a cell that was unknown (log-odds 0)."""
        return int(math.ceil(self.occupied_log_odds / self.hit_log_odds - 1e-9))

    def frames_to_clear(self) -> int:
        """Frames of seen ground that clear a cell at the upper clamp."""
        return int(math.floor((self.max_log_odds - self.occupied_log_odds)
                              / -self.miss_log_odds + 1e-9)) + 1


@dataclass(frozen=True)
class FusionUpdate:
    """What one :meth:`FusedGrid.update` did; message: a log line when the state changed."""

    pose: Pose
    in_place: bool
    reset: bool
    reason: str = ''
    message: str = ''
    warning: bool = False


def _wrap_angle(angle_rad: float) -> float:
    """Angle wrapped into [-pi, pi) [rad]."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def _check_pose(pose: object) -> str:
    """'' when ``pose`` is a usable (x, y, yaw), else what is wrong with it."""
    try:
        values = tuple(float(v) for v in pose)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        values = ()
    if len(values) != 3:
        return f'pose {pose!r} is not (x, y, yaw)'
    return '' if all(math.isfinite(v) for v in values) else f'pose {values!r} is not finite'


def frame_evidence(costmap: Costmap, pose: Pose, origin_cell: tuple[int, int],
                   cells: tuple[int, int], resolution_m: float,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Where a per-frame costmap puts evidence in an odom window: (hit, miss) (ny, nx) bool.

    The window's cell (0, 0) is odom-lattice cell ``origin_cell``; cells: (nx, ny).
    """
    nx, ny = cells
    res = float(resolution_m)
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    # window cell centres relative to the robot, odom axes
    dx = (origin_cell[0] + np.arange(nx) + 0.5) * res - x
    dy = (origin_cell[1] + np.arange(ny) + 0.5) * res - y
    # into the base frame: R(-yaw) (p - t), then the costmap's cells
    base = np.stack((np.add.outer(s * dy, c * dx), np.add.outer(c * dy, -s * dx)), axis=-1)
    row, col, inside = costmap.cell_of(base.reshape(-1, 2))
    value = np.full(nx * ny, CELL_UNKNOWN, dtype=np.int8)
    value[inside] = costmap.data[row[inside], col[inside]]
    hit = (value == CELL_OCCUPIED).reshape(ny, nx)
    miss = (value == CELL_FREE).reshape(ny, nx)
    # splat the occupied cells' centres so that none falls between window cell centres
    occ_row, occ_col = np.nonzero(costmap.data == CELL_OCCUPIED)
    if occ_row.size:
        fres = float(costmap.resolution_m)
        bx = float(costmap.origin_xy_m[0]) + (occ_col + 0.5) * fres
        by = float(costmap.origin_xy_m[1]) + (occ_row + 0.5) * fres
        wc = np.floor((x + c * bx - s * by) / res).astype(np.int64) - origin_cell[0]
        wr = np.floor((y + s * bx + c * by) / res).astype(np.int64) - origin_cell[1]
        ok = (wc >= 0) & (wc < nx) & (wr >= 0) & (wr < ny)
        hit[wr[ok], wc[ok]] = True
        miss[wr[ok], wc[ok]] = False
    return hit, miss


class FusedGrid:
    """A rolling log-odds grid centred on the robot in the odometry frame (one thread)."""

    def __init__(self, params: FusionParams | None = None) -> None:
        self.params = params if params is not None else FusionParams()
        n = self.params.cells
        self._log_odds = np.zeros((n, n), dtype=np.float32)
        self._origin_cell = (-(n // 2), -(n // 2))   # robot at the odom origin until a pose
        self._pose: Pose | None = None          # last pose used (None: none yet)
        self._pose_stamp_s: float | None = None
        self._in_place_kind: str | None = None   # why the last frame fused in place, '' if not

    @property
    def origin_cell(self) -> tuple[int, int]:
        """Odom-lattice (column, row) of the window's cell (0, 0)."""
        return self._origin_cell

    @property
    def origin_xy_m(self) -> tuple[float, float]:
        """Odom (x, y) of the outer corner of cell (0, 0) [m] (the OccupancyGrid origin)."""
        res = self.params.resolution_m
        return (self._origin_cell[0] * res, self._origin_cell[1] * res)

    @property
    def pose(self) -> Pose | None:
        """The last pose a frame was fused at (None before the first frame)."""
        return self._pose

    @property
    def log_odds(self) -> np.ndarray:
        """(n, n) float32 log-odds per cell (a read-only view)."""
        view = self._log_odds.view()
        view.flags.writeable = False
        return view

    def _centred_origin(self, x_m: float, y_m: float) -> tuple[int, int]:
        """Window origin cell that puts the odom point (x, y) in the centre cell."""
        res = self.params.resolution_m
        half = self.params.cells // 2
        return (int(math.floor(x_m / res)) - half, int(math.floor(y_m / res)) - half)

    def cell_of(self, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, inside) of odom points xy (M, 2) [m] in the window."""
        xy_m = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        res = self.params.resolution_m
        col = np.floor(xy_m[:, 0] / res).astype(np.int64) - self._origin_cell[0]
        row = np.floor(xy_m[:, 1] / res).astype(np.int64) - self._origin_cell[1]
        n = self.params.cells
        return row, col, (col >= 0) & (col < n) & (row >= 0) & (row < n)

    def cell_states(self) -> np.ndarray:
        """(n, n) int8: 100 occupied, 0 free, -1 unknown, from the log-odds thresholds."""
        p = self.params
        out = np.full(self._log_odds.shape, CELL_UNKNOWN, dtype=np.int8)
        out[self._log_odds <= p.free_log_odds] = CELL_FREE
        out[self._log_odds >= p.occupied_log_odds] = CELL_OCCUPIED
        return out

    def to_costmap(self) -> Costmap:
        """Return the fused grid as a :class:`Costmap` in odom (publish it in frame ``odom``)."""
        return Costmap(self.cell_states(), self.params.resolution_m, self.origin_xy_m)

    def values_at(self, xy_m: np.ndarray) -> np.ndarray:
        """(M,) int8 cell states at odom points xy (M, 2) [m]; -1 outside the window."""
        row, col, inside = self.cell_of(xy_m)
        out = np.full(row.shape, CELL_UNKNOWN, dtype=np.int8)
        out[inside] = self.cell_states()[row[inside], col[inside]]
        return out

    def _scroll_to(self, origin: tuple[int, int]) -> None:
        """Move the window's origin to ``origin``; the cells that leave it are forgotten."""
        d_col = origin[0] - self._origin_cell[0]
        d_row = origin[1] - self._origin_cell[1]
        if d_col or d_row:
            # whole cells: new[r, c] = old[r + d_row, c + d_col], 0 from outside the old window
            self._log_odds = ndimage.shift(self._log_odds, (-d_row, -d_col), order=0, cval=0.0,
                                           prefilter=False)
            self._origin_cell = origin

    def _reanchor(self, old: Pose, new: Pose) -> int:
        """Re-express the map with the robot at ``new`` (was ``old``, not moved); cells lost."""
        n = self.params.cells
        res = self.params.resolution_m
        origin = self._centred_origin(new[0], new[1])
        centres = (np.arange(n) + 0.5) * res
        gx = origin[0] * res + centres - new[0]       # (n,) new odom, relative to the robot
        gy = origin[1] * res + centres - new[1]
        d_yaw = old[2] - new[2]
        c, s = math.cos(d_yaw), math.sin(d_yaw)
        old_xy = np.stack((old[0] + np.add.outer(-s * gy, c * gx),   # (n, n): [row, col]
                           old[1] + np.add.outer(c * gy, s * gx)), axis=-1)
        row, col, inside = self.cell_of(old_xy)
        before = int(np.count_nonzero(self._log_odds))
        moved = np.zeros(n * n, np.float32)
        moved[inside] = self._log_odds[row[inside], col[inside]]
        self._log_odds = moved.reshape(n, n)
        self._origin_cell = origin
        return max(0, before - int(np.count_nonzero(moved)))

    def update(self, costmap: Costmap, pose: Pose | None, *,
               pose_stamp_s: float | None = None, no_pose_reason: str = '') -> FusionUpdate:
        """Fuse one frame's costmap (base frame) taken at base pose ``pose`` (x, y, yaw) in odom.

        Without a usable pose, or an older one: fused in place.
        """
        p = self.params
        if pose is None:
            kind, reason = 'missing', no_pose_reason or 'no odometry'
        else:
            kind, reason = 'invalid', _check_pose(pose)
        if not reason and pose_stamp_s is not None and self._pose_stamp_s is not None and \
                pose_stamp_s < self._pose_stamp_s:
            kind = 'old'
            reason = (f'odometry pose {self._pose_stamp_s - pose_stamp_s:.3f} s older than '
                      f'the last one used')
        message, warning, reset = '', False, False
        if reason:   # fuse in place; say so once per kind of cause
            used = self._pose if self._pose is not None else (0.0, 0.0, 0.0)
            if kind != self._in_place_kind:
                message = f'fused costmap: {reason}: fusing in place'
                warning = True
            self._in_place_kind = kind
            if self._pose is None:
                self._origin_cell = self._centred_origin(0.0, 0.0)
        else:
            used = (float(pose[0]), float(pose[1]), _wrap_angle(float(pose[2])))
            if self._in_place_kind:
                message = 'fused costmap: odometry received, the map follows it'
            self._in_place_kind = ''
            if self._pose is not None:
                jump_m = math.hypot(used[0] - self._pose[0], used[1] - self._pose[1])
                jump_deg = abs(math.degrees(_wrap_angle(used[2] - self._pose[2])))
                if jump_m > p.max_jump_m or jump_deg > p.max_jump_deg:
                    reset = True
                    forgotten = self._reanchor(self._pose, used)
                    reason = (f'odometry jumped {jump_m:.2f} m, {jump_deg:.1f} deg in one '
                              f'frame (limits {p.max_jump_m:g} m, {p.max_jump_deg:g} deg)')
                    message = (f'fused costmap: {reason}: odometry reset, map re-anchored '
                               f'on the new pose ({forgotten} cells lost)')
                    warning = True
            if pose_stamp_s is not None:
                self._pose_stamp_s = float(pose_stamp_s)
        if not reset:
            self._scroll_to(self._centred_origin(used[0], used[1]))
        self._pose = used
        n = p.cells
        hit, miss = frame_evidence(costmap, used, self._origin_cell, (n, n), p.resolution_m)
        grid = self._log_odds
        grid[hit] += np.float32(p.hit_log_odds)
        grid[miss] += np.float32(p.miss_log_odds)
        np.clip(grid, np.float32(p.min_log_odds), np.float32(p.max_log_odds), out=grid)
        return FusionUpdate(pose=used, in_place=bool(reason) and not reset, reset=reset,
                            reason=reason, message=message, warning=warning)


class PoseBuffer:
    """Recent odometry poses by time (thread-safe); the pose at a frame's stamp."""

    def __init__(self, max_age_s: float = 0.2) -> None:
        self.max_age_s = max_age_s
        self._items: deque[tuple[float, Pose]] = deque(maxlen=POSE_CAPACITY)
        self._lock = threading.Lock()

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)

    def add(self, stamp_s: float, pose: Pose) -> str:
        """Store a pose; return '' or why it was refused (not finite, older than the newest)."""
        problem = _check_pose(pose)
        if problem:
            return problem
        if not math.isfinite(stamp_s):
            return f'stamp {stamp_s!r} is not finite'
        with self._lock:
            if self._items and stamp_s <= self._items[-1][0]:
                return (f'odometry stamp {stamp_s:.3f} s not newer than the last one '
                        f'({self._items[-1][0]:.3f} s)')
            self._items.append((float(stamp_s), tuple(float(v) for v in pose)))  # type: ignore
        return ''

    def pose_at(self, stamp_s: float) -> tuple[Pose | None, str]:
        """(pose at ``stamp_s``, '') or (None, why there is none)."""
        with self._lock:
            items = list(self._items)
        if not items:
            return None, 'no odometry received'
        newest_s, newest = items[-1]
        if stamp_s >= newest_s:
            late = stamp_s - newest_s
            if late <= self.max_age_s:
                return newest, ''
            return None, (f'odometry late: the newest pose is {late:.3f} s older than the '
                          f'frame (limit {self.max_age_s:g} s)')
        oldest_s = items[0][0]
        if stamp_s < oldest_s:
            return None, (f'frame {oldest_s - stamp_s:.3f} s older than the oldest odometry '
                          f'pose kept')
        stamps = np.fromiter((item[0] for item in items), dtype=np.float64)
        i = int(np.searchsorted(stamps, stamp_s, side='right'))  # stamps[i-1] <= t < stamps[i]
        (t0, a), (t1, b) = items[i - 1], items[i]
        w = (stamp_s - t0) / (t1 - t0)
        yaw = a[2] + w * _wrap_angle(b[2] - a[2])
        return (a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), _wrap_angle(yaw)), ''
