"""The replay's truth (test/nav2_replay.py): what it calls free floor next to the ROI's edge."""

from __future__ import annotations

from types import SimpleNamespace

import nav2_replay as replay
import numpy as np

from obstacle_detection.labels import GT_OBSTACLE, GT_TRAVERSABLE

#: the region of interest: 0-2 m ahead, 2 m each side, from 0.1 m below the floor to 1.4 m
PARAMS = SimpleNamespace(min_range_m=0.0, max_range_m=2.0, lateral_limit_m=2.0, tdbg_m=-0.1,
                         max_height_m=1.4, costmap_resolution_m=0.05)


def _cut(points: list[list[float]], labels: list[int]) -> list[bool]:
    pts = np.array(points, np.float32)
    lab = np.array(labels)
    keep = ((pts[:, 0] >= 0.0) & (pts[:, 0] <= 2.0) & (np.abs(pts[:, 1]) <= 2.0)
            & (pts[:, 2] >= -0.1) & (pts[:, 2] <= 1.4))
    free = keep & (lab == GT_TRAVERSABLE)
    return replay.beside_cut_obstacles(pts, lab, keep, free, PARAMS).tolist()


def test_floor_within_a_cell_of_a_face_just_past_the_range_is_not_free() -> None:
    floor = [[1.97, 0.50, 0.0], [1.90, 0.50, 0.0], [1.97, 0.70, 0.0], [1.00, 0.50, 0.0]]
    face = [[2.01, 0.50, 0.3], [2.30, 0.70, 0.3]]       # 1 cm past the range; 30 cm past

    cut = _cut(floor + face, [GT_TRAVERSABLE] * 4 + [GT_OBSTACLE] * 2)

    # within 5 cm (each axis) of the face at 2.01: the first floor point only
    assert cut == [True, False, False, False]


def test_floor_beside_an_obstacle_past_the_side_or_above_the_band_stays_free() -> None:
    floor = [[1.00, 1.97, 0.0], [1.98, 0.0, 0.0]]
    cut_off = [[1.00, 2.02, 0.5],        # past the side by 2 cm: its floor is not free
               [2.01, 0.0, 1.60]]        # above the band (a shelf out of reach): it stays

    assert _cut(floor + cut_off, [GT_TRAVERSABLE] * 2 + [GT_OBSTACLE] * 2) == [True, False]


def test_nothing_cut_leaves_every_floor_point_free() -> None:
    assert _cut([[1.97, 0.5, 0.0], [1.5, 0.0, 0.3]], [GT_TRAVERSABLE, GT_OBSTACLE]) == [False]
