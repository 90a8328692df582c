"""Pictures of what the detector saw, without ROS running: PNG panels and contact sheets.

All images are RGB uint8; how they are drawn: docs/pictures.md.
"""

from __future__ import annotations

import math

from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from obstacle_detection.labels import GT_NO_RETURN, GT_OBSTACLE, LABEL_GROUND, LABEL_OBSTACLE
from .overlay import (MIN_GREY, NO_RETURN_RGB, OBSTACLE_ALPHA, OBSTACLE_RGB, OCCUPIED_RGB,
                      FREE_RGB, ROBOT_RGB, UNKNOWN_RGB, blend, render_costmap,
                      render_overlay)

#: Background of the caption band and the padding, and its text colour.
BACKGROUND_RGB = (255, 255, 255)
TEXT_RGB = (20, 20, 20)
#: Truth-comparison panel: correctly found obstacle pixels, false alarms, misses.
HIT_RGB = (220, 0, 0)
FALSE_ALARM_RGB = (255, 170, 0)
MISS_RGB = (0, 90, 255)

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_GAP_PX = 6
#: Font scale of every text (ticks, legends, captions): capitals 11 px high, as the pictures
#: are shown (they are drawn at the size they are shown: nothing with text is scaled down).
TEXT_SCALE = 0.5
#: Font scale of a picture's title (drawn twice, a pixel apart: bold).
TITLE_SCALE = 0.6
#: A costmap panel's grid is at most this share of the depth image's width.
GRID_WIDTH_SHARE = 1.2


def _text_size(text: str, scale: float) -> tuple[int, int]:
    (width, height), baseline = cv2.getTextSize(text, _FONT, scale, 1)
    return width, height + baseline


def titled(image: np.ndarray, title: str, *, below: np.ndarray | None = None) -> np.ndarray:
    """Return ``image`` under a bold title (and over ``below``, e.g. its legend), padded white."""
    parts = [image] if below is None else [image, below]
    width = max(part.shape[1] for part in parts)
    parts = [np.pad(part, ((0, 0), (0, width - part.shape[1]), (0, 0)), constant_values=255)
             for part in parts]
    band = caption_band(wrap([title], width, TITLE_SCALE), width, scale=TITLE_SCALE, bold=True)
    return np.vstack([band, *parts])


def fit_width(render: Any, width: int, *, smallest: float = 0.2) -> np.ndarray:
    """Return ``render(image_scale)`` for the largest scale <= 1 (0.05 steps) fitting ``width``."""
    scale = 1.0
    while True:
        picture = render(scale)
        if picture.shape[1] <= width or scale <= smallest:
            break
        scale = max(smallest, round(scale - 0.05, 2))
    pad = max(0, width - picture.shape[1])
    return np.pad(picture, ((0, 0), (0, pad), (0, 0)), constant_values=255)


def caption_band(lines: Sequence[str], width: int, *, scale: float = 0.5,
                 bold: bool = False) -> np.ndarray:
    """(h, width, 3) uint8 RGB: the text lines on a white band, too long ones cut with '...'."""
    pad = 6 if bold else 4
    line_h = _text_size('Ag', scale)[1] + pad
    band = np.full((line_h * len(lines) + pad + 2, width, 3), BACKGROUND_RGB, dtype=np.uint8)
    for i, line in enumerate(lines):
        while line and _text_size(line, scale)[0] > width - 8:
            line = line[:-4] + '...' if len(line) > 4 else ''
        for dx in ((4, 5) if bold else (4,)):   # bold: drawn twice, a pixel apart
            _put(band, line, (dx, line_h * (i + 1) - pad // 2 - 1), scale=scale)
    return band


def join_panels(panels: Sequence[np.ndarray], *, gap_px: int = _GAP_PX) -> np.ndarray:
    """Return RGB panels side by side, top-aligned on a white background, ``gap_px`` apart."""
    height = max(panel.shape[0] for panel in panels)
    return np.hstack([cv2.copyMakeBorder(panel, 0, height - panel.shape[0], 0, gap_px,
                                         cv2.BORDER_CONSTANT, value=BACKGROUND_RGB)
                      for panel in panels])[:, :-gap_px]


def truth_comparison(labels: np.ndarray, truth_labels: np.ndarray,
                     depth_m: np.ndarray, *, max_depth_m: float | None = None) -> np.ndarray:
    """(H, W, 3) RGB: grey depth with obstacle hits red, false alarms orange, misses blue."""
    base = render_overlay(depth_m, np.zeros_like(labels), max_depth_m=max_depth_m)
    called = (labels == LABEL_OBSTACLE) | (labels == LABEL_GROUND)
    truth_obstacle = (truth_labels == GT_OBSTACLE)
    valid_truth = truth_labels != GT_NO_RETURN
    predicted = labels == LABEL_OBSTACLE
    base[predicted & truth_obstacle] = HIT_RGB
    base[predicted & valid_truth & ~truth_obstacle] = FALSE_ALARM_RGB
    base[called & ~predicted & truth_obstacle] = MISS_RGB
    return base


#: Depth panel: pixels inside the region of interest that the pipeline called ground are the
#: depth grey blended with this green (GROUND_TINT of it), so the region's cut is visible.
GROUND_RGB = (40, 190, 60)
GROUND_TINT = 0.45
#: Depth panel, robot level: surfaces higher than the robot above the ground under them (not
#: obstacles; the pipeline labels them ground) are the depth grey blended with this blue.
ABOVE_ROBOT_RGB = (0, 150, 255)
#: Costmap panel: axis and tick ink.
AXIS_RGB = (60, 60, 60)


def depth_overlay(depth_m: np.ndarray, labels: np.ndarray, *,
                  max_depth_m: float | None = None,
                  above_robot: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) RGB: ``render_overlay`` with ground tinted green, ``above_robot`` blue."""
    rgb = render_overlay(depth_m, labels, max_depth_m=max_depth_m)
    ground = np.asarray(labels) == LABEL_GROUND
    above = np.zeros_like(ground) if above_robot is None else ground & above_robot
    for mask, colour in ((ground & ~above, GROUND_RGB), (above, ABOVE_ROBOT_RGB)):
        rgb[mask] = blend(colour, rgb[mask], GROUND_TINT)
    return rgb


def above_robot_pixels(result: Any, params: Any) -> np.ndarray | None:
    """(H, W) bool: ground pixels whose voxel is higher than the robot (robot level, else None)."""
    heights = result.voxel_height_m
    if not params.robot_level or heights is None:
        return None
    pixel_voxel = np.asarray(result.pixel_voxel)
    has = pixel_voxel >= 0
    above = np.zeros(pixel_voxel.shape, bool)
    above[has] = np.asarray(heights)[pixel_voxel[has]] > params.robot_height_m
    return above & (np.asarray(result.labels) == LABEL_GROUND)


def _ticks(low: float, high: float, px_per_m: float, min_px: float) -> np.ndarray:
    """Ticks [m] from low to high: the first step of 0.1, 0.2, 0.25 ... 10 m >= min_px apart."""
    step = next((step for step in (0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0)
                 if step * px_per_m >= min_px), max(high - low, 10.0))
    first = math.ceil(low / step - 1e-9) * step
    return np.round(np.arange(first, high + 1e-9, step), 6)


def _put(image: np.ndarray, text: str, org: tuple[int, int], *, scale: float = TEXT_SCALE,
         colour: tuple[int, int, int] = TEXT_RGB, anchor: str = 'left') -> None:
    """Write text with its baseline at org; anchor 'left', 'centre' or 'right'."""
    width = _text_size(text, scale)[0]
    x = org[0] - (width if anchor == 'right' else width // 2 if anchor == 'centre' else 0)
    cv2.putText(image, text, (int(x), int(org[1])), _FONT, scale, colour, 1, cv2.LINE_AA)


def costmap_panel(costmap: Any, *, scale: float = 4,
                  robot_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  axis_names: tuple[str, str] = ('x forward [m]', 'y left [m]')) -> np.ndarray:
    """Return the costmap seen from above with metre axes, the camera at robot_pose (x, y, yaw).

    scale: pixels a cell; a fraction draws the cells to the nearest pixel.
    """
    if float(scale).is_integer():
        grid = render_costmap(costmap, scale=int(scale))
    else:
        cells = render_costmap(costmap, scale=1)
        size = (round(cells.shape[1] * scale), round(cells.shape[0] * scale))
        grid = cv2.resize(cells, size, interpolation=cv2.INTER_NEAREST)
        scale = size[1] / cells.shape[0]   # the drawn pixels a cell, for the axes
    grid_h, grid_w = grid.shape[:2]
    line_h = _text_size('Ag', TEXT_SCALE)[1]
    tick_w = _text_size('-10.0', TEXT_SCALE)[0]
    left, top = tick_w + 12, line_h + 8
    marker = max(6, round(scale * 2))
    bottom = marker + 2 * line_h + 12
    right = _text_size('-10.0', TEXT_SCALE)[0] // 2 + 4
    panel = np.full((top + grid_h + bottom, left + grid_w + right, 3), BACKGROUND_RGB,
                    dtype=np.uint8)
    panel[top:top + grid_h, left:left + grid_w] = grid
    cv2.rectangle(panel, (left - 1, top - 1), (left + grid_w, top + grid_h), AXIS_RGB, 1)
    res = costmap.resolution_m
    px_per_m = scale / res
    x0, y0 = costmap.origin_xy_m
    x1, y1 = x0 + costmap.width * res, y0 + costmap.height * res
    _put(panel, axis_names[0], (2, line_h + 2))
    for x in _ticks(x0, x1, px_per_m, 2.5 * line_h):
        row = top + round((x1 - x) * px_per_m)
        cv2.line(panel, (left - 5, row), (left - 1, row), AXIS_RGB, 1)
        _put(panel, f'{x:g}', (left - 7, row + line_h // 2 - 1), anchor='right')
    tick_y = top + grid_h + marker + line_h + 4
    # across: 1.5 labels apart (a 4 m grid 100 px wide gets -2, 0, 2; it had 2 labels: 0)
    for y in _ticks(y0, y1, px_per_m, 1.5 * tick_w):
        col = left + round((y1 - y) * px_per_m)
        cv2.line(panel, (col, top + grid_h), (col, top + grid_h + 4), AXIS_RGB, 1)
        _put(panel, f'{y:g}', (col, tick_y), anchor='centre')
    _put(panel, axis_names[1], (left + grid_w // 2, tick_y + line_h + 4), anchor='centre')
    # the camera's foot point (or the robot), its tip pointing along its heading (x forward is
    # up, y left is left); below the grid when x = 0 is its edge
    rx, ry, yaw = robot_pose
    robot_marker(panel, (left + (y1 - ry) * px_per_m, top + (x1 - rx) * px_per_m), yaw, marker)
    return panel


#: Half the width of the robot marker over its length.
_MARKER_HALF_WIDTH = 0.6


def robot_marker(image: np.ndarray, tip: tuple[float, float], yaw: float, length: float,
                 colour: tuple[int, int, int] = ROBOT_RGB) -> None:
    """Draw the robot (or camera foot point): a triangle with its tip at (col, row) [px].

    yaw 0 points up the image (x forward is up, y left is left); the legend draws the same.
    """
    ahead = np.array([-math.sin(yaw), -math.cos(yaw)])      # (d col, d row) of the heading
    side = np.array([ahead[1], -ahead[0]])
    tip_px = np.array(tip, dtype=np.float64)
    base = tip_px - length * ahead
    triangle = np.array([tip_px, base + _MARKER_HALF_WIDTH * length * side,
                         base - _MARKER_HALF_WIDTH * length * side]).round().astype(np.int32)
    cv2.fillPoly(image, [triangle], colour, cv2.LINE_AA)


def _swatch(image: np.ndarray, x: int, y: int, size: int, kind: str,
            colour: tuple[int, int, int]) -> None:
    """Draw a legend symbol with its top-left corner at (x, y)."""
    if kind == 'box':
        cv2.rectangle(image, (x, y), (x + size, y + size), colour, -1)
        cv2.rectangle(image, (x, y), (x + size, y + size), AXIS_RGB, 1)
    elif kind == 'line':
        cv2.line(image, (x, y + size // 2), (x + size, y + size // 2), colour, 2)
    elif kind == 'robot':   # the marker the grids draw, facing up
        length = size / (2 * _MARKER_HALF_WIDTH)
        robot_marker(image, (x + size / 2, y + (size - length) / 2), 0.0, length, colour)
    elif kind == 'shades':   # a colour over the depth grey: near (dark) left, far right
        near, far = colour
        cv2.rectangle(image, (x, y), (x + size // 2, y + size), near, -1)
        cv2.rectangle(image, (x + size // 2 + 1, y), (x + size, y + size), far, -1)
        cv2.rectangle(image, (x, y), (x + size, y + size), AXIS_RGB, 1)


def legend(title: str, items: Sequence[tuple[str, tuple[int, int, int], str]],
           width: int) -> np.ndarray:
    """(h, width, 3) RGB: a title, then (kind, colour, text) items wrapped to width."""
    line_h = _text_size('Ag', TEXT_SCALE)[1] + 6
    size = line_h - 8
    rows: list[list[tuple[str, tuple[int, int, int], str]]] = [[]]
    used = 4
    for kind, colour, text in items:
        # an item wider than the legend goes on rows of its own, its text wrapped
        lines = wrap([text], width - size - 6, TEXT_SCALE) if \
            size + 20 + _text_size(text, TEXT_SCALE)[0] > width else [text]
        for k, line in enumerate(lines):
            need = size + 6 + _text_size(line, TEXT_SCALE)[0] + 14
            if rows[-1] and (used + need > width or len(lines) > 1):
                rows.append([])
                used = 4
            rows[-1].append((kind if k == 0 else 'none', colour, line.strip()))
            used += need if len(lines) == 1 else width   # nothing after a wrapped item
    band = np.full((line_h * (len(rows) + 1) + 4, width, 3), BACKGROUND_RGB, dtype=np.uint8)
    for dx in (4, 5):   # bold: drawn twice, a pixel apart
        _put(band, title, (dx, line_h - 5))
    for r, row in enumerate(rows):
        x, y = 4, line_h * (r + 1) + 3
        for kind, colour, text in row:
            _swatch(band, x, y, size, kind, colour)
            _put(band, text, (x + size + 6, y + size))
            x += size + 6 + _text_size(text, TEXT_SCALE)[0] + 14
    return band


def wrap(lines: Sequence[str], width: int, scale: float = 0.5) -> list[str]:
    """Split lines at spaces so that each fits ``width`` px (continuations indented)."""
    out: list[str] = []
    for line in lines:
        words, current = line.split(' '), ''
        for word in words:
            trial = f'{current} {word}' if current else word
            if current and _text_size(trial, scale)[0] > width - 8:
                out.append(current)
                current = '    ' + word
            else:
                current = trial
        out.append(current)
    return out


def side_by_side(result: Any, params: Any, *, caption: str = '',
                 truth_labels: np.ndarray | None = None, max_depth_m: float | None = None,
                 extra_lines: Sequence[str] = (), with_legend: bool = True,
                 image_scale: float = 1.0) -> np.ndarray:
    """Return the panel picture of one ``DetectionResult``: depth, costmap, truth, caption.

    The depth panel occupies rows ``0:H`` and columns ``0:W`` at image_scale 1.
    """
    labels, costmap = result.labels, result.costmap
    depth_m = np.asarray(result.depth_m)
    above = above_robot_pixels(result, params)
    panels = [depth_overlay(depth_m, labels, max_depth_m=max_depth_m, above_robot=above)]
    if truth_labels is not None:
        panels.append(truth_comparison(labels, truth_labels, depth_m, max_depth_m=max_depth_m))
    panels = [_scaled(panel, image_scale) for panel in panels]
    height, width = panels[0].shape[:2]
    panels.insert(1, costmap_panel(costmap, scale=_grid_scale(costmap, height, width)))
    top = join_panels(panels)
    parts = [top]
    if with_legend:
        parts.append(legend_row([p.shape[1] for p in panels], params,
                                truth=truth_labels is not None, above_robot=above is not None))
    lines = [line for line in (caption, *extra_lines) if line]
    parts.append(caption_band(wrap(lines, top.shape[1]), top.shape[1]))
    return np.vstack(parts)


def _scaled(image: np.ndarray, scale: float) -> np.ndarray:
    """Return ``image`` resized by ``scale`` (area interpolation), itself at scale 1."""
    if scale == 1.0:
        return image
    size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def _grid_scale(costmap: Any, height: int, width: int) -> int:
    """Pixels a cell: the grid as high as an image (axes below) and not much wider."""
    return max(1, min(int(GRID_WIDTH_SHARE * width) // max(costmap.height, 1),
                      height // max(costmap.width, 1)))


def legend_row(widths: Sequence[int], params: Any, *, truth: bool,
               above_robot: bool) -> np.ndarray:
    """Return the legends of the panels (``widths`` [px]) side by side, padded to one height."""
    depth_items = [('shades', depth_shades(OBSTACLE_RGB, OBSTACLE_ALPHA),
                    'obstacle (over its depth: dark near, light far)'),
                   ('box', over_grey(GROUND_RGB, GROUND_TINT), 'ground (passable)')]
    if above_robot:
        depth_items.append(('box', over_grey(ABOVE_ROBOT_RGB, GROUND_TINT),
                            f'above the robot (> {params.robot_height_m:g} m over the ground): '
                            'not an obstacle'))
    roi_text = (f'outside the region of interest (x {params.min_range_m:g}-'
                f'{params.max_range_m:g} m, |y| <= {params.lateral_limit_m:g} m, z '
                f'{params.tdbg_m:g} to {params.max_height_m:.2g} m): depth grey')
    depth = legend('depth image (camera view)', [
        *depth_items, ('box', (150, 150, 150), roi_text),
        ('box', NO_RETURN_RGB, 'no return')], widths[0])
    cells = legend('costmap, top view', _grid_items(
        ('occupied', 'free (ground seen)', 'unknown (not seen)'),
        'camera (x = y = 0), facing +x'), widths[1])
    blocks = [depth, cells]
    if truth:
        blocks.append(legend('obstacle pixels vs ground truth', [
            ('box', HIT_RGB, 'hit'), ('box', FALSE_ALARM_RGB, 'false alarm'),
            ('box', MISS_RGB, 'miss (called ground)')], widths[2]))
    return join_panels(blocks)


def _grid_items(cells: tuple[str, str, str], robot: str) -> list:
    """Legend items of a costmap panel: occupied, free, unknown, the robot."""
    return [*(('box', colour, text) for colour, text in
              zip((OCCUPIED_RGB, FREE_RGB, UNKNOWN_RGB), cells)), ('robot', ROBOT_RGB, robot)]


def depth_shades(colour: tuple[int, int, int], share: float
                 ) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """Return ``colour`` over the nearest and the farthest depth grey, as the overlay draws it."""
    return (tuple(int(v) for v in blend(colour, MIN_GREY, share)),
            tuple(int(v) for v in blend(colour, 255, share)))


def over_grey(colour: tuple[int, int, int], share: float,
              grey: int = 150) -> tuple[int, int, int]:
    """Return ``colour`` over a mid depth grey, as the depth panel draws it (legend swatches)."""
    return tuple(int(v) for v in blend(colour, grey, share))


def write_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write an RGB uint8 image as PNG (parent folders created); raises OSError on failure."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)):
        raise OSError(f'could not write {path}')


def heatmap(scores: np.ndarray, x_labels: Sequence[str], y_labels: Sequence[str], *,
            title: str = '', x_name: str = '', y_name: str = '',
            best: tuple[int, int] | None = None, values: np.ndarray | None = None,
            cell_px: int = 64) -> np.ndarray:
    """Return a score grid (ny, nx) in 0..1 as a coloured table with a value in each cell (RGB).

    NaN: grey '-'; viridis; best: (row, col) outlined in red; values: numbers to write instead
    of ``scores``.
    """
    scores = np.asarray(scores, dtype=np.float64)
    values = scores if values is None else np.asarray(values, dtype=np.float64)
    ny, nx = scores.shape
    scaled = np.clip(np.nan_to_num(scores, nan=0.0), 0.0, 1.0)
    grey = (scaled * 255).round().astype(np.uint8)
    colours = cv2.cvtColor(cv2.applyColorMap(grey, cv2.COLORMAP_VIRIDIS), cv2.COLOR_BGR2RGB)
    colours[np.isnan(scores)] = 170
    label_w = max(_text_size(s, TEXT_SCALE)[0] for s in [*y_labels, y_name])
    left = label_w + 12
    line_h = _text_size('Ag', TEXT_SCALE)[1]
    top = 2 * (line_h + 6)   # and as much below the grid
    image = np.full((2 * top + ny * cell_px, max(left + nx * cell_px + 8, 160,
                                                 _text_size(title, TEXT_SCALE)[0] + 8), 3),
                    BACKGROUND_RGB, dtype=np.uint8)
    image[top:top + ny * cell_px, left:left + nx * cell_px] = \
        np.repeat(np.repeat(colours, cell_px, axis=0), cell_px, axis=1)
    for r in range(ny):
        for c in range(nx):
            y0, x0 = top + r * cell_px, left + c * cell_px
            text = '-' if np.isnan(values[r, c]) else f'{values[r, c]:.2f}'
            tw, th = _text_size(text, TEXT_SCALE)
            ink = (0, 0, 0) if np.isnan(scores[r, c]) or scaled[r, c] > 0.6 else (255, 255, 255)
            _put(image, text, (x0 + (cell_px - tw) // 2, y0 + (cell_px + th) // 2 - 3), colour=ink)
        th = _text_size(y_labels[r], TEXT_SCALE)[1]
        _put(image, y_labels[r], (left - 6, top + r * cell_px + (cell_px + th) // 2),
             anchor='right')
    for c in range(nx):
        tw, th = _text_size(x_labels[c], TEXT_SCALE)
        _put(image, x_labels[c],
             (left + c * cell_px + (cell_px - tw) // 2, top + ny * cell_px + th + 2))
    if best is not None:
        r, c = best
        cv2.rectangle(image, (left + c * cell_px, top + r * cell_px),
                      (left + (c + 1) * cell_px - 1, top + (r + 1) * cell_px - 1),
                      (230, 0, 0), 3)
    _put(image, x_name, (left, top + ny * cell_px + 2 * (line_h + 4)))
    _put(image, y_name, (4, top - 6))
    _put(image, title, (4, line_h + 2))
    return image


def colour_bar(width: int, text: str, *, low: str = '0', high: str = '1') -> np.ndarray:
    """Return the heatmaps' one colour scale (viridis, 0 to 1) with its labels and ``text``."""
    line_h = _text_size('Ag', TEXT_SCALE)[1]
    bar_w = min(256, width - 16 - _text_size(low, TEXT_SCALE)[0] - _text_size(high,
                                                                               TEXT_SCALE)[0])
    ramp = np.linspace(0, 255, max(bar_w, 2)).round().astype(np.uint8)[np.newaxis, :]
    colours = cv2.cvtColor(cv2.applyColorMap(ramp, cv2.COLORMAP_VIRIDIS), cv2.COLOR_BGR2RGB)
    lines = wrap([text], width)
    band = np.full((line_h * 2 + 12 + (line_h + 6) * len(lines), width, 3), BACKGROUND_RGB,
                   dtype=np.uint8)
    x0 = 8 + _text_size(low, TEXT_SCALE)[0]
    band[4:4 + line_h * 2, x0:x0 + colours.shape[1]] = colours
    _put(band, low, (4, 4 + line_h + line_h // 2))
    _put(band, high, (x0 + colours.shape[1] + 4, 4 + line_h + line_h // 2))
    for k, line in enumerate(lines):
        _put(band, line, (4, line_h * 2 + 10 + (line_h + 6) * (k + 1) - 4))
    return band


def tile(images: Sequence[np.ndarray], *, columns: int = 3,
         labels: Sequence[str] | None = None) -> np.ndarray:
    """Images (RGB) placed on a grid without scaling, white padding, ``labels`` under them."""
    if labels is not None:
        width = max(i.shape[1] for i in images)
        images = [np.vstack([np.pad(image, ((0, 0), (0, width - image.shape[1]), (0, 0)),
                                    constant_values=255), caption_band([label], width)])
                  for image, label in zip(images, labels)]
    columns = max(1, min(columns, len(images)))
    cell_h = max(i.shape[0] for i in images) + _GAP_PX
    cell_w = max(i.shape[1] for i in images) + _GAP_PX
    rows = -(-len(images) // columns)
    page = np.full((rows * cell_h, columns * cell_w, 3), BACKGROUND_RGB, dtype=np.uint8)
    for i, image in enumerate(images):
        r, c = divmod(i, columns)
        page[r * cell_h:r * cell_h + image.shape[0], c * cell_w:c * cell_w + image.shape[1]] = \
            image
    return page


def node_outputs_legend(widths: Sequence[int]) -> np.ndarray:
    """Return the legend row under :func:`node_outputs` (panel widths [px])."""
    parts = [legend('obstacles/overlay (camera view)', [
        ('shades', depth_shades(OBSTACLE_RGB, OBSTACLE_ALPHA),
         'obstacle pixel (over its depth: dark near, light far)'),
        ('box', (160, 160, 160), 'other depth: dark near, white far'),
        ('box', NO_RETURN_RGB, 'no return')], widths[0]),
        legend('obstacles/costmap, top view [m]', _grid_items(
            ('occupied (100)', 'free (0)', 'unknown (-1)'), 'camera foot point, facing +x'),
            widths[1])]
    if len(widths) > 2:
        parts.append(legend('obstacles/fused_costmap, odom [m]', _grid_items(
            ('occupied: seen often enough', 'free', 'unknown / not sure'),
            'robot at its odometry pose'), widths[2]))
    return join_panels(parts)


def node_outputs(overlay: np.ndarray, costmap: Any, *, caption: Sequence[str],
                 fused: Any = None,
                 robot_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 image_scale: float = 1.0, with_legend: bool = True) -> np.ndarray:
    """Return the picture of one frame of the node's outputs.

    image_scale: the overlay scaled by it, the grids drawn to its height, the text not.
    """
    overlay = _scaled(overlay, image_scale)
    height, width = overlay.shape[:2]
    # pixels a cell, a fraction too: the grids grow with the overlay, not in whole steps; each
    # grid 0.8 of the overlay's width, so that three panels share a row evenly
    scale = max(1.0, min(0.8 * width / max(costmap.height, 1), height / max(costmap.width, 1)))
    panels = [overlay, costmap_panel(costmap, scale=scale)]
    if fused is not None:
        # at the costmap's metres per pixel: a 4 m window is as wide as the costmap's 4 m (it
        # was fitted to the overlay's height: 80 px, one tick)
        panels.append(costmap_panel(fused, scale=scale * costmap.resolution_m
                                    / fused.resolution_m,
                                    robot_pose=robot_pose,
                                    axis_names=('x [m], odom', 'y [m], odom')))
    row = join_panels(panels)
    parts = [row, caption_band(wrap(caption, row.shape[1]), row.shape[1])]
    if with_legend:
        parts.append(node_outputs_legend([p.shape[1] for p in panels]))
    return np.vstack(parts)
