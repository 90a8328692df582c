"""Pictures of what the detector saw, without ROS running: PNG panels and contact sheets.

One panel per frame: on the left the depth frame with obstacle pixels marked (the seed's
figures 4.22-4.27, drawn by ``overlay.render_overlay``), on the right the costmap seen from
above (figure 4.23, ``overlay.render_costmap``), optionally a third panel comparing the
obstacle pixels with a ground truth, and a caption band underneath (frame name, obstacle
count, time). A sequence becomes a contact sheet, a grid of captioned thumbnails.

Frames come from a depth PNG with an intrinsics YAML (``evaluation.read_camera_yaml``), a
scene of the generator, a labelled folder, or a ROS 2 bag (:func:`bag_frames`).

All images are RGB uint8; :func:`write_png` converts to OpenCV's BGR when writing.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import cv2
import numpy as np

from .metrics import CELL_OCCUPIED, GT_NO_RETURN, GT_OBSTACLE, LABEL_GROUND, LABEL_OBSTACLE
from .overlay import render_costmap, render_overlay
from .params import Intrinsics

#: Background of the caption band and the padding, and its text colour.
BACKGROUND_RGB = (255, 255, 255)
TEXT_RGB = (20, 20, 20)
#: Truth-comparison panel: correctly found obstacle pixels, false alarms, misses.
HIT_RGB = (220, 0, 0)
FALSE_ALARM_RGB = (255, 170, 0)
MISS_RGB = (0, 90, 255)

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_GAP_PX = 6


def _text_size(text: str, scale: float) -> tuple[int, int]:
    (width, height), baseline = cv2.getTextSize(text, _FONT, scale, 1)
    return width, height + baseline


def caption_band(lines: Sequence[str], width: int, *, scale: float = 0.5) -> np.ndarray:
    """(h, width, 3) uint8 RGB: the text lines on a white band, left aligned.

    Lines longer than the band are shortened with '...' so that nothing is cut mid-glyph.
    """
    line_h = _text_size('Ag', scale)[1] + 4
    band = np.full((line_h * len(lines) + 6, width, 3), BACKGROUND_RGB, dtype=np.uint8)
    for i, line in enumerate(lines):
        text = line
        while text and _text_size(text, scale)[0] > width - 8:
            text = text[:-4] + '...' if len(text) > 4 else ''
        cv2.putText(band, text, (4, 3 + line_h * (i + 1) - 6), _FONT, scale, TEXT_RGB, 1,
                    cv2.LINE_AA)
    return band


def _pad_to_height(image: np.ndarray, height: int) -> np.ndarray:
    if image.shape[0] >= height:
        return image[:height]
    top = (height - image.shape[0]) // 2
    out = np.full((height, image.shape[1], 3), BACKGROUND_RGB, dtype=np.uint8)
    out[top:top + image.shape[0]] = image
    return out


def truth_comparison(labels: np.ndarray, truth_labels: np.ndarray,
                     depth_m: np.ndarray, *, max_depth_m: float | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB: grey depth with obstacle hits red, false alarms orange, misses blue.

    labels: pipeline ``LABEL_*``; truth_labels: ``GT_*``. A miss is a truth obstacle pixel the
    pipeline called ground; pixels the pipeline made no call on keep their grey.
    """
    base = render_overlay(depth_m, np.zeros_like(labels), max_depth_m=max_depth_m)
    called = (labels == LABEL_OBSTACLE) | (labels == LABEL_GROUND)
    truth_obstacle = (truth_labels == GT_OBSTACLE)
    valid_truth = truth_labels != GT_NO_RETURN
    predicted = labels == LABEL_OBSTACLE
    base[predicted & truth_obstacle] = HIT_RGB
    base[predicted & valid_truth & ~truth_obstacle] = FALSE_ALARM_RGB
    base[called & ~predicted & truth_obstacle] = MISS_RGB
    return base


def side_by_side(result: Any, *, caption: str = '', truth_labels: np.ndarray | None = None,
                 max_depth_m: float | None = None, labels: np.ndarray | None = None,
                 costmap: Any = None, extra_lines: Sequence[str] = ()) -> np.ndarray:
    """Return the panel picture of one ``DetectionResult``.

    Layout: ``[overlay (H x W) | costmap | truth comparison (optional)]`` over a caption band.
    The overlay occupies exactly rows ``0:H`` and columns ``0:W`` of the returned image.
    labels / costmap: draw these instead of the result's (e.g. a refined result's).
    The caption's second line gives the obstacle pixel and voxel counts and the pipeline
    time. Returns (H + band, W_total, 3) uint8 RGB.
    """
    labels = result.labels if labels is None else labels
    costmap = result.costmap if costmap is None else costmap
    depth_m = np.asarray(result.depth_m)
    height, width = depth_m.shape
    panels = [render_overlay(depth_m, labels, max_depth_m=max_depth_m)]
    scale = max(1, min(height // max(costmap.width, 1), width // max(costmap.height, 1)))
    panels.append(_pad_to_height(render_costmap(costmap, scale=scale), height))
    if truth_labels is not None:
        panels.append(truth_comparison(labels, truth_labels, depth_m, max_depth_m=max_depth_m))
    gap = np.full((height, _GAP_PX, 3), BACKGROUND_RGB, dtype=np.uint8)
    row: list[np.ndarray] = []
    for panel in panels:
        row.extend([panel, gap])
    top = np.hstack(row[:-1])
    n_pixels = int(np.count_nonzero(labels == LABEL_OBSTACLE))
    occupied = int(np.count_nonzero(np.asarray(costmap.data) == CELL_OCCUPIED))
    total_ms = float(result.timings_ms.get('total', float('nan')))
    stats = (f'{n_pixels} obstacle px, {int(result.obstacle_points.shape[0])} obstacle voxels, '
             f'{occupied} occupied cells, {total_ms:.0f} ms')
    legend = 'left: depth, obstacles red | right: costmap, occupied blue, x forward up'
    if truth_labels is not None:
        legend += ' | truth: hit red, false alarm orange, miss blue'
    lines = [line for line in (caption, stats, *extra_lines, legend) if line]
    return np.vstack([top, caption_band(lines, top.shape[1])])


def contact_sheet(images: Sequence[np.ndarray], *, labels: Sequence[str] | None = None,
                  columns: int = 4, thumb_width: int = 400) -> np.ndarray:
    """Return a grid of RGB thumbnails, each ``thumb_width`` wide with an optional label below.

    Returns (rows * cell_h, columns * thumb_width, 3) uint8 RGB (white padding).
    """
    if not images:
        raise ValueError('contact sheet of no images')
    if columns < 1 or thumb_width < 8:
        raise ValueError(f'columns={columns} must be >= 1 and thumb_width={thumb_width} >= 8')
    thumbs = []
    for i, image in enumerate(images):
        h, w = image.shape[:2]
        thumb_h = max(1, round(h * thumb_width / w))
        thumb = cv2.resize(image, (thumb_width, thumb_h), interpolation=cv2.INTER_AREA)
        if labels is not None:
            thumb = np.vstack([thumb, caption_band([labels[i]], thumb_width, scale=0.45)])
        thumbs.append(thumb)
    cell_h = max(t.shape[0] for t in thumbs) + _GAP_PX
    cell_w = thumb_width + _GAP_PX
    columns = min(columns, len(thumbs))
    rows = -(-len(thumbs) // columns)
    sheet = np.full((rows * cell_h, columns * cell_w, 3), BACKGROUND_RGB, dtype=np.uint8)
    for i, thumb in enumerate(thumbs):
        r, c = divmod(i, columns)
        sheet[r * cell_h:r * cell_h + thumb.shape[0], c * cell_w:c * cell_w + thumb_width] = thumb
    return sheet


def write_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write an RGB uint8 image as PNG (parent folders created); raises OSError on failure."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)):
        raise OSError(f'could not write {path}')


# --------------------------------------------------------------------------------------------
# Frames from files and bags


@dataclass
class DepthFrame:
    """A depth frame to draw: depth (H, W) uint16/float, its intrinsics, a name."""

    name: str
    depth: np.ndarray
    intrinsics: Intrinsics | None
    depth_scale: float | None = None
    truth_labels: np.ndarray | None = None
    #: where the intrinsics came from (e.g. ``CameraInfo on /x (found by type)``), '' = none
    intrinsics_origin: str = ''


def read_depth_png(path: str | Path) -> np.ndarray:
    """Return the (H, W) uint16 depth of a 16-bit one-channel PNG or PGM (ValueError if not)."""
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise ValueError(f'{path}: cannot read the image')
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ValueError(f'{path}: a depth PNG must be 16-bit single channel, got '
                         f'{depth.dtype} with shape {depth.shape}')
    return depth


def bag_frames(path: str | Path, depth_topic: str, info_topic: str | None = None, *,
               every: int = 1, max_frames: int | None = None,
               find_info_topic: bool = False) -> Iterator[DepthFrame]:
    """Depth frames of a ROS 2 (or ROS 1) bag, in time order, with the latest camera info.

    depth_topic: sensor_msgs/Image (16UC1 [mm] or 32FC1 [m]); info_topic: its CameraInfo.
    Without ``info_topic`` and with ``find_info_topic``, the CameraInfo topic is found by type
    (``tool_support.choose_info_topic``). No CameraInfo topic, or no message before a frame:
    the frame's intrinsics are None (the caller chooses a fallback and says so); each frame's
    ``intrinsics_origin`` names the topic. every: keep one frame in ``every``; max_frames: stop
    after so many. Raises ValueError naming the path when it is not a bag, cannot be read, or
    lacks the depth topic.
    """
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    from .tool_support import check_bag_path

    if every < 1:
        raise ValueError(f'every={every} must be >= 1')
    check_bag_path(path)
    try:
        reader = AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except AnyReaderError as exc:
        raise ValueError(f'{path}: cannot read the bag ({exc})') from None
    try:
        yield from _bag_frames(reader, path, depth_topic, info_topic, every, max_frames,
                               find_info_topic)
    finally:
        reader.close()


def _bag_frames(reader: Any, path: str | Path, depth_topic: str, info_topic: str | None,
                every: int, max_frames: int | None, find_info_topic: bool
                ) -> Iterator[DepthFrame]:
    from .conversions import camera_info_to_intrinsics, image_to_array
    from .tool_support import IMAGE_TYPE, choose_info_topic

    topics = {c.topic: c.msgtype for c in reader.connections}
    if depth_topic not in topics:
        images = sorted(t for t, kind in topics.items() if kind == IMAGE_TYPE)
        raise ValueError(f'{path}: no topic {depth_topic!r}; its {IMAGE_TYPE} topics: '
                         f'{", ".join(images) or "none"} (use --depth-topic)')
    how = 'given'
    if info_topic is None and find_info_topic:
        info_topic, how = choose_info_topic(topics, depth_topic)
    elif info_topic is not None:
        try:
            choose_info_topic(topics, depth_topic, info_topic)
        except ValueError as exc:
            raise ValueError(f'{path}: {exc}') from None
    wanted = [c for c in reader.connections
              if c.topic == depth_topic or (info_topic and c.topic == info_topic)]
    intrinsics: Intrinsics | None = None
    seen = kept = 0
    for connection, timestamp, raw in reader.messages(connections=wanted):
        if connection.topic != depth_topic:
            intrinsics = camera_info_to_intrinsics(reader.deserialize(raw,
                                                                      connection.msgtype))
            continue
        seen += 1
        if (seen - 1) % every:
            continue
        msg = reader.deserialize(raw, connection.msgtype)
        stamp = msg.header.stamp
        origin = (f'CameraInfo on {info_topic} ({how})' if intrinsics is not None
                  else f'none: no CameraInfo on {info_topic} before the frame'
                  if info_topic else f'none: {how}')
        yield DepthFrame(f'{depth_topic} #{seen - 1} t={stamp.sec}.{stamp.nanosec:09d}',
                         image_to_array(msg), intrinsics, intrinsics_origin=origin)
        kept += 1
        if max_frames is not None and kept >= max_frames:
            return


# --------------------------------------------------------------------------------------------
# Heatmaps of parameter sweeps (seed figures 4.18 and 4.19 as numbers)


def heatmap(scores: np.ndarray, x_labels: Sequence[str], y_labels: Sequence[str], *,
            title: str = '', x_name: str = '', y_name: str = '', vmin: float = 0.0,
            vmax: float = 1.0, best: tuple[int, int] | None = None,
            values: np.ndarray | None = None, cell_px: int = 64) -> np.ndarray:
    """Return a score grid drawn as a coloured table with the value written in each cell.

    scores: (ny, nx) float, NaN = not run / invalid (drawn grey, '-'); row 0 is drawn at the
    top; colours: OpenCV's viridis from ``vmin`` (dark) to ``vmax`` (yellow); best: (row, col)
    outlined in red; values: numbers to write instead of ``scores`` (e.g. when the colour
    shows 1 - a false-alarm rate). Returns RGB uint8.
    """
    scores = np.asarray(scores, dtype=np.float64)
    values = scores if values is None else np.asarray(values, dtype=np.float64)
    if scores.ndim != 2 or scores.shape != (len(y_labels), len(x_labels)):
        raise ValueError(f'scores shape {scores.shape} does not match {len(y_labels)} y labels '
                         f'and {len(x_labels)} x labels')
    if not vmax > vmin:
        raise ValueError(f'vmax={vmax} must be above vmin={vmin}')
    ny, nx = scores.shape
    scaled = np.clip((np.nan_to_num(scores, nan=vmin) - vmin) / (vmax - vmin), 0.0, 1.0)
    grey = (scaled * 255).round().astype(np.uint8)
    colours = cv2.cvtColor(cv2.applyColorMap(grey, cv2.COLORMAP_VIRIDIS), cv2.COLOR_BGR2RGB)
    label_w = max([_text_size(s, 0.45)[0] for s in y_labels] + [_text_size(y_name, 0.45)[0]])
    left = label_w + 12
    top = 2 * (_text_size('Ag', 0.5)[1] + 6)
    bottom = 2 * (_text_size('Ag', 0.45)[1] + 6)
    image = np.full((top + ny * cell_px + bottom, max(left + nx * cell_px + 8, 160), 3),
                    BACKGROUND_RGB, dtype=np.uint8)
    for r in range(ny):
        for c in range(nx):
            y0, x0 = top + r * cell_px, left + c * cell_px
            value = scores[r, c]
            colour = (170, 170, 170) if np.isnan(value) else tuple(int(v) for v in colours[r, c])
            cv2.rectangle(image, (x0, y0), (x0 + cell_px - 1, y0 + cell_px - 1), colour, -1)
            text = '-' if np.isnan(values[r, c]) else f'{values[r, c]:.2f}'
            tw, th = _text_size(text, 0.45)
            ink = (0, 0, 0) if np.isnan(value) or scaled[r, c] > 0.6 else (255, 255, 255)
            cv2.putText(image, text, (x0 + (cell_px - tw) // 2, y0 + (cell_px + th) // 2 - 3),
                        _FONT, 0.45, ink, 1, cv2.LINE_AA)
        tw, th = _text_size(y_labels[r], 0.45)
        cv2.putText(image, y_labels[r], (left - tw - 6, top + r * cell_px + (cell_px + th) // 2),
                    _FONT, 0.45, TEXT_RGB, 1, cv2.LINE_AA)
    for c in range(nx):
        tw, th = _text_size(x_labels[c], 0.45)
        cv2.putText(image, x_labels[c],
                    (left + c * cell_px + (cell_px - tw) // 2, top + ny * cell_px + th + 2),
                    _FONT, 0.45, TEXT_RGB, 1, cv2.LINE_AA)
    if best is not None:
        r, c = best
        cv2.rectangle(image, (left + c * cell_px, top + r * cell_px),
                      (left + (c + 1) * cell_px - 1, top + (r + 1) * cell_px - 1),
                      (230, 0, 0), 3)
    axis_y = top + ny * cell_px + 2 * (_text_size('Ag', 0.45)[1] + 4)
    cv2.putText(image, x_name, (left, axis_y), _FONT, 0.45, TEXT_RGB, 1, cv2.LINE_AA)
    cv2.putText(image, y_name, (4, top - 6), _FONT, 0.45, TEXT_RGB, 1, cv2.LINE_AA)
    cv2.putText(image, title, (4, _text_size('Ag', 0.5)[1] + 2), _FONT, 0.5, TEXT_RGB, 1,
                cv2.LINE_AA)
    return image


def tile(images: Sequence[np.ndarray], *, columns: int = 3) -> np.ndarray:
    """Images (RGB) placed on a grid without scaling, white padding; for heatmap pages."""
    if not images:
        raise ValueError('tile of no images')
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
