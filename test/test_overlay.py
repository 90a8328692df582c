"""Tests of the result pictures: depth overlay and costmap top view."""

from __future__ import annotations

import numpy as np
import pytest

from obstacle_detection.labels import (CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN, LABEL_GROUND,
                                       LABEL_NO_RETURN, LABEL_OBSTACLE, LABEL_OUTSIDE_ROI)
from obstacle_detection.pipeline.costmap import Costmap
from obstacle_detection.viz.overlay import (
    FREE_RGB,
    OCCUPIED_RGB,
    UNKNOWN_RGB,
    costmap_pixel_of,
    render_costmap,
    render_overlay,
)

from eval_helpers import is_obstacle_rgb


def _frame() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    depth = rng.uniform(0.5, 4.0, size=(20, 30)).astype(np.float32)
    labels = np.full(depth.shape, LABEL_GROUND, dtype=np.uint8)
    labels[:, :5] = LABEL_OUTSIDE_ROI
    labels[5:9, 10:14] = LABEL_OBSTACLE
    depth[15:, 20:] = 0.0
    depth[0, 29] = np.nan
    labels[15:, 20:] = LABEL_NO_RETURN
    labels[0, 29] = LABEL_NO_RETURN
    return depth, labels


def test_overlay_marks_obstacle_pixels() -> None:
    depth, labels = _frame()

    rgb = render_overlay(depth, labels)

    assert rgb.shape == (20, 30, 3) and rgb.dtype == np.uint8
    assert is_obstacle_rgb(rgb[labels == LABEL_OBSTACLE]).all()
    assert not is_obstacle_rgb(rgb[labels != LABEL_OBSTACLE]).any()


def test_overlay_other_pixels_are_grey() -> None:
    depth, labels = _frame()

    rgb = render_overlay(depth, labels)

    others = rgb[labels != LABEL_OBSTACLE]
    assert (others[:, 0] == others[:, 1]).all() and (others[:, 1] == others[:, 2]).all()


def test_overlay_blind_spots_are_black_and_valid_depth_is_not() -> None:
    depth, labels = _frame()

    rgb = render_overlay(depth, labels)

    assert (rgb[15:, 20:] == 0).all() and (rgb[0, 29] == 0).all()
    valid = np.isfinite(depth) & (depth > 0) & (labels != LABEL_OBSTACLE)
    assert (rgb[valid][:, 0] > 0).all()


def test_overlay_near_is_darker_than_far() -> None:
    depth = np.array([[0.5, 1.0, 2.0, 4.0]], dtype=np.float32)
    labels = np.full(depth.shape, LABEL_GROUND, dtype=np.uint8)

    grey = render_overlay(depth, labels)[0, :, 0]

    assert (np.diff(grey.astype(int)) > 0).all()
    assert grey[-1] == 255


def test_overlay_max_depth_saturates() -> None:
    depth = np.array([[1.0, 3.0, 6.0]], dtype=np.float32)
    labels = np.zeros(depth.shape, dtype=np.uint8)

    grey = render_overlay(depth, labels, max_depth_m=3.0)[0, :, 0]

    assert grey[1] == 255 and grey[2] == 255 and grey[0] < 255


def _costmap() -> Costmap:
    # nx = 8 cells forward (x from 0 to 0.8 m), ny = 6 across (y from -0.3 to 0.3 m).
    data = np.full((6, 8), CELL_UNKNOWN, dtype=np.int8)
    return Costmap(data=data, resolution_m=0.1, origin_xy_m=(0.0, -0.3))


def _pixel_colour(image: np.ndarray, costmap: Costmap, x_m: float, y_m: float,
                  scale: int) -> tuple[int, ...]:
    col, row = costmap_pixel_of(costmap, x_m, y_m, scale=scale)
    return tuple(int(v) for v in image[int(row), int(col)])


def test_costmap_colours() -> None:
    costmap = _costmap()
    costmap.data[1, 6] = CELL_OCCUPIED  # x = 0.65, y = -0.15
    costmap.data[4, 3] = CELL_FREE      # x = 0.35, y = 0.15

    image = render_costmap(costmap, scale=3)

    assert image.shape == (8 * 3, 6 * 3, 3) and image.dtype == np.uint8
    assert _pixel_colour(image, costmap, 0.65, -0.15, 3) == OCCUPIED_RGB
    assert _pixel_colour(image, costmap, 0.35, 0.15, 3) == FREE_RGB
    assert _pixel_colour(image, costmap, 0.05, 0.25, 3) == UNKNOWN_RGB
    assert (image == OCCUPIED_RGB).all(axis=2).sum() == 9


def test_costmap_forward_is_up_and_left_is_left() -> None:
    costmap = _costmap()
    costmap.data[3, 7] = CELL_OCCUPIED  # far forward (x = 0.75), just left of centre (y = 0.05)
    costmap.data[0, 0] = CELL_OCCUPIED  # near (x = 0.05), far right (y = -0.25)

    image = render_costmap(costmap, scale=2)

    occupied = np.argwhere((image == OCCUPIED_RGB).all(axis=2))
    robot = costmap_pixel_of(costmap, 0.0, 0.0, scale=2)[::-1]   # (row, col) of the camera
    far_left = occupied[occupied[:, 0] < 2]       # top rows: the farthest x cells
    near_right = occupied[occupied[:, 0] >= 2]
    assert len(far_left) == 4 and len(near_right) == 4
    assert far_left[:, 0].max() < robot[0]        # forward cell is above the robot
    assert near_right[:, 1].min() > robot[1]      # right-hand cell (y < 0) is right of it
    assert far_left[:, 1].max() <= robot[1] + 1   # the y > 0 cell is on the left half
    assert robot[0] == pytest.approx(image.shape[0])   # the camera at x = 0: the bottom edge
