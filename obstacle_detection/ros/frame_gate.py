"""The checks a depth frame passes before the pipeline sees it: one gate for node and bag tools."""

from __future__ import annotations

import re
from dataclasses import dataclass
from collections.abc import Sequence
from typing import Any

import numpy as np

from obstacle_detection.pipeline.params import Intrinsics

from .compressed_depth import compressed_depth_to_array, is_compressed_image
from . import RosInputError
from .conversions import (K_FALLBACK_NOTE, camera_info_to_intrinsics, depth_problem,
                          depth_sample, image_to_array, intrinsics_come_from_k, intrinsics_problem)


@dataclass(frozen=True)
class Skip:
    """Why a frame is not processed: a throttling key and the sentence to print."""

    kind: str
    reason: str


@dataclass(frozen=True)
class CameraState:
    """One CameraInfo: its stamp, image size and intrinsics, or why it is unusable."""

    width: int
    height: int
    intrinsics: Intrinsics | None
    error: str | None
    stamp_ns: int = 0
    note: str | None = None

    @classmethod
    def from_camera_info(cls, msg: Any) -> CameraState:
        """Read a sensor_msgs/CameraInfo: P (else K) as intrinsics, refused when implausible."""
        width, height = int(msg.width), int(msg.height)
        note = None
        try:
            intrinsics, error = camera_info_to_intrinsics(msg), None
            error = intrinsics_problem(intrinsics, width, height)
            if error is None and intrinsics_come_from_k(msg):
                note = K_FALLBACK_NOTE
        except ValueError as exc:
            intrinsics, error = None, str(exc)
        return cls(width, height, intrinsics if error is None else None, error,
                   stamp_ns(msg.header.stamp), note)

    def same_camera(self, other: CameraState) -> bool:
        """Whether two CameraInfos describe the same camera (size, intrinsics, error)."""
        return ((self.width, self.height, self.intrinsics, self.error)
                == (other.width, other.height, other.intrinsics, other.error))



#: CameraInfos kept for matching depth frames by stamp (a second at 30 Hz).
CAMERA_INFO_HISTORY = 30


def keep_camera(cameras: Any, camera: CameraState) -> None:
    """Append a CameraInfo to the recent ones (a deque), once per stamp and camera."""
    if not any(c.stamp_ns == camera.stamp_ns and c.same_camera(camera) for c in cameras):
        cameras.append(camera)


def camera_for(cameras: Sequence[CameraState], frame_stamp_ns: int,
               tolerance_ns: int) -> CameraState | Skip | None:
    """Choose a frame's CameraInfo among the recent ones (oldest first), as the node does."""
    if not cameras:
        return None
    nearest = min(cameras, key=lambda c: abs(c.stamp_ns - frame_stamp_ns))
    if abs(nearest.stamp_ns - frame_stamp_ns) <= tolerance_ns:
        return nearest
    if all(c.same_camera(cameras[-1]) for c in cameras):
        return cameras[-1]
    return Skip('camera_info_stamp', (
        f'no CameraInfo within camera_info_tolerance_s ({tolerance_ns * 1e-9:g} s) of the '
        f'frame stamp (nearest {abs(nearest.stamp_ns - frame_stamp_ns) * 1e-9:.3f} s away) '
        'while the recent CameraInfos disagree'))

@dataclass(frozen=True)
class Verdict:
    """The intrinsics a frame uses, or why it is skipped; ``note`` says a fallback was used."""

    intrinsics: Intrinsics | None = None
    skip: Skip | None = None
    note: str | None = None


def stamp_ns(stamp: Any) -> int:
    """Return a builtin_interfaces/Time as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def problem_kind(prefix: str, text: str) -> str:
    """Return the throttling key of a problem: its text without the numbers."""
    return f'{prefix}:{re.sub(r"[-+]?[0-9][0-9.e+-]*", "#", text)}'


def has_valid_depth(depth: np.ndarray) -> bool:
    """Whether any pixel holds a depth (> 0 and, for float depth, finite)."""
    if depth.dtype.kind == 'f':
        return bool(np.any(np.isfinite(depth) & (depth > 0.0)))
    return np.count_nonzero(depth) > 0   # no boolean copy: 3x faster on a frame's first touch


def decode(msg: Any) -> np.ndarray | Skip:
    """Return the depth array of a raw or compressed depth message, or why not (a Skip)."""
    compressed = is_compressed_image(msg)
    try:
        # raw: a view of the message's pixels when they need no copy (the pipeline only
        # reads them)
        return (compressed_depth_to_array(msg) if compressed
                else image_to_array(msg, copy=False))
    except RosInputError as error:
        # each kind of problem (encoding, size, ...) is throttled on its own
        return Skip('compressed' if compressed else problem_kind('image', str(error)),
                    str(error))


def choose_intrinsics(camera: CameraState | None, shape: tuple[int, ...], *,
                      use_fallback: bool, fallback: Intrinsics, no_camera: str) -> Verdict:
    """Choose the intrinsics of a frame of ``shape`` (H, W, ...) from its CameraInfo."""
    if camera is None:
        if use_fallback:
            return Verdict(fallback, note=(
                f'no CameraInfo yet: using the fallback intrinsics fx={fallback.fx:g} '
                f'fy={fallback.fy:g} cx={fallback.cx:g} cy={fallback.cy:g}'))
        return Verdict(skip=Skip('no_camera_info', no_camera))
    if camera.intrinsics is None:
        return Verdict(skip=Skip(problem_kind('camera_info', str(camera.error)),
                                 str(camera.error)))
    height, width = shape[:2]
    if (camera.width, camera.height) != (width, height):
        return Verdict(skip=Skip('size', f'image is {width}x{height} but CameraInfo is '
                                         f'{camera.width}x{camera.height}'))
    return Verdict(camera.intrinsics)


def check_depth(depth: np.ndarray, msg: Any) -> Skip | None:
    """Why a decoded frame's depth cannot be processed (none valid, implausible), or None."""
    # the sampled rows first (what depth_problem reads): one valid pixel there spares the
    # scan of the whole frame
    if not has_valid_depth(depth_sample(depth)) and not has_valid_depth(depth):
        return Skip('no_depth', 'no valid depth pixel (every pixel is 0, NaN or inf)')
    problem = depth_problem(depth)
    if problem is not None:
        form = (f'CompressedImage format {msg.format!r}' if is_compressed_image(msg) else
                f'encoding {msg.encoding!r}, is_bigendian={bool(msg.is_bigendian)}')
        return Skip(problem_kind('depth', problem), f'{problem} ({form})')
    return None
