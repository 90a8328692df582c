#!/usr/bin/env python3
"""Convert recorded RGB-D data into rosbag2 bags that the detector can replay.

Sources (one sub-command each):

``tum``
    RGB-D benchmark layout (TUM RGB-D; also ETH3D SLAM, Bonn, ICL-NUIM in TUM format):
    ``rgb.txt`` and ``depth.txt`` list ``timestamp filename`` lines (``#`` starts a comment),
    depth is a 16-bit PNG with 5000 units per metre. Depth keeps its real timestamps and is
    written in millimetres (``round(v / 5)``); each depth frame gets the colour frame nearest in
    time if it is within ``--max-difference`` seconds, otherwise it is kept without colour and
    counted as a dropped pair. Intrinsics: ``--camera fr1|fr2|fr3|ros`` or ``--intrinsics FILE``;
    without either, ``freiburgN`` in the folder name chooses, then an ETH3D ``calibration.txt``
    in the folder, then the ROS default (with a warning).
``diml``
    DIML/CVL RGB-D indoor (Kinect v2) full release: a sequence folder ``<scene>/<date>/<n>``
    holding ``col/`` (``..._c.png``) and ``raw_png/`` (``..._rd.png``), ``up_png/``
    (``..._ud.png``, upsampled) and ``warp_png/`` (``..._wd.png``, warped to the colour view);
    depth is 16-bit millimetres. The release has no timestamps and no intrinsics: frame ``i``
    (the number before the suffix, e.g. 000630 in ``in_k_03_170201_000630_rd.png``) is stamped
    ``start + i / rate``; intrinsics come from ``--intrinsics`` or, loudly, from defaults.
``diml-sample``
    The DIML sample subset: ``<split>/{HR,LR}/<scene>/{color,depth_filled}/`` with
    ``<id>_c.png`` and ``<id>_depth_filled.png`` (16-bit millimetres). The samples are not a
    sequence; they are sorted by scene and id and stamped ``start + k / rate``.
``folder``
    A folder of 16-bit depth PNGs in millimetres (and optionally a colour folder with as many
    images), sorted by name and stamped ``start + k / rate``.
``ros1``
    A ROS 1 bag (e.g. from the iai_kinect2 driver): every message (or those of ``--topics``)
    is converted to its ROS 2 Jazzy type and written with its topic, stamp and data. Compressed
    depth (``sensor_msgs/CompressedImage`` such as iai_kinect2's
    ``/kinect2/sd/image_depth_rect/compressed`` or image_transport's ``.../compressedDepth``)
    is kept as it is, for ``bag_process.py --depth-topic``, and named in the summary; with
    ``--decompress-depth`` it is decoded instead (``obstacle_detection.ros.compressed_depth``,
    16UC1 exactly) and written as a raw ``sensor_msgs/Image`` on the raw topic (``.../compressed``
    -> ``...``), which the node and every tool read.

Output: a rosbag2 folder (``--storage sqlite3`` by default, or ``mcap``) with, per frame, a
``sensor_msgs/Image`` depth (16UC1, millimetres), a ``sensor_msgs/CameraInfo`` and, when
available, a colour ``Image`` (``bgr8`` or ``rgb8``), all with the frame's stamp as header stamp
and bag timestamp, on the Kinect v2 driver's SD topics by default. The bag is written into a
temporary sibling folder and renamed when complete, so a failed run leaves nothing behind.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import math
import re
import shutil
import sys
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

if __package__ in (None, ''):  # run as a script: make the repository root importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402
from builtin_interfaces.msg import Time  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from obstacle_detection.cli import support as tool_support  # noqa: E402
from obstacle_detection.ros.compressed_depth import (COMPRESSED_IMAGE_TYPE,  # noqa: E402
                                                 CompressedDepthError,
                                                 compressed_depth_to_array, parse_format,
                                                 raw_topic)
from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info  # noqa: E402
from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE, Intrinsics  # noqa: E402
from obstacle_detection.cli.progress import Progress  # noqa: E402

# The one set of default topic names of every tool (tool_support), kept here under their names.
DEFAULT_DEPTH_TOPIC = tool_support.DEFAULT_DEPTH_TOPIC
DEFAULT_INFO_TOPIC = tool_support.DEFAULT_INFO_TOPIC
DEFAULT_COLOR_TOPIC = tool_support.DEFAULT_COLOR_TOPIC
DEFAULT_FRAME_ID = 'kinect2_ir_optical_frame'
#: Odometry of frames that carry a pose (nav_msgs/Odometry, base_footprint in odom).
DEFAULT_ODOM_TOPIC = '/odom'
BAG_VERSION = 9
STORAGES = {'sqlite3': StoragePlugin.SQLITE3, 'mcap': StoragePlugin.MCAP}

#: TUM RGB-D benchmark cameras (fx, fy, cx, cy) for 640x480 images, and the ROS default.
TUM_CAMERAS: dict[str, Intrinsics] = {
    'fr1': Intrinsics(517.3, 516.5, 318.6, 255.3),
    'fr2': Intrinsics(520.9, 521.0, 325.1, 249.7),
    'fr3': Intrinsics(535.4, 539.2, 320.1, 247.6),
    'ros': Intrinsics(525.0, 525.0, 319.5, 239.5),
}
#: Depth units per metre in the TUM-format benchmarks.
TUM_DEPTH_UNITS_PER_M = 5000

#: Nominal Kinect v2 colour camera at 1920x1080 (libfreenect2's factory defaults), used, scaled
#: to the image size, for depth that DIML warped or upsampled into the colour view when the
#: user gives no intrinsics.
KINECT_V2_COLOR = Intrinsics(1081.37, 1081.37, 959.5, 539.5)
KINECT_V2_COLOR_SIZE = (1920, 1080)

DIML_DEPTH_KINDS = {  # --depth choice -> (folder, file suffix)
    'raw': ('raw_png', '_rd.png'),
    'up': ('up_png', '_ud.png'),
    'warp': ('warp_png', '_wd.png'),
}
DIML_COLOR = ('col', '_c.png')
DIML_SAMPLE_COLOR = ('color', '_c.png')
DIML_SAMPLE_DEPTH = ('depth_filled', '_depth_filled.png')


class ConvertError(Exception):
    """Bad input or output for a conversion; the message names the offending file."""


@dataclasses.dataclass(frozen=True)
class Frame:
    """One depth frame to write, with the colour image paired to it (if any)."""

    stamp_ns: int
    depth_path: Path
    color_path: Path | None = None
    #: the robot base pose in odom at the frame, (x [m], y [m], yaw [rad]): written as
    #: nav_msgs/Odometry on BagOptions.odom_topic (None: no odometry for this frame)
    pose: tuple[float, float, float] | None = None


@dataclasses.dataclass
class FrameSource:
    """What a dataset layout yields: frames, their camera and what could not be paired.

    ``intrinsics`` None means "not given": defaults for the view are chosen (with a warning)
    once the image size is known. ``size`` is (width, height) from the intrinsics file, checked
    against the images when given.
    """

    frames: list[Frame]
    intrinsics: Intrinsics | None
    intrinsics_origin: str
    size: tuple[int, int] | None = None
    depth_divisor: int = 1
    default_view: str = 'depth'
    dropped: Counter[str] = dataclasses.field(default_factory=Counter)
    notes: list[str] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(frozen=True)
class BagOptions:
    """Where and how frames are written."""

    storage: str = 'sqlite3'
    depth_topic: str = DEFAULT_DEPTH_TOPIC
    info_topic: str = DEFAULT_INFO_TOPIC
    color_topic: str = DEFAULT_COLOR_TOPIC
    frame_id: str = DEFAULT_FRAME_ID
    color_encoding: str = 'bgr8'
    odom_topic: str = DEFAULT_ODOM_TOPIC
    with_color: bool = True
    progress: bool = True


@dataclasses.dataclass
class Summary:
    """What a conversion wrote."""

    output: Path
    frames: int = 0
    color_frames: int = 0
    messages: int = 0
    duration_s: float = 0.0
    size: tuple[int, int] | None = None
    intrinsics: Intrinsics | None = None
    dropped: Counter[str] = dataclasses.field(default_factory=Counter)
    topics: dict[str, int] = dataclasses.field(default_factory=dict)
    notes: list[str] = dataclasses.field(default_factory=list)

    def lines(self) -> list[str]:
        """Return the summary as printable lines."""
        out = [f'wrote {self.output}']
        if self.size is None:  # a bag conversion: no frames of our own
            out.append(f'  {self.messages} messages; duration {self.duration_s:.3f} s')
        else:
            out.append(f'  frames: {self.frames} depth ({self.size[0]}x{self.size[1]}, 16UC1 mm), '
                       f'{self.color_frames} with colour; duration {self.duration_s:.3f} s')
        if self.intrinsics is not None:
            i = self.intrinsics
            out.append(f'  intrinsics: fx={i.fx:g} fy={i.fy:g} cx={i.cx:g} cy={i.cy:g}')
        for topic, count in self.topics.items():
            out.append(f'  {topic}: {count} messages')
        if self.size is not None:
            out.append(f'  dropped pairs: {sum(self.dropped.values())}')
            out.extend(f'    {count}: {reason}' for reason, count in self.dropped.items())
        out.extend(f'  note: {note}' for note in self.notes)
        return out


# --------------------------------------------------------------------------------------------
# Intrinsics


def load_intrinsics(path: Path) -> tuple[Intrinsics, tuple[int, int] | None]:
    """Read camera intrinsics from a file.

    Accepted: a YAML mapping with ``fx, fy, cx, cy`` and optionally ``width, height`` (also
    nested under an ``intrinsics`` or ``camera`` key); a ROS ``camera_info`` YAML
    (``camera_matrix: {data: [...]}``, ``image_width``, ``image_height``); or an ETH3D
    ``calibration.txt`` holding ``fx fy cx cy`` on one line.

    Returns:
        The intrinsics and (width, height) if the file gives them.

    Raises:
        ConvertError: naming the file when it is missing, unreadable or incomplete.
    """
    try:
        text = path.read_text()
    except OSError as err:
        raise ConvertError(f'{path}: cannot read intrinsics file ({err.strerror})') from err
    numbers = text.split()
    try:
        if len(numbers) == 4 and all(_is_number(n) for n in numbers):
            return _intrinsics(path, *map(float, numbers)), None
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConvertError(f'{path}: not valid YAML ({err})') from err
    if not isinstance(data, dict):
        raise ConvertError(f'{path}: expected a mapping with fx, fy, cx, cy')
    for key in ('intrinsics', 'camera'):
        if isinstance(data.get(key), dict):
            data = data[key]
    size = None
    if 'camera_matrix' in data:
        try:
            k = [float(v) for v in data['camera_matrix']['data']]
            values = (k[0], k[4], k[2], k[5])
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise ConvertError(f'{path}: camera_matrix must hold 9 numbers in data') from err
        width, height = data.get('image_width'), data.get('image_height')
    else:
        missing = [k for k in ('fx', 'fy', 'cx', 'cy') if k not in data]
        if missing:
            raise ConvertError(f'{path}: missing {", ".join(missing)} (need fx, fy, cx, cy)')
        try:
            values = tuple(float(data[k]) for k in ('fx', 'fy', 'cx', 'cy'))
        except (TypeError, ValueError) as err:
            raise ConvertError(f'{path}: fx, fy, cx, cy must be numbers') from err
        width, height = data.get('width'), data.get('height')
    if (width is None) != (height is None):
        raise ConvertError(f'{path}: give both width and height, or neither')
    if width is not None:
        try:
            size = (int(width), int(height))
        except (TypeError, ValueError) as err:
            raise ConvertError(f'{path}: width and height must be integers') from err
        if size[0] <= 0 or size[1] <= 0:
            raise ConvertError(f'{path}: width and height must be positive, got {size}')
    return _intrinsics(path, *values), size


def _intrinsics(path: Path, fx: float, fy: float, cx: float, cy: float) -> Intrinsics:
    try:
        return Intrinsics(fx, fy, cx, cy)
    except ValueError as err:
        raise ConvertError(f'{path}: {err}') from err


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def scaled_intrinsics(intr: Intrinsics, from_size: tuple[int, int],
                      to_size: tuple[int, int]) -> Intrinsics:
    """Scale intrinsics given for an image of ``from_size`` to ``to_size`` (width, height)."""
    sx = to_size[0] / from_size[0]
    sy = to_size[1] / from_size[1]
    return Intrinsics(intr.fx * sx, intr.fy * sy,
                      (intr.cx + 0.5) * sx - 0.5, (intr.cy + 0.5) * sy - 0.5)


def default_intrinsics(view: str, size: tuple[int, int]) -> tuple[Intrinsics, str]:
    """Kinect v2 nominal intrinsics for the depth or colour view, scaled to ``size``."""
    if view == 'depth':
        base, base_size, name = KINECT_V2_SD, KINECT_V2_SD_SIZE, 'Kinect v2 depth camera'
    else:
        base, base_size, name = KINECT_V2_COLOR, KINECT_V2_COLOR_SIZE, 'Kinect v2 colour camera'
    if tuple(size) == tuple(base_size):
        return base, f'{name} defaults'
    return (scaled_intrinsics(base, base_size, size),
            f'{name} defaults scaled from {base_size[0]}x{base_size[1]} to {size[0]}x{size[1]}')


# --------------------------------------------------------------------------------------------
# Dataset layouts


def stamp_ns(seconds: float) -> int:
    """Seconds to integer nanoseconds (rounded).

    Frame stamps are ``stamp_ns(start) + stamp_ns(i / rate)``: adding in integers keeps the
    frame spacing exact to the nanosecond even for a start near the current epoch.
    """
    return int(round(seconds * 1e9))


def _require_dir(path: Path, what: str) -> None:
    if not path.is_dir():
        raise ConvertError(f'{path}: {what} folder not found')


def _optional_intrinsics(path: Path | None
                         ) -> tuple[Intrinsics | None, str, tuple[int, int] | None]:
    if path is None:
        return None, '', None
    intr, size = load_intrinsics(path)
    return intr, f'from {path}', size


def _check_rate(rate_hz: float) -> None:
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ConvertError(f'--rate must be a positive number of frames per second, got {rate_hz}')


def _files_with_suffix(folder: Path, suffix: str) -> dict[str, Path]:
    """Map the name without ``suffix`` to the path, for files in ``folder`` ending in it."""
    return {p.name[:-len(suffix)]: p for p in sorted(folder.iterdir())
            if p.is_file() and p.name.endswith(suffix)}


def _pair_by_key(depth: dict[str, Path], color: dict[str, Path], depth_dir: Path,
                 color_dir: Path) -> None:
    """Raise unless depth and colour folders hold the same frames."""
    if len(depth) != len(color):
        raise ConvertError(f'{depth_dir} holds {len(depth)} depth images but {color_dir} holds '
                           f'{len(color)} colour images; they must match one to one')
    for key, path in depth.items():
        if key not in color:
            raise ConvertError(f'{path}: no colour image for this depth image in {color_dir}')


def diml_frames(sequence: Path, *, depth_kind: str = 'raw', intrinsics_path: Path | None = None,
                rate_hz: float = 30.0, start_s: float = 0.0,
                with_color: bool = True) -> FrameSource:
    """List the frames of one DIML/CVL indoor sequence folder (``<scene>/<date>/<n>``).

    Frame ``i`` (the number before the suffix) is stamped ``start_s + i / rate_hz``.
    """
    _check_rate(rate_hz)
    folder, suffix = DIML_DEPTH_KINDS[depth_kind]
    depth_dir = sequence / folder
    if not sequence.is_dir():
        raise ConvertError(f'{sequence}: DIML sequence folder not found')
    if not depth_dir.is_dir():
        found = sorted(p.parent for p in sequence.rglob(folder) if p.is_dir())
        hint = (f'; sequence folders below it: {", ".join(map(str, found[:5]))}'
                + (' ...' if len(found) > 5 else '')) if found else ''
        raise ConvertError(f'{depth_dir}: DIML {depth_kind} depth folder not found '
                           f'(pass a <scene>/<date>/<n> folder){hint}')
    depth = _files_with_suffix(depth_dir, suffix)
    if not depth:
        raise ConvertError(f'{depth_dir}: no *{suffix} depth images')
    pattern = re.compile(r'(\d+)$')
    frames_index: dict[str, int] = {}
    for key, path in depth.items():
        match = pattern.search(key)
        if match is None:
            raise ConvertError(f'{path}: no frame number before {suffix} in the file name')
        frames_index[key] = int(match.group(1))
    color: dict[str, Path] = {}
    color_dir = sequence / DIML_COLOR[0]
    if with_color and color_dir.is_dir():
        color = _files_with_suffix(color_dir, DIML_COLOR[1])
        _pair_by_key(depth, color, depth_dir, color_dir)
    intr, origin, size = _optional_intrinsics(intrinsics_path)
    start_ns = stamp_ns(start_s)
    frames = [Frame(start_ns + stamp_ns(frames_index[key] / rate_hz), path, color.get(key))
              for key, path in sorted(depth.items(), key=lambda kv: frames_index[kv[0]])]
    notes = [f'DIML has no timestamps: frames stamped from their number at {rate_hz:g} Hz']
    if with_color and not color_dir.is_dir():
        notes.append(f'{color_dir} not found: no colour written')
    return FrameSource(frames, intr, origin, size,
                       default_view='depth' if depth_kind == 'raw' else 'color', notes=notes)


def diml_sample_frames(root: Path, *, resolution: str = 'LR',
                       intrinsics_path: Path | None = None, rate_hz: float = 30.0,
                       start_s: float = 0.0, with_color: bool = True) -> FrameSource:
    """List the frames of the DIML sample subset below ``root``.

    ``root`` is a split folder (``.../test``), a resolution folder (``.../test/LR``) or one
    scene folder holding ``color/`` and ``depth_filled/``. Frames are sorted by scene folder
    and id and stamped ``start_s + k / rate_hz``.
    """
    _check_rate(rate_hz)
    if not root.is_dir():
        raise ConvertError(f'{root}: DIML sample folder not found')
    name = DIML_SAMPLE_DEPTH[0]
    depth_dirs = sorted({p for p in [root / name, *root.rglob(name)] if p.is_dir()})
    # Below a split folder both HR and LR exist: keep the chosen one.
    parts = {part for p in depth_dirs for part in p.relative_to(root).parts}
    if {'HR', 'LR'} & parts:
        depth_dirs = [p for p in depth_dirs if resolution in p.relative_to(root).parts]
        if not depth_dirs:
            raise ConvertError(f'{root}: no {resolution}/ folder below it')
    if not depth_dirs:
        raise ConvertError(f'{root}: no {DIML_SAMPLE_DEPTH[0]}/ folder below it '
                           f'(expected <split>/{{HR,LR}}/<scene>/{{color,depth_filled}})')
    frames: list[Frame] = []
    for depth_dir in depth_dirs:
        depth = _files_with_suffix(depth_dir, DIML_SAMPLE_DEPTH[1])
        if not depth:
            raise ConvertError(f'{depth_dir}: no *{DIML_SAMPLE_DEPTH[1]} depth images')
        color: dict[str, Path] = {}
        if with_color:
            color_dir = depth_dir.parent / DIML_SAMPLE_COLOR[0]
            _require_dir(color_dir, 'DIML sample colour')
            color = _files_with_suffix(color_dir, DIML_SAMPLE_COLOR[1])
            _pair_by_key(depth, color, depth_dir, color_dir)
        for key, path in depth.items():
            stamp = stamp_ns(start_s) + stamp_ns(len(frames) / rate_hz)
            frames.append(Frame(stamp, path, color.get(key)))
    intr, origin, size = _optional_intrinsics(intrinsics_path)
    notes = [f'DIML samples have no timestamps: stamped in file order at {rate_hz:g} Hz']
    return FrameSource(frames, intr, origin, size, default_view='color', notes=notes)


def folder_frames(depth_dir: Path, *, color_dir: Path | None = None,
                  intrinsics_path: Path | None = None, rate_hz: float = 30.0,
                  start_s: float = 0.0) -> FrameSource:
    """List a folder of depth PNGs (and a colour folder), sorted by name, stamped by rate."""
    _check_rate(rate_hz)
    _require_dir(depth_dir, 'depth')
    depth = sorted(p for p in depth_dir.iterdir() if p.is_file() and p.suffix.lower() == '.png')
    if not depth:
        raise ConvertError(f'{depth_dir}: no .png depth images')
    color: list[Path | None] = [None] * len(depth)
    if color_dir is not None:
        _require_dir(color_dir, 'colour')
        found = sorted(p for p in color_dir.iterdir()
                       if p.is_file() and p.suffix.lower() in ('.png', '.jpg', '.jpeg'))
        if len(found) != len(depth):
            raise ConvertError(f'{depth_dir} holds {len(depth)} depth images but {color_dir} '
                               f'holds {len(found)} colour images; they must match one to one')
        color = list(found)
    intr, origin, size = _optional_intrinsics(intrinsics_path)
    frames = [Frame(stamp_ns(start_s) + stamp_ns(k / rate_hz), d, c)
              for k, (d, c) in enumerate(zip(depth, color))]
    return FrameSource(frames, intr, origin, size)


def read_timestamp_list(path: Path) -> list[tuple[float, str]]:
    """Read a TUM ``rgb.txt`` / ``depth.txt``: ``timestamp filename`` lines, ``#`` comments."""
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise ConvertError(f'{path}: cannot read ({err.strerror})') from err
    entries = []
    for number, line in enumerate(lines, start=1):
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        parts = line.replace(',', ' ').split()
        if len(parts) < 2 or not _is_number(parts[0]):
            raise ConvertError(f'{path}:{number}: expected "timestamp filename", got {line!r}')
        entries.append((float(parts[0]), parts[1]))
    return sorted(entries)


def tum_frames(root: Path, *, camera: str | None = None, intrinsics_path: Path | None = None,
               max_difference_s: float = 0.02, with_color: bool = True) -> FrameSource:
    """List the depth frames of a TUM-format sequence, each with its nearest colour frame."""
    if not root.is_dir():
        raise ConvertError(f'{root}: sequence folder not found')
    if not (math.isfinite(max_difference_s) and max_difference_s >= 0):
        raise ConvertError(f'--max-difference must be >= 0 s, got {max_difference_s}')
    depth_list = root / 'depth.txt'
    if not depth_list.is_file():
        raise ConvertError(f'{depth_list}: not found (expected a TUM-format sequence folder)')
    depth = read_timestamp_list(depth_list)
    if not depth:
        raise ConvertError(f'{depth_list}: lists no depth images')
    notes: list[str] = []
    dropped: Counter[str] = Counter()
    color_for: list[Path | None] = [None] * len(depth)
    rgb_list = root / 'rgb.txt'
    if with_color and rgb_list.is_file():
        rgb = read_timestamp_list(rgb_list)
        rgb_t = np.array([t for t, _ in rgb])
        used = set()
        for k, (t, _) in enumerate(depth):
            if len(rgb_t) == 0:
                dropped['rgb.txt lists no colour images'] += 1
                continue
            j = int(np.searchsorted(rgb_t, t))
            best = min((c for c in (j - 1, j) if 0 <= c < len(rgb_t)),
                       key=lambda c: abs(rgb_t[c] - t))
            if abs(rgb_t[best] - t) <= max_difference_s:
                color_for[k] = root / rgb[best][1]
                used.add(best)
            else:
                dropped[f'no colour frame within {max_difference_s:g} s of the depth frame '
                        '(kept without colour)'] += 1
        if len(rgb) > len(used):
            notes.append(f'{len(rgb) - len(used)} colour frames not nearest to any depth frame '
                         'were not written')
        notes.append('colour is stamped with the stamp of the depth frame it is paired with')
    elif with_color:
        notes.append(f'{rgb_list} not found: no colour written')
    frames = [Frame(stamp_ns(t), root / name, color_for[k]) for k, (t, name) in enumerate(depth)]

    intr, origin, size = _optional_intrinsics(intrinsics_path)
    if intr is None and camera is not None:
        intr, origin = TUM_CAMERAS[camera], f'TUM camera {camera}'
    if intr is None:
        match = re.search(r'freiburg([123])', root.resolve().name)
        calibration = root / 'calibration.txt'
        if match:
            name = f'fr{match.group(1)}'
            intr, origin = TUM_CAMERAS[name], f'TUM camera {name} (from the folder name)'
        elif calibration.is_file():
            intr, size = load_intrinsics(calibration)
            origin = f'from {calibration}'
        else:
            intr, origin = TUM_CAMERAS['ros'], 'ROS default camera'
            _warn(f'no intrinsics for {root}: using the ROS default camera fx=fy=525 '
                  'cx=319.5 cy=239.5; pass --camera fr1|fr2|fr3 or --intrinsics FILE')
    return FrameSource(frames, intr, origin, size, depth_divisor=TUM_DEPTH_UNITS_PER_M // 1000,
                       dropped=dropped, notes=notes)


# --------------------------------------------------------------------------------------------
# Writing


def read_depth_png(path: Path, *, divisor: int = 1) -> np.ndarray:
    """Read a 16-bit single-channel depth PNG; return (H, W) uint16 millimetres.

    ``divisor`` converts other units to millimetres (5 for 5000 units per metre), rounding to
    the nearest millimetre.
    """
    if not path.is_file():
        raise ConvertError(f'{path}: depth image not found')
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ConvertError(f'{path}: cannot read depth image (not an image file?)')
    if image.ndim != 2:
        raise ConvertError(f'{path}: depth must have one channel, found {image.shape[2]}')
    if image.dtype != np.uint16:
        bits = image.dtype.itemsize * 8
        raise ConvertError(f'{path}: depth must be a 16-bit image in millimetres, '
                           f'found {bits}-bit ({image.dtype})')
    if divisor != 1:
        # (v + divisor // 2) // divisor rounds half up; with divisor 5 there are no ties.
        image = ((image.astype(np.uint32) + divisor // 2) // divisor).astype(np.uint16)
    return image


def read_color(path: Path, encoding: str) -> np.ndarray:
    """Read a colour image as (H, W, 3) uint8 in ``encoding`` ('bgr8' or 'rgb8')."""
    if not path.is_file():
        raise ConvertError(f'{path}: colour image not found')
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ConvertError(f'{path}: cannot read colour image')
    if encoding == 'rgb8':
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return image


def to_time(ns: int) -> Time:
    """Integer nanoseconds to a ``builtin_interfaces/Time``."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


@contextlib.contextmanager
def staged_output(output: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``output``; rename it to ``output`` on success.

    On any error the temporary folder is removed, so no half-written bag is left.
    """
    if output.exists() or output.is_symlink():
        raise ConvertError(f'{output}: output already exists; remove it or choose another name')
    parent = output.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        staging = parent / f'.{output.name}.partial'
        if staging.exists():
            shutil.rmtree(staging)
        staging.mkdir()
    except OSError as err:
        raise ConvertError(f'{parent}: cannot create the output ({err.strerror})') from err
    try:
        yield staging / output.name
        if output.exists():
            raise ConvertError(f'{output}: appeared while converting; not overwriting it')
        (staging / output.name).rename(output)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


class FrameBagWriter:
    """Write depth, camera-info and colour messages of frames to an open rosbag2 Writer."""

    def __init__(self, writer: Writer, options: BagOptions, *, color: bool,
                 odometry: bool = False) -> None:
        """Add the connections (color, odometry: whether those topics are wanted)."""
        typestore = get_typestore(Stores.ROS2_JAZZY)
        self.options = options
        self.depth = writer.add_connection(options.depth_topic, 'sensor_msgs/msg/Image',
                                           typestore=typestore)
        self.info = writer.add_connection(options.info_topic, 'sensor_msgs/msg/CameraInfo',
                                          typestore=typestore)
        self.color = (writer.add_connection(options.color_topic, 'sensor_msgs/msg/Image',
                                            typestore=typestore) if color else None)
        self.odom = (writer.add_connection(options.odom_topic, 'nav_msgs/msg/Odometry',
                                           typestore=typestore) if odometry else None)
        self.writer = writer

    def write_odometry(self, stamp: int, pose: tuple[float, float, float]) -> int:
        """Write the base pose in odom at bag time ``stamp`` [ns]; return 1 (or 0: no topic)."""
        if self.odom is None:
            return 0
        from nav_msgs.msg import Odometry

        msg = Odometry()
        msg.header.stamp = to_time(stamp)
        msg.header.frame_id = 'odom'
        msg.child_frame_id = 'base_footprint'
        msg.pose.pose.position.x, msg.pose.pose.position.y = float(pose[0]), float(pose[1])
        msg.pose.pose.orientation.z = math.sin(pose[2] / 2.0)
        msg.pose.pose.orientation.w = math.cos(pose[2] / 2.0)
        self.writer.write(self.odom, stamp, serialize_message(msg))
        return 1

    def write(self, stamp: int, depth_mm: np.ndarray, intr: Intrinsics,
              color: np.ndarray | None) -> int:
        """Write one frame at bag time ``stamp`` [ns]; return the number of messages."""
        time = to_time(stamp)
        frame_id = self.options.frame_id
        height, width = depth_mm.shape
        depth_msg = array_to_image(depth_mm, stamp=time, frame_id=frame_id, encoding='16UC1')
        info_msg = intrinsics_to_camera_info(intr, width, height, stamp=time, frame_id=frame_id)
        self.writer.write(self.info, stamp, serialize_message(info_msg))
        self.writer.write(self.depth, stamp, serialize_message(depth_msg))
        if color is None or self.color is None:
            return 2
        color_msg = array_to_image(color, stamp=time, frame_id=frame_id,
                                   encoding=self.options.color_encoding)
        self.writer.write(self.color, stamp, serialize_message(color_msg))
        return 3


def write_frames(source: FrameSource, output: Path, options: BagOptions) -> Summary:
    """Write the frames of ``source`` as a rosbag2 at ``output``.

    Raises:
        ConvertError: naming the file for an unreadable or wrong-format image, a size change,
            intrinsics that do not fit the images, or an existing output. Nothing is left at
            ``output`` then.
    """
    if not source.frames:
        raise ConvertError(f'{output}: no frames to write')
    first = source.frames[0].depth_path
    first_depth = read_depth_png(first, divisor=source.depth_divisor)
    size = (first_depth.shape[1], first_depth.shape[0])
    if source.size is not None and source.size != size:
        raise ConvertError(f'{source.intrinsics_origin.removeprefix("from ")}: intrinsics are '
                           f'for {source.size[0]}x{source.size[1]} images but {first} is '
                           f'{size[0]}x{size[1]}')
    intr, origin = source.intrinsics, source.intrinsics_origin
    if intr is None:
        intr, origin = default_intrinsics(source.default_view, size)
        _warn(f'no intrinsics given (--intrinsics FILE): using {origin}, fx={intr.fx:.2f} '
              f'fy={intr.fy:.2f} cx={intr.cx:.2f} cy={intr.cy:.2f}. Obstacle positions are '
              'only as right as these values.')
    with_color = options.with_color and any(f.color_path is not None for f in source.frames)
    summary = Summary(output=output, size=size, intrinsics=intr, dropped=source.dropped.copy(),
                      notes=[*source.notes, f'intrinsics: {origin}'])
    with staged_output(output) as staging:
        try:
            with Writer(staging, version=BAG_VERSION,
                        storage_plugin=STORAGES[options.storage]) as writer:
                with_odometry = any(f.pose is not None for f in source.frames)
                frame_writer = FrameBagWriter(writer, options, color=with_color,
                                              odometry=with_odometry)
                bar = Progress(len(source.frames), 'converting',
                               stream=None if options.progress else io.StringIO())
                with bar:
                    for k, frame in enumerate(source.frames):
                        depth = first_depth if k == 0 else read_depth_png(
                            frame.depth_path, divisor=source.depth_divisor)
                        if depth.shape != first_depth.shape:
                            raise ConvertError(
                                f'{frame.depth_path}: {depth.shape[1]}x{depth.shape[0]} but '
                                f'the first depth image {first} is {size[0]}x{size[1]}')
                        color = None
                        if with_color and frame.color_path is not None:
                            color = read_color(frame.color_path, options.color_encoding)
                            summary.color_frames += 1
                        if frame.pose is not None:
                            summary.messages += frame_writer.write_odometry(frame.stamp_ns,
                                                                            frame.pose)
                            summary.topics[options.odom_topic] = (
                                summary.topics.get(options.odom_topic, 0) + 1)
                        summary.messages += frame_writer.write(frame.stamp_ns, depth, intr, color)
                        summary.frames += 1
                        bar.update()
        except WriterError as err:
            raise ConvertError(f'{output}: cannot write bag ({err})') from err
    summary.topics = {options.depth_topic: summary.frames, options.info_topic: summary.frames,
                      **summary.topics}
    if with_color:
        summary.topics[options.color_topic] = summary.color_frames
    stamps = [f.stamp_ns for f in source.frames]
    summary.duration_s = (max(stamps) - min(stamps)) / 1e9
    if with_color and summary.color_frames and (
            read_color(next(f.color_path for f in source.frames if f.color_path),
                       'bgr8').shape[:2] != first_depth.shape):
        summary.notes.append('colour images differ in size from depth: the colour topic is not '
                             'registered to the depth image')
    return summary


def convert_ros1(src: Path, output: Path, *, storage: str = 'sqlite3',
                 topics: Sequence[str] = (), progress: bool = True,
                 decompress_depth: bool = False) -> Summary:
    """Convert a ROS 1 bag to rosbag2, every message to its ROS 2 Jazzy type.

    Topics, bag timestamps, header stamps, frame ids and data are kept; ROS 1 only fields
    (``Header.seq``) are dropped and renamed fields (``CameraInfo.D`` -> ``d``) carried over.
    A CompressedImage topic whose first message's format names a depth encoding
    (``compressed_depth.parse_format``) is compressed depth: named in the summary's notes and,
    with ``decompress_depth``, decoded and written as ``sensor_msgs/Image`` on its raw topic
    (``raw_topic``); a frame that cannot be decoded is left out, counted in the notes and
    warned about.

    Raises:
        ConvertError: naming the bag: unreadable, not ROS 1, no such topic, or (with
            ``decompress_depth``) a raw topic that is recorded too.
    """
    # Imported here: only this conversion needs them.
    from rosbags.convert.converter import create_connections_converters
    from rosbags.highlevel import AnyReader, AnyReaderError

    if not src.is_file():
        raise ConvertError(f'{src}: ROS 1 bag not found')
    summary = Summary(output=output)
    noetic = get_typestore(Stores.ROS1_NOETIC)
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    with staged_output(output) as staging:
        try:
            with AnyReader([src], default_typestore=noetic) as reader:
                if reader.is2:
                    raise ConvertError(f'{src}: not a ROS 1 bag (expected a .bag file)')
                connections = [c for c in reader.connections if not topics or c.topic in topics]
                if missing := sorted(set(topics) - {c.topic for c in reader.connections}):
                    raise ConvertError(f'{src}: has no topic {", ".join(missing)}')
                if not connections:
                    raise ConvertError(f'{src}: contains no messages')
                depth = _compressed_depth_topics(reader, connections, noetic)
                for topic, fmt in sorted(depth.items()):
                    summary.notes.append(
                        f'{topic}: compressed depth ({fmt!r}); '
                        + (f'decoded to sensor_msgs/Image on {raw_topic(topic)}'
                           if decompress_depth else
                           f'bag_process.py --depth-topic {topic} reads it (or convert with '
                           '--decompress-depth)'))
                decoded = set(depth) if decompress_depth else set()
                targets = Counter(raw_topic(t) for t in decoded)
                if clash := sorted(t for t, n in targets.items() if n > 1 or t in (
                        {c.topic for c in connections} - decoded)):
                    raise ConvertError(
                        f'{src}: {", ".join(clash)} would be written twice by '
                        '--decompress-depth (recorded raw too, or from two compressed topics); '
                        'choose one with --topics')
                total = sum(c.msgcount for c in connections)
                with Writer(staging, version=BAG_VERSION,
                            storage_plugin=STORAGES[storage]) as writer:
                    kept = [c for c in connections if c.topic not in decoded]
                    # rosbags prints which types it migrates; keep stdout for our summary.
                    with contextlib.redirect_stdout(io.StringIO()):
                        connmap, convmap = create_connections_converters(
                            kept, jazzy, reader, writer) if kept else ({}, {})
                    raw_conns = {t: writer.add_connection(raw_topic(t), tool_support.IMAGE_TYPE,
                                                          typestore=jazzy)
                                 for t in sorted(decoded)}
                    counts: Counter[str] = Counter()
                    failed: Counter[tuple[str, str]] = Counter()
                    with Progress(total, 'converting',
                                  stream=None if progress else io.StringIO()) as bar:
                        for conn, timestamp, data in reader.messages(connections=connections):
                            bar.update()
                            if conn.topic in decoded:
                                image, reason = _decoded_depth(data, noetic)
                                if image is None:
                                    failed[(conn.topic, reason)] += 1
                                    continue
                                writer.write(raw_conns[conn.topic], timestamp, image)
                                counts[raw_topic(conn.topic)] += 1
                                continue
                            writer.write(connmap[(conn.id, conn.owner)], timestamp,
                                         convmap[conn.msgtype](data))
                            counts[conn.topic] += 1
                summary.duration_s = (reader.end_time - reader.start_time) / 1e9
        except AnyReaderError as err:
            raise ConvertError(f'{src}: cannot read ROS 1 bag ({err})') from err
        except WriterError as err:
            raise ConvertError(f'{output}: cannot write bag ({err})') from err
    for (topic, reason), count in sorted(failed.items()):
        note = f'{count} frame(s) of {topic} not decoded, left out: {reason}'
        summary.notes.append(note)
        _warn(note)
    summary.topics = dict(sorted(counts.items()))
    summary.messages = sum(counts.values())
    summary.frames = max(counts.values(), default=0)
    return summary


def _compressed_depth_topics(reader: Any, connections: Sequence[Any],
                             typestore: Any) -> dict[str, str]:
    """Map each CompressedImage topic holding depth to its first message's format."""
    found: dict[str, str] = {}
    for conn in connections:
        if conn.msgtype != COMPRESSED_IMAGE_TYPE or conn.msgcount == 0 or conn.topic in found:
            continue
        _, _, data = next(iter(reader.messages(connections=[conn])))
        fmt = str(typestore.deserialize_ros1(data, COMPRESSED_IMAGE_TYPE).format)
        try:
            parse_format(fmt)
        except CompressedDepthError:
            continue  # colour (jpeg, png of bgr8, ...): not depth
        found[conn.topic] = fmt
    return found


def _decoded_depth(data: bytes, typestore: Any) -> tuple[bytes | None, str]:
    """Decode one ROS 1 CompressedImage of depth into a serialized ROS 2 Image, or say why not."""
    msg = typestore.deserialize_ros1(data, COMPRESSED_IMAGE_TYPE)
    try:
        array = compressed_depth_to_array(msg)
        encoding = parse_format(msg.format)[0]
    except CompressedDepthError as err:
        return None, str(err)
    stamp = Time(sec=int(msg.header.stamp.sec), nanosec=int(msg.header.stamp.nanosec))
    image = array_to_image(array, stamp=stamp, frame_id=str(msg.header.frame_id),
                           encoding=encoding)
    return serialize_message(image), ''


# --------------------------------------------------------------------------------------------
# Command line


def _warn(text: str) -> None:
    print(f'WARNING: {text}', file=sys.stderr)


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='bag_convert.py', description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='Run "bag_convert.py SOURCE -h" for the options of one source.')
    sub = parser.add_subparsers(dest='source', required=True, metavar='SOURCE')

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument('--storage', choices=sorted(STORAGES), default='sqlite3',
                        help='rosbag2 storage (default: %(default)s)')
    common.add_argument('--quiet', action='store_true', help='no progress bar')

    frames = argparse.ArgumentParser(add_help=False)
    frames.add_argument('--depth-topic', default=DEFAULT_DEPTH_TOPIC, help='(%(default)s)')
    frames.add_argument('--info-topic', default=DEFAULT_INFO_TOPIC, help='(%(default)s)')
    frames.add_argument('--color-topic', default=DEFAULT_COLOR_TOPIC, help='(%(default)s)')
    frames.add_argument('--frame-id', default=DEFAULT_FRAME_ID, help='(%(default)s)')
    frames.add_argument('--color-encoding', choices=('bgr8', 'rgb8'), default='bgr8',
                        help='colour encoding (default %(default)s, as the Kinect v2 driver)')
    frames.add_argument('--no-color', action='store_true', help='write depth and camera info only')

    timed = argparse.ArgumentParser(add_help=False)
    timed.add_argument('--intrinsics', type=Path, metavar='FILE',
                       help='YAML with fx, fy, cx, cy[, width, height] (or a ROS camera_info '
                            'YAML); Kinect v2 defaults, with a warning, when absent')
    timed.add_argument('--rate', type=float, default=30.0, help='frame rate [Hz] used to stamp '
                       'frames (default %(default)s)')
    timed.add_argument('--start-time', type=float, default=0.0,
                       help='stamp of frame 0 [s since the epoch] (default %(default)s)')

    p = sub.add_parser('tum', parents=[common, frames], help='TUM RGB-D format '
                       '(TUM, ETH3D SLAM, Bonn, ICL-NUIM)', description=tum_frames.__doc__)
    p.add_argument('sequence', type=Path, help='folder with rgb.txt and depth.txt')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.add_argument('--camera', choices=sorted(TUM_CAMERAS),
                   help='TUM camera intrinsics (fr1, fr2, fr3, or ros = 525/525/319.5/239.5)')
    p.add_argument('--intrinsics', type=Path, metavar='FILE',
                   help='intrinsics YAML or ETH3D calibration.txt (overrides --camera)')
    p.add_argument('--max-difference', type=float, default=0.02,
                   help='largest depth-colour time difference to pair [s] (%(default)s)')

    p = sub.add_parser('diml', parents=[common, frames, timed],
                       help='DIML/CVL indoor sequence folder <scene>/<date>/<n>',
                       description=diml_frames.__doc__)
    p.add_argument('sequence', type=Path, help='folder holding col/ and raw_png/ (up, warp)')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.add_argument('--depth', choices=sorted(DIML_DEPTH_KINDS), default='raw',
                   help='raw (_rd), up (_ud, upsampled) or warp (_wd, in the colour view) '
                        'depth (default %(default)s)')

    p = sub.add_parser('diml-sample', parents=[common, frames, timed],
                       help='DIML sample subset <split>/{HR,LR}/<scene>/{color,depth_filled}',
                       description=diml_sample_frames.__doc__)
    p.add_argument('root', type=Path, help='split, resolution or scene folder')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.add_argument('--resolution', choices=('HR', 'LR'), default='LR',
                   help='which resolution to take when both exist (default %(default)s)')

    p = sub.add_parser('folder', parents=[common, frames, timed],
                       help='a folder of 16-bit depth PNGs [mm] (+ a colour folder)',
                       description=folder_frames.__doc__)
    p.add_argument('depth_dir', type=Path, help='folder of 16-bit depth PNGs in millimetres')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.add_argument('--color-dir', type=Path, help='folder with as many colour images')

    p = sub.add_parser('ros1', parents=[common], help='a ROS 1 bag (e.g. iai_kinect2)',
                       description=convert_ros1.__doc__)
    p.add_argument('bag', type=Path, help='ROS 1 .bag file')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.add_argument('--topics', nargs='+', default=(), metavar='TOPIC',
                   help='convert only these topics (default: all)')
    p.add_argument('--decompress-depth', action='store_true',
                   help='write compressed depth topics (.../compressed, .../compressedDepth) '
                        'as raw sensor_msgs/Image on their raw topic (.../compressed -> ...)')
    return parser


def options_from_args(args: argparse.Namespace) -> BagOptions:
    """Build the writing options from parsed arguments."""
    return BagOptions(storage=args.storage, depth_topic=args.depth_topic,
                      info_topic=args.info_topic, color_topic=args.color_topic,
                      frame_id=args.frame_id, color_encoding=args.color_encoding,
                      with_color=not args.no_color, progress=not args.quiet)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the converter; return the exit code (0 success, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    sources: dict[str, Callable[[], FrameSource]] = {
        'tum': lambda: tum_frames(args.sequence, camera=args.camera,
                                  intrinsics_path=args.intrinsics,
                                  max_difference_s=args.max_difference,
                                  with_color=not args.no_color),
        'diml': lambda: diml_frames(args.sequence, depth_kind=args.depth,
                                    intrinsics_path=args.intrinsics, rate_hz=args.rate,
                                    start_s=args.start_time, with_color=not args.no_color),
        'diml-sample': lambda: diml_sample_frames(args.root, resolution=args.resolution,
                                                  intrinsics_path=args.intrinsics,
                                                  rate_hz=args.rate, start_s=args.start_time,
                                                  with_color=not args.no_color),
        'folder': lambda: folder_frames(args.depth_dir, color_dir=args.color_dir,
                                        intrinsics_path=args.intrinsics, rate_hz=args.rate,
                                        start_s=args.start_time),
    }
    try:
        if args.source == 'ros1':
            summary = convert_ros1(args.bag, args.output, storage=args.storage,
                                   topics=args.topics, progress=not args.quiet,
                                   decompress_depth=args.decompress_depth)
        else:
            source = sources[args.source]()
            summary = write_frames(source, args.output, options_from_args(args))
    except ConvertError as err:
        return tool_support.report_error('bag_convert.py', err)
    print('\n'.join(summary.lines()))
    return 0


if __name__ == '__main__':
    sys.exit(main())
