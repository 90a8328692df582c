"""The scoring of test/nav2_replay.py: when a lethal cell counts as seen free floor left lethal.

A stand-in costmap returns a chosen master grid, so the figures come from the scoring alone.
"""

from __future__ import annotations

import nav2_layers as nav2
import nav2_replay as replay
import numpy as np
import ros_env

NAV2_YAML = ros_env.REPO_ROOT / 'params' / 'nav2_costmap.yaml'
CELL = (1.025, 0.025)          # the cell held lethal: centre [m], base = odom
BESIDE = (1.075, 0.025)        # the next cell in x
ORIGIN = (-3.0, -3.0)          # the stand-in window's corner [m]


class _HeldCostmap:
    """A costmap whose master grid holds one cell lethal, whatever it is fed."""

    def __init__(self, res: float, size_m: float) -> None:
        n = round(size_m / res)
        self.master = np.zeros((n, n), np.uint8)
        self.master[round((CELL[1] - ORIGIN[1]) / res - 0.5),
                    round((CELL[0] - ORIGIN[0]) / res - 0.5)] = nav2.LETHAL_OBSTACLE
        self.origin_xy_m = ORIGIN

    def update(self, pose: tuple, observations: dict) -> np.ndarray:
        return self.master


def _replay() -> replay.Replay:
    config = nav2.read_costmap(NAV2_YAML)
    r = replay.Replay('held', config, (np.eye(3), np.zeros(3)), [(0.0, 0.0, 0.0)])
    r.costmap = _HeldCostmap(config.resolution_m, config.width_m)
    return r


def _frame(index: int, obstacle_at: tuple[float, float] | None) -> replay.UpdateInput:
    """Floor seen over 0.8-1.3 m x -0.2-0.2 m, with an obstacle point in one cell or none."""
    xs, ys = np.meshgrid(np.arange(0.8125, 1.3, 0.025), np.arange(-0.1875, 0.2, 0.025))
    floor = np.column_stack((xs.ravel(), ys.ravel(), np.zeros(xs.size)))
    obstacle = np.zeros((0, 3)) if obstacle_at is None else np.array([[*obstacle_at, 0.3]])
    if obstacle_at is not None:     # the floor of the obstacle's cell is not seen
        floor = floor[np.floor(floor[:, 0] / 0.05) != np.floor(obstacle_at[0] / 0.05)]
    empty = np.zeros((0, 3))
    return replay.UpdateInput(index=index, pose=(0.0, 0.0, 0.0), obstacle_points=empty,
                              clearing_points=empty, truth_obstacle=obstacle, truth_free=floor)


def _stale(obstacles: list[tuple[float, float] | None], period: int = 1) -> int:
    r = _replay()
    for index, at in enumerate(obstacles):
        frame = _frame(index, at)
        if index % period == 0:
            r.step(frame)
        else:
            r.see(frame)
    return r.report().stale_lethal_max


def test_a_cell_seen_free_for_10_frames_and_lethal_is_stale() -> None:
    assert _stale([CELL] * 3 + [None] * 14) == 1


def test_a_cell_with_an_obstacle_beside_it_until_lately_is_not_stale() -> None:
    # the one-cell tolerance: a mark beside the obstacle counts as right, so the obstacle
    # standing in the next cell is not this cell seen free
    assert _stale([BESIDE] * 8 + [None] * 9) == 0
    assert _stale([BESIDE] * 8 + [None] * 11) == 1


def test_the_frames_between_slow_updates_count_for_seen_free() -> None:
    # updates every 6th frame: the obstacle in the cell at frames 7-10 falls between two
    # updates and still restarts the count
    obstacles = [None] * 7 + [CELL] * 4 + [None] * 8
    assert _stale(obstacles, period=6) == 0
    assert _stale([None] * 19, period=6) == 1
