"""Pictures of a result: the depth frame with obstacles marked, the costmap from above (RGB)."""

from __future__ import annotations

from typing import Any

import numpy as np

from obstacle_detection.labels import CELL_UNKNOWN, LABEL_OBSTACLE
from obstacle_detection.pipeline.costmap import Costmap

#: Obstacle pixels in the depth overlay. The seed (figures 4.22-4.27) marks obstacles with black
#: dots, but black is also its colour for blind spots, so obstacles are drawn in red here.
OBSTACLE_RGB = (255, 0, 0)
#: Share of OBSTACLE_RGB in an obstacle pixel, the rest its depth grey: an object filling the
#: view (a cabinet 0.6 m ahead) keeps its edges and shading instead of becoming a red block.
OBSTACLE_ALPHA = 0.7
#: Pixels without a depth return (blind spots) in the depth overlay, as in the seed.
NO_RETURN_RGB = (0, 0, 0)
#: Darkest grey used for a valid depth (the nearest point), so that it differs from a blind spot.
MIN_GREY = 48

#: Costmap colours: occupied cells blue as in the seed's figure 4.21 (the non-navigable area),
#: free cells white, unknown cells mid grey, and the robot (camera foot point) in red.
OCCUPIED_RGB = (30, 60, 220)
FREE_RGB = (255, 255, 255)
UNKNOWN_RGB = (128, 128, 128)
ROBOT_RGB = (220, 0, 0)


def render_overlay(depth_m: np.ndarray, labels: np.ndarray, *,
                   max_depth_m: float | None = None) -> np.ndarray:
    """Draw the depth frame in grey (dark near, white at ``max_depth_m``), obstacles red over it.

    No return is black. Returns (H, W, 3) uint8 RGB.
    """
    depth = np.asarray(depth_m, dtype=np.float32)
    valid = np.isfinite(depth) & (depth > 0.0)
    if max_depth_m is None:
        max_depth_m = float(depth[valid].max()) if valid.any() else 1.0
    scaled = np.clip(np.where(valid, depth, 0.0) / np.float32(max_depth_m), 0.0, 1.0)
    grey = (MIN_GREY + scaled * (255 - MIN_GREY)).round().astype(np.uint8)
    grey[~valid] = 0
    rgb = np.repeat(grey[:, :, np.newaxis], 3, axis=2)
    rgb[~valid] = NO_RETURN_RGB
    obstacle = np.asarray(labels) == LABEL_OBSTACLE
    rgb[obstacle] = blend(OBSTACLE_RGB, rgb[obstacle], OBSTACLE_ALPHA)
    return rgb


def top_view(cells_yx: np.ndarray, scale: int) -> np.ndarray:
    """Grid cells [y, x] as seen from above: x forward up, y left to the left, scale px a cell."""
    view = np.swapaxes(cells_yx, 0, 1)[::-1, ::-1]
    return np.ascontiguousarray(np.repeat(np.repeat(view, scale, axis=0), scale, axis=1))


def blend(colour: Any, base: Any, share: Any) -> np.ndarray:
    """uint8 RGB: ``colour`` over ``base`` (RGB arrays or values, broadcast), ``share`` of it."""
    return (np.asarray(colour, np.float32) * share
            + np.asarray(base, np.float32) * (1.0 - share)).round().astype(np.uint8)


def costmap_pixel_of(costmap: Costmap, x_m: float, y_m: float, *,
                     scale: int = 4) -> tuple[float, float]:
    """Fractional (column, row) in ``render_costmap``'s image of the ground point (x, y) [m]."""
    col_cells = (costmap.origin_xy_m[1] + costmap.height * costmap.resolution_m - y_m)
    row_cells = (costmap.origin_xy_m[0] + costmap.width * costmap.resolution_m - x_m)
    return (col_cells / costmap.resolution_m * scale, row_cells / costmap.resolution_m * scale)


def render_costmap(costmap: Costmap, *, scale: int = 4) -> np.ndarray:
    """Draw the costmap from above (x forward up, y left to the left), ``scale`` px a cell."""
    data = np.asarray(costmap.data)
    cost = np.clip(data.astype(np.float32), 0.0, 100.0)[:, :, np.newaxis] / 100.0
    cells = blend(OCCUPIED_RGB, FREE_RGB, cost)
    cells[data <= CELL_UNKNOWN] = UNKNOWN_RGB
    return top_view(cells, scale)
