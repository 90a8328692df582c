"""Test-only helpers: camera YAML, optical-to-ground points, obstacle colours, picture text."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from obstacle_detection.evaluation import camera as camera_file
from obstacle_detection.pipeline.geometry import mount_transform
from obstacle_detection.pipeline.params import DetectorParams, Intrinsics
from obstacle_detection.viz.overlay import OBSTACLE_ALPHA
from obstacle_detection.viz.pictures import TEXT_SCALE

#: Smallest height of a capital letter [px] at TEXT_SCALE.
MIN_TEXT_PX = 11


def write_camera_yaml(path: str | Path, intrinsics: Intrinsics, height_m: float,
                      pitch_rad: float, roll_rad: float) -> None:
    """Write a camera YAML with the intrinsics and the mount (angles in degrees)."""
    Path(path).write_text(camera_file.camera_yaml_text(
        intrinsics, comment='pinhole intrinsics [px] and camera mount', height_m=height_m,
        pitch_deg=math.degrees(pitch_rad), roll_deg=math.degrees(roll_rad)), encoding='utf-8')


def to_ground(points_optical: np.ndarray, params: DetectorParams) -> np.ndarray:
    """Optical-frame points (M, 3) -> ground-frame points (M, 3) float32 [m] via the mount."""
    rot, trans = mount_transform(params.camera_height_m, params.camera_pitch_rad,
                                 params.camera_roll_rad)
    return points_optical @ rot.T.astype(np.float32) + trans.astype(np.float32)


def is_obstacle_rgb(rgb: np.ndarray) -> np.ndarray:
    """Return (...) bool: which RGB pixels (..., 3) are obstacle-coloured (red over grey)."""
    rgb = np.asarray(rgb, np.int16)
    red, green, blue = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (green == blue) & (np.abs(red - green - OBSTACLE_ALPHA * 255) <= 1.0)


def text_height_px(scale: float = TEXT_SCALE) -> int:
    """Height [px] of the ink of a capital letter ('H') written at ``scale``."""
    image = np.zeros((100, 100), np.uint8)
    cv2.putText(image, 'H', (10, 80), cv2.FONT_HERSHEY_SIMPLEX, scale, 255, 1, cv2.LINE_AA)
    rows = np.flatnonzero((image > 100).any(axis=1))
    return int(rows[-1] - rows[0] + 1)
