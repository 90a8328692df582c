"""What the command-line tools share: default topics, error lines and exit codes, data checks."""

from __future__ import annotations

import argparse
import functools
import math
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from obstacle_detection.pipeline.params import DetectorParams, Intrinsics

#: One set of default topic names for every tool: the iai_kinect2 driver's SD (512x424) topics.
DEFAULT_DEPTH_TOPIC = '/kinect2/sd/image_depth_rect'
DEFAULT_INFO_TOPIC = '/kinect2/sd/camera_info'
IMAGE_TYPE = 'sensor_msgs/msg/Image'
CAMERA_INFO_TYPE = 'sensor_msgs/msg/CameraInfo'

#: Depth units per metre of the usual 16-bit depth formats, and what they are.
KNOWN_DEPTH_SCALES: dict[float, str] = {
    1000.0: 'millimetres (Kinect, RealSense, ROS 16UC1)',
    5000.0: 'TUM RGB-D format, 0.2 mm',
    10000.0: '0.1 mm',
    100.0: 'centimetres',
}
#: Median depth [m] of a plausible indoor RGB-D frame (structured light / time of flight).
PLAUSIBLE_MEDIAN_DEPTH_M = (0.3, 8.0)
#: Depth [m] that 5 % of an indoor frame does not reach (TUM's 0.2 mm read as millimetres puts a
#: desk at 7 m and the hall behind it at 20 m).
FAR_DEPTH_M = 10.0
#: A mount differing from the floor in view by more than this is reported.
MOUNT_HEIGHT_TOLERANCE_M = 0.15
MOUNT_ANGLE_TOLERANCE_DEG = 5.0


class ToolError(ValueError):
    """The tools' error, ``<path>: <problem>`` or a message: bad input, or ``usage``: options."""

    def __init__(self, path: str | Path, problem: str | None = None, *,
                 usage: bool = False) -> None:
        super().__init__(str(path) if problem is None else f'{path}: {problem}')
        self.usage = usage


#: The folder holding the ``obstacle_detection`` package (the repository root in a checkout).
PACKAGE_ROOT = Path(__file__).resolve().parents[2]


def package_file(relative: str) -> Path:
    """Return a file the package ships beside its Python code, e.g. ``params/corridor.yaml``."""
    candidates = [PACKAGE_ROOT / relative]
    if len(PACKAGE_ROOT.parents) > 2:   # <prefix>/lib/pythonX.Y/site-packages
        candidates.append(PACKAGE_ROOT.parents[2] / 'share' / 'obstacle_detection' / relative)
    return next((path for path in candidates if path.exists()), candidates[0])


def command(prog: str) -> Callable[[Callable[..., int]], Callable[..., int]]:
    """Decorate a tool's ``main(argv)``: bad input -> one error line (exit 1, 2 if usage)."""
    def decorate(main: Callable[..., int]) -> Callable[..., int]:
        @functools.wraps(main)
        def run(argv: Any = None) -> int:
            try:
                return main(argv)
            except (ValueError, OSError, KeyError) as exc:   # KeyError: an unknown name
                if getattr(exc, 'usage', False):
                    print(f'{prog}: error: {exc}', file=sys.stderr)
                    return 2
                text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
                if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
                    text = f'{exc.filename}: {exc.strerror}'
                print(f'error: {text}', file=sys.stderr)
                return 1
            except KeyboardInterrupt:   # the tools write their outputs whole or not at all
                print(f'{prog}: interrupted', file=sys.stderr)
                return 130
        return run
    return decorate


def warn(text: str) -> None:
    """Print one ``warning: ...`` line on stderr."""
    print(f'warning: {text}', file=sys.stderr)


# --------------------------------------------------------------------------------------------
# Bags


def check_bag_path(path: str | Path, *, ros1: bool = True) -> None:
    """Raise ToolError unless ``path`` looks like a bag the rosbags library can open."""
    path = Path(path)
    expected = ('a rosbag2 folder (holding metadata.yaml)'
                + (' or a ROS 1 .bag file' if ros1 else ''))
    if not path.exists():
        raise ToolError(path, f'no such file or folder; expected {expected}')
    if path.is_dir() and not (path / 'metadata.yaml').is_file():
        raise ToolError(path, f'not a bag: no metadata.yaml in the folder; expected {expected}')
    if path.suffix in ('.db3', '.mcap'):
        raise ToolError(path, f'a rosbag2 storage file: give its folder {path.parent}')
    if path.suffix == '.bag' and not ros1:
        raise ToolError(path, 'a ROS 1 bag: convert it first with tools/bag_convert.py ros1')
    if not path.is_dir() and path.suffix != '.bag':
        raise ToolError(path, f'not a bag; expected {expected}')


def choose_info_topic(topics: Mapping[str, str], depth_topic: str,
                      requested: str | None = None) -> tuple[str | None, str]:
    """Pick the CameraInfo topic of a bag's depth topic: ``(topic or None, how it was found)``."""
    infos = sorted(t for t, kind in topics.items() if kind == CAMERA_INFO_TYPE)
    if requested is not None:
        if topics.get(requested) != CAMERA_INFO_TYPE:
            kind = topics.get(requested, 'none (no such topic)')
            raise ValueError(f'{requested} has type {kind}, not {CAMERA_INFO_TYPE} (CameraInfo '
                             f'topics: {", ".join(infos) or "none"})')
        return requested, 'given'
    if not infos:
        return None, 'the bag has no CameraInfo topic'
    if DEFAULT_INFO_TOPIC in infos:
        return DEFAULT_INFO_TOPIC, 'the default topic'
    best = max(infos, key=lambda topic: len(os.path.commonprefix([topic, depth_topic])))
    return best, f'found by type, the nearest to {depth_topic}'


# --------------------------------------------------------------------------------------------
# Saying what is used, checking it against the data


def parse_intrinsics(text: str) -> Intrinsics:
    """``fx,fy,cx,cy`` [px] -> Intrinsics (argparse type)."""
    try:
        values = [float(v) for v in text.split(',')]
        if len(values) != 4:
            raise ValueError(f'4 values needed, got {len(values)}')
        return Intrinsics(*values)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f'expected fx,fy,cx,cy, got {text!r}: {exc}') from None


def intrinsics_text(intrinsics: Intrinsics) -> str:
    """``fx 535.4 fy 539.2 cx 320.1 cy 247.6 px``."""
    return (f'fx {intrinsics.fx:g} fy {intrinsics.fy:g} cx {intrinsics.cx:g} '
            f'cy {intrinsics.cy:g} px')


def mount_text(params: DetectorParams) -> str:
    """``height 0.60 m, pitch 0.0 deg, roll 0.0 deg`` of the parameters' camera mount."""
    return (f'height {params.camera_height_m:.2f} m, pitch '
            f'{math.degrees(params.camera_pitch_rad):.1f} deg, roll '
            f'{math.degrees(params.camera_roll_rad):.1f} deg')


def time_text(stamp_ns: int, first_ns: int) -> str:
    """Return ``t = 1.667 s``, a message's time after the first of its recording.

    A stamp read as a date (1796279833.666666667) says nothing at a glance.
    """
    return f't = {(stamp_ns - first_ns) / 1e9:.3f} s'


def intrinsics_warning(intrinsics: Intrinsics, shape: tuple[int, int]) -> str | None:
    """Why these intrinsics do not fit an (H, W) image (principal point off centre), or None."""
    height, width = shape
    if abs(intrinsics.cx - width / 2) > width / 4 or abs(intrinsics.cy - height / 2) > height / 4:
        return (f'the principal point ({intrinsics.cx:g}, {intrinsics.cy:g}) is far from the '
                f'centre ({width / 2:g}, {height / 2:g}) of the {width}x{height} image: these '
                'intrinsics are not this camera\'s')
    return None


def depth_unit_warning(depth: np.ndarray, depth_scale: float | None,
                       option: str = '--depth-scale', *,
                       out_of_range_m: float | None = None) -> str | None:
    """Say why integer depth read at ``depth_scale`` units/m looks like another unit, or None.

    It does when its median is not what a depth camera sees indoors, when 5 % of it lies beyond
    FAR_DEPTH_M, or (``out_of_range_m`` given) when another known scale fits the median better.
    """
    arr = np.asarray(depth)
    valid = arr[arr > 0] if arr.dtype.kind in 'ui' else arr[:0]
    if valid.size == 0:
        return None
    scale = 1000.0 if depth_scale is None else float(depth_scale)
    median_units = float(np.median(valid))
    median_m = median_units / scale
    far_m = float(np.quantile(valid, 0.95)) / scale
    low, high = PLAUSIBLE_MEDIAN_DEPTH_M
    fits = [s for s in KNOWN_DEPTH_SCALES if low <= median_units / s <= high]
    best = min(fits, key=lambda s: abs(math.log(median_units / s / 2.0)), default=None)
    better = best is not None and best != scale
    if not low <= median_m <= high:
        text = (f'the depth looks like another unit: read at {scale:g} units/m its median is '
                f'{median_m:.2f} m, {"beyond" if median_m > high else "below"} what a depth '
                f'camera sees indoors ({low:g}-{high:g} m)')
    elif far_m > FAR_DEPTH_M:
        text = (f'the depth looks like another unit: read at {scale:g} units/m, 5% of it lies '
                f'beyond {far_m:.1f} m (median {median_m:.2f} m), farther than a depth camera '
                'sees indoors')
    elif out_of_range_m is not None and better:
        return (f'read at {scale:g} units/m the depth\'s median is {median_m:.2f} m and little '
                f'of it lies within {out_of_range_m:g} m: if the depth is in another unit, '
                f'{option} {best:g} ({KNOWN_DEPTH_SCALES[best]}) would make its median '
                f'{median_units / best:.2f} m')
    else:
        return None
    if better:
        text += (f'; with {option} {best:g} ({KNOWN_DEPTH_SCALES[best]}) the median would be '
                 f'{median_units / best:.2f} m')
    return text


@dataclass(frozen=True)
class MountCheck:
    """The floor found in a frame compared with the mount in use."""

    estimate: object | None
    warning: str | None = None
    reason: str = ''


def check_mount(depth_m: np.ndarray, intrinsics: Intrinsics, params: DetectorParams,
                fix: str = '--estimate-mount') -> MountCheck:
    """Find the floor (``mount.estimate_mount``, RANSAC) and compare it with the params' mount."""
    from obstacle_detection.pipeline.mount import estimate_mount

    try:
        estimate = estimate_mount(depth_m, intrinsics)
    except ValueError as exc:
        return MountCheck(None, reason=str(exc))
    d_angle = max(abs(estimate.pitch_deg - math.degrees(params.camera_pitch_rad)),
                  abs(estimate.roll_deg - math.degrees(params.camera_roll_rad)))
    if (abs(estimate.height_m - params.camera_height_m) <= MOUNT_HEIGHT_TOLERANCE_M
            and d_angle <= MOUNT_ANGLE_TOLERANCE_DEG):
        return MountCheck(estimate)
    warning = (f'the floor in view ({estimate.inlier_fraction:.0%} of the points) puts the '
               f'camera at height {estimate.height_m:.2f} m, pitch {estimate.pitch_deg:.1f} deg, '
               f'roll {estimate.roll_deg:.1f} deg, but the mount used is {mount_text(params)}: '
               f'the floor will be marked as obstacles or cut off; use {fix}')
    return MountCheck(estimate, warning)


def int_in(low: int, high: int | None = None) -> Callable[[str], int]:
    """Return an argparse type: an integer in ``low..high`` (no upper bound when None)."""
    wanted = f'in {low}..{high}' if high is not None else f'>= {low}'

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'must be an integer {wanted}, got {text!r}') \
                from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f'must be {wanted}, got {value}')
        return value

    return parse


#: A ROS_DOMAIN_ID for argparse: an integer in 0..232 (Fast DDS's port range).
domain_id = int_in(0, 232)


def add_domain_id_option(parser: argparse.ArgumentParser, help_text: str) -> None:
    """Add ``--domain-id``: default an exported ROS_DOMAIN_ID, else 100-200 from the pid.

    A user in a domain of their own sees the run's topics there; without one, the run gets a
    domain of its own so that two runs on a machine do not mix.
    """
    exported = os.environ.get('ROS_DOMAIN_ID', '').strip()

    def parse(text: str) -> int:
        try:
            return domain_id(text)
        except argparse.ArgumentTypeError as err:
            if exported and text == exported:
                raise argparse.ArgumentTypeError(
                    f'ROS_DOMAIN_ID={exported!r} (from the environment) {err}') from None
            raise

    parser.add_argument('--domain-id', type=parse,
                        default=exported or str(100 + os.getpid() % 101), metavar='ID',
                        help=f'{help_text} (default: ROS_DOMAIN_ID when exported, else 100-200 '
                             'from the process id)')


def add_topic_options(parser: argparse.ArgumentParser) -> None:
    """Add a bag's ``--depth-topic`` and ``--info-topic``."""
    parser.add_argument('--depth-topic', default=DEFAULT_DEPTH_TOPIC,
                        help='depth topic (default %(default)s)')
    parser.add_argument('--info-topic', help=f'CameraInfo topic (default: {DEFAULT_INFO_TOPIC}, '
                                             "else the bag's CameraInfo topic found by type)")


def pin_one_cpu() -> str:
    """Pin this process to one CPU and OpenCV to one thread; return what was done."""
    import cv2

    cv2.setNumThreads(1)
    if hasattr(os, 'sched_setaffinity'):
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return f'pinned to CPU {cpu}; BLAS/OpenMP/OpenCV threads = 1'
    return 'not pinned (no sched_setaffinity); BLAS/OpenMP/OpenCV threads = 1'
