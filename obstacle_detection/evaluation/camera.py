"""Camera files: the one reader and writer of the camera YAML, and intrinsics scaling.

Keys: ``fx fy cx cy`` (or a ROS ``camera_matrix``), optional ``width height``, ``depth_scale``
and mount (``camera_height_m``, ``camera_pitch_deg|rad``, ``camera_roll_deg|rad``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from obstacle_detection.evaluation import EvaluationError
from obstacle_detection.pipeline.params import Intrinsics


@dataclass(frozen=True)
class CameraFile:
    """What a camera YAML gives: intrinsics, and the size, depth scale and mount when given."""

    intrinsics: Intrinsics
    size: tuple[int, int] | None = None          #: (width, height) [px]
    depth_scale: float | None = None             #: depth units per metre
    mount: tuple[float, float, float] | None = None   #: height [m], pitch [rad], roll [rad]


def scaled_intrinsics(intrinsics: Intrinsics, sx: float, sy: float | None = None
                      ) -> Intrinsics:
    """Intrinsics of the camera with images resized by ``sx`` (and ``sy``), pixel-centre aware."""
    sy = sx if sy is None else sy
    return Intrinsics(fx=intrinsics.fx * sx, fy=intrinsics.fy * sy,
                      cx=(intrinsics.cx + 0.5) * sx - 0.5,
                      cy=(intrinsics.cy + 0.5) * sy - 0.5)


def _number(data: Mapping[str, Any], key: str, default: Any = None) -> Any:
    try:
        return default if data.get(key) is None else float(data[key])
    except (TypeError, ValueError):
        raise ValueError(f'{key} must be a number, got {data[key]!r}') from None


def camera_from_mapping(data: Any) -> CameraFile:
    """Return the camera a parsed camera YAML describes; ValueError saying what is bad."""
    if not isinstance(data, dict):
        raise ValueError('not a YAML mapping (expected fx, fy, cx, cy, ...)')
    if 'camera_matrix' in data:
        try:
            k = [float(v) for v in data['camera_matrix']['data']]
            values = (k[0], k[4], k[2], k[5])
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise ValueError('camera_matrix must hold 9 numbers in data') from err
        width, height = data.get('image_width'), data.get('image_height')
    else:
        missing = [k for k in ('fx', 'fy', 'cx', 'cy') if k not in data]
        if missing:
            raise ValueError(f'missing {", ".join(missing)} (need fx, fy, cx, cy)')
        values = tuple(_number(data, k) for k in ('fx', 'fy', 'cx', 'cy'))
        width, height = data.get('width'), data.get('height')
    if (width is None) != (height is None):
        raise ValueError('give both width and height, or neither')
    size = None
    if width is not None:
        try:
            size = (int(width), int(height))
        except (TypeError, ValueError):
            raise ValueError('width and height must be integers') from None
        if size[0] <= 0 or size[1] <= 0:
            raise ValueError(f'width and height must be positive, got {size}')
    scale = _number(data, 'depth_scale')
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise ValueError(f'depth_scale={scale} must be > 0')
    mount = None
    if 'camera_height_m' in data:
        mount = (_number(data, 'camera_height_m'), _angle(data, 'camera_pitch'),
                 _angle(data, 'camera_roll'))
    return CameraFile(Intrinsics(*values), size, scale, mount)


def _angle(data: Mapping[str, Any], name: str) -> float:
    if f'{name}_rad' in data:
        return _number(data, f'{name}_rad')
    return math.radians(_number(data, f'{name}_deg', 0.0))


def read_camera_yaml(path: str | Path) -> CameraFile:
    """Read a camera YAML; OSError if unreadable, EvaluationError naming a bad content."""
    import yaml  # PyYAML ships with ROS 2 (rclpy's own dependency)

    text = Path(path).read_text(encoding='utf-8')
    try:
        return camera_from_mapping(yaml.safe_load(text) or {})
    except yaml.YAMLError as err:
        raise EvaluationError(f'not valid YAML ({err})', path) from None
    except ValueError as err:
        raise EvaluationError(str(err), path) from None


def camera_yaml_text(intrinsics: Intrinsics, *, comment: str,
                     size: tuple[int, int] | None = None, depth_scale: float | None = None,
                     height_m: float | None = None, pitch_deg: float = 0.0,
                     roll_deg: float = 0.0) -> str:
    """Return a camera YAML: intrinsics [px], then size, depth scale and mount when given."""
    lines = [f'# {comment}', f'fx: {intrinsics.fx!r}', f'fy: {intrinsics.fy!r}',
             f'cx: {intrinsics.cx!r}', f'cy: {intrinsics.cy!r}']
    if size is not None:
        lines += [f'width: {int(size[0])}', f'height: {int(size[1])}']
    if depth_scale is not None:
        lines.append(f'depth_scale: {float(depth_scale)!r}')
    if height_m is not None:
        lines += [f'camera_height_m: {float(height_m)!r}',
                  f'camera_pitch_deg: {float(pitch_deg)!r}',
                  f'camera_roll_deg: {float(roll_deg)!r}']
    return '\n'.join(lines) + '\n'
