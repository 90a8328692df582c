"""Recorded RGB-D datasets as frame lists: TUM RGB-D format, DIML/CVL, depth PNG folders.

``cli.bag_writer`` writes a :class:`FrameSource` as a rosbag2 bag (``tools/bag_convert.py``).
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from obstacle_detection.evaluation import EvaluationError
from obstacle_detection.evaluation.camera import read_camera_yaml, scaled_intrinsics
from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE, Intrinsics

#: TUM RGB-D benchmark cameras (fx, fy, cx, cy) for 640x480 images, and the ROS default.
TUM_CAMERAS: dict[str, Intrinsics] = {
    'fr1': Intrinsics(517.3, 516.5, 318.6, 255.3),
    'fr2': Intrinsics(520.9, 521.0, 325.1, 249.7),
    'fr3': Intrinsics(535.4, 539.2, 320.1, 247.6),
    'ros': Intrinsics(525.0, 525.0, 319.5, 239.5),
}
#: Depth units per metre in the TUM-format benchmarks.
TUM_DEPTH_UNITS_PER_M = 5000
#: Depth units per metre of a folder of depth PNGs unless told otherwise (millimetres).
DEFAULT_DEPTH_UNITS_PER_M = 1000.0
#: A TUM file name: a timestamp [s], ``1305031102.160407.png``.
TUM_STAMP_NAME = re.compile(r'^(\d+(?:\.\d+)?)\.png$')
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
    """Frames, their camera (None: Kinect v2 defaults, with a warning), what was not paired."""

    frames: list[Frame]
    intrinsics: Intrinsics | None
    intrinsics_origin: str
    size: tuple[int, int] | None = None
    #: depth units per metre of the images (1000: millimetres, written as they are)
    depth_units_per_m: float = DEFAULT_DEPTH_UNITS_PER_M
    #: where ``depth_units_per_m`` came from: '' = the default, not given (so a frame that
    #: looks like another unit is refused rather than converted wrongly)
    depth_units_origin: str = ''
    default_view: str = 'depth'
    dropped: Counter[str] = dataclasses.field(default_factory=Counter)
    notes: list[str] = dataclasses.field(default_factory=list)


def load_intrinsics(path: Path) -> tuple[Intrinsics, tuple[int, int] | None]:
    """Intrinsics (and size if given) of a camera YAML, ROS camera_info or ETH3D calibration.txt.

    Raises EvaluationError naming the file when it is missing, unreadable or incomplete.
    """
    try:
        numbers = [float(n) for n in path.read_text().split()]
    except ValueError:
        numbers = []
    except OSError as err:
        raise EvaluationError(f'{path}: cannot read intrinsics file ({err.strerror})') from err
    if len(numbers) != 4:
        camera = read_camera_yaml(path)
        return camera.intrinsics, camera.size
    try:
        return Intrinsics(*numbers), None
    except ValueError as err:
        raise EvaluationError(f'{path}: {err}') from err


def default_intrinsics(view: str, size: tuple[int, int]) -> tuple[Intrinsics, str]:
    """Kinect v2 nominal intrinsics for the depth or colour view, scaled to ``size``."""
    if view == 'depth':
        base, base_size, name = KINECT_V2_SD, KINECT_V2_SD_SIZE, 'Kinect v2 depth camera'
    else:
        base, base_size, name = KINECT_V2_COLOR, KINECT_V2_COLOR_SIZE, 'Kinect v2 colour camera'
    if tuple(size) == tuple(base_size):
        return base, f'{name} defaults'
    return (scaled_intrinsics(base, size[0] / base_size[0], size[1] / base_size[1]),
            f'{name} defaults scaled from {base_size[0]}x{base_size[1]} to {size[0]}x{size[1]}')


def stamp_ns(seconds: float) -> int:
    """Seconds to integer nanoseconds (rounded), so that frame spacing stays exact."""
    return int(round(seconds * 1e9))


def _require_dir(path: Path, what: str) -> None:
    if not path.is_dir():
        raise EvaluationError(f'{path}: {what} folder not found')


def _optional_intrinsics(path: Path | Intrinsics | None
                         ) -> tuple[Intrinsics | None, str, tuple[int, int] | None]:
    if path is None:
        return None, '', None
    if isinstance(path, Intrinsics):
        return path, 'given (--intrinsics)', None
    intr, size = load_intrinsics(path)
    return intr, f'from {path}', size


def _check_rate(rate_hz: float) -> None:
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise EvaluationError(f'--rate must be a positive number of frames per second, '
                              f'got {rate_hz}')


def _files_with_suffix(folder: Path, suffix: str) -> dict[str, Path]:
    """Map the name without ``suffix`` to the path, for files in ``folder`` ending in it."""
    return {p.name[:-len(suffix)]: p for p in sorted(folder.iterdir())
            if p.is_file() and p.name.endswith(suffix)}


def _pair_by_key(depth: dict[str, Path], color: dict[str, Path], depth_dir: Path,
                 color_dir: Path) -> None:
    """Raise unless depth and colour folders hold the same frames."""
    if len(depth) != len(color):
        raise EvaluationError(f'{depth_dir} holds {len(depth)} depth images but {color_dir} holds '
                              f'{len(color)} colour images; they must match one to one')
    for key, path in depth.items():
        if key not in color:
            raise EvaluationError(f'{path}: no colour image for this depth image in {color_dir}')


def diml_frames(sequence: Path, *, depth_kind: str = 'raw',
                intrinsics_path: Path | Intrinsics | None = None,
                rate_hz: float = 30.0, start_s: float = 0.0,
                with_color: bool = True) -> FrameSource:
    """List the frames of one DIML/CVL indoor sequence folder (``<scene>/<date>/<n>``).

    Frame ``i`` (the number before the suffix) is stamped ``start_s + i / rate_hz``.
    """
    _check_rate(rate_hz)
    folder, suffix = DIML_DEPTH_KINDS[depth_kind]
    depth_dir = sequence / folder
    if not sequence.is_dir():
        raise EvaluationError(f'{sequence}: DIML sequence folder not found')
    if not depth_dir.is_dir():
        raise EvaluationError(f'{depth_dir}: DIML {depth_kind} depth folder not found '
                              '(pass a <scene>/<date>/<n> folder)')
    depth = _files_with_suffix(depth_dir, suffix)
    if not depth:
        raise EvaluationError(f'{depth_dir}: no *{suffix} depth images')
    pattern = re.compile(r'(\d+)$')
    frames_index: dict[str, int] = {}
    for key, path in depth.items():
        match = pattern.search(key)
        if match is None:
            raise EvaluationError(f'{path}: no frame number before {suffix} in the file name')
        frames_index[key] = int(match.group(1))
    color: dict[str, Path] = {}
    color_dir = sequence / 'col'
    if with_color and color_dir.is_dir():
        color = _files_with_suffix(color_dir, '_c.png')
        _pair_by_key(depth, color, depth_dir, color_dir)
    intr, origin, size = _optional_intrinsics(intrinsics_path)
    start_ns = stamp_ns(start_s)
    frames = [Frame(start_ns + stamp_ns(frames_index[key] / rate_hz), path, color.get(key))
              for key, path in sorted(depth.items(), key=lambda kv: frames_index[kv[0]])]
    notes = [f'DIML has no timestamps: frames stamped from their number at {rate_hz:g} Hz']
    if with_color and not color_dir.is_dir():
        notes.append(f'{color_dir} not found: no colour written')
    return FrameSource(frames, intr, origin, size, depth_units_origin='DIML: millimetres',
                       default_view='depth' if depth_kind == 'raw' else 'color', notes=notes)


#: File endings of depth images a folder may hold (16-bit PNG or PGM) and of colour images.
DEPTH_SUFFIXES = ('.png', '.pgm')
COLOR_SUFFIXES = ('.png', '.jpg', '.jpeg', '.ppm')
#: The word naming a colour image beside a depth image (``color_1.png`` beside ``depth_1.pgm``).
_COLOR_WORD = re.compile(r'colou?r|rgb', re.IGNORECASE)
_DEPTH_WORD = re.compile(r'depth', re.IGNORECASE)


def natural_key(path: Path) -> list[object]:
    """Sort key of a file name with its numbers as numbers (``depth_2`` before ``depth_10``)."""
    return [int(part) if part.isdigit() else part.lower()
            for part in re.split(r'(\d+)', path.name)]


def split_depth_and_color(folder: Path) -> tuple[list[Path], dict[Path, Path]]:
    """Return the depth images of ``folder`` in name order, and the colour named beside each.

    When some file names hold "depth", those are the depth images and the images named the same
    with "color", "colour" or "rgb" in its place are their colour (as the real frames ship:
    ``depth_1.pgm`` and ``color_1.png``); otherwise every PNG or PGM is depth.
    """
    images = sorted((p for p in folder.iterdir() if p.is_file()
                     and p.suffix.lower() in DEPTH_SUFFIXES + COLOR_SUFFIXES), key=natural_key)
    named = [p for p in images if _DEPTH_WORD.search(p.stem)]
    if not named:
        return [p for p in images if p.suffix.lower() in DEPTH_SUFFIXES], {}
    colors = {_COLOR_WORD.sub('#', p.stem, count=1).lower(): p for p in images
              if not _DEPTH_WORD.search(p.stem) and _COLOR_WORD.search(p.stem)}
    depth = [p for p in named if p.suffix.lower() in DEPTH_SUFFIXES]
    pairs = {d: colors[key] for d in depth
             if (key := _DEPTH_WORD.sub('#', d.stem, count=1).lower()) in colors}
    return depth, pairs


def _check_is_depth(path: Path) -> None:
    """Raise when the first image of a depth folder is not 16-bit single-channel depth."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is not None and (image.dtype != np.uint16 or image.ndim != 2):
        kind = (f'a colour image ({image.dtype.itemsize * 8}-bit, {image.shape[2]} channels)'
                if image.ndim == 3 else f'a {image.dtype.itemsize * 8}-bit image')
        raise EvaluationError(f'{path}: {kind}, not 16-bit depth; the folder must hold 16-bit '
                              'depth images (PNG or PGM), alone or named depth_N.png beside '
                              'color_N.png, or give the colour images with --color-dir')


def folder_frames(depth_dir: Path, *, color_dir: Path | None = None,
                  intrinsics_path: Path | Intrinsics | None = None, rate_hz: float = 30.0,
                  start_s: float = 0.0, depth_units_per_m: float | None = None,
                  with_color: bool = True) -> FrameSource:
    """List a folder of 16-bit depth images, PNG or PGM, in name order, stamped by rate.

    Colour comes from ``color_dir`` (as many images, in name order) or from the same folder:
    ``color_N.png`` (or ``colour``, ``rgb``) beside ``depth_N.pgm``. depth_units_per_m: of the
    images (``--depth-scale``; 5000 for TUM frames); None: 1000 (millimetres), the default, and a
    first frame that looks like another unit is refused.
    """
    _check_rate(rate_hz)
    if depth_units_per_m is not None and not (math.isfinite(depth_units_per_m)
                                              and depth_units_per_m > 0):
        raise EvaluationError(f'--depth-scale must be a positive number of depth units per metre, '
                              f'got {depth_units_per_m:g}')
    _require_dir(depth_dir, 'depth')
    depth, beside = split_depth_and_color(depth_dir)
    if not depth:
        raise EvaluationError(f'{depth_dir}: no depth images (16-bit .png or .pgm)')
    _check_is_depth(depth[0])
    notes: list[str] = []
    color: list[Path | None] = [None] * len(depth)
    if color_dir is not None and with_color:
        _require_dir(color_dir, 'colour')
        found = sorted((p for p in color_dir.iterdir()
                        if p.is_file() and p.suffix.lower() in COLOR_SUFFIXES), key=natural_key)
        if len(found) != len(depth):
            raise EvaluationError(f'{depth_dir} holds {len(depth)} depth images but {color_dir} '
                                  f'holds {len(found)} colour images; they must match one to one')
        color = list(found)
    elif beside and with_color:
        color = [beside.get(d) for d in depth]
        notes.append(f'colour paired by name in {depth_dir} ({len(beside)} of {len(depth)} depth '
                     'images have one)')
    intr, origin, size = _optional_intrinsics(intrinsics_path)
    frames = [Frame(stamp_ns(start_s) + stamp_ns(k / rate_hz), d, c)
              for k, (d, c) in enumerate(zip(depth, color))]
    if depth_units_per_m is None:
        return FrameSource(frames, intr, origin, size, notes=notes)
    return FrameSource(frames, intr, origin, size, depth_units_per_m=depth_units_per_m,
                       depth_units_origin='--depth-scale', notes=notes)


def read_timestamp_list(path: Path) -> list[tuple[float, str]]:
    """Read a TUM ``rgb.txt`` / ``depth.txt``: ``timestamp filename`` lines, ``#`` comments."""
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise EvaluationError(f'{path}: cannot read ({err.strerror})') from err
    entries = []
    for number, line in enumerate(lines, start=1):
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        parts = line.replace(',', ' ').split()
        try:
            entries.append((float(parts[0]), parts[1]))
        except (IndexError, ValueError):
            raise EvaluationError(f'{path}:{number}: expected "timestamp filename", '
                                  f'got {line!r}') from None
    return sorted(entries)


def tum_frames(root: Path, *, camera: str | None = None,
               intrinsics_path: Path | Intrinsics | None = None,
               max_difference_s: float = 0.02, with_color: bool = True) -> FrameSource:
    """List the depth frames of a TUM-format sequence, each with its nearest colour frame."""
    if not root.is_dir():
        raise EvaluationError(f'{root}: sequence folder not found')
    notes: list[str] = []
    depth_list = root / 'depth.txt'
    if depth_list.is_file():
        depth = read_timestamp_list(depth_list)
    else:
        depth = stamps_from_names(root, 'depth')
        notes.append(f'{depth_list} not found: depth frames listed from the timestamps in the '
                     f'file names of {root / "depth"}')
    if not depth:
        raise EvaluationError(f'{depth_list}: lists no depth images')
    dropped: Counter[str] = Counter()
    color_for: list[Path | None] = [None] * len(depth)
    rgb_list = root / 'rgb.txt'
    named_rgb = stamps_from_names(root, 'rgb') if with_color and not rgb_list.is_file() and \
        (root / 'rgb').is_dir() else []
    if with_color and (rgb_list.is_file() or named_rgb):
        rgb = read_timestamp_list(rgb_list) if rgb_list.is_file() else named_rgb
        if named_rgb:
            notes.append(f'{rgb_list} not found: colour frames listed from the timestamps in '
                         f'the file names of {root / "rgb"}')
        rgb_t, depth_t = np.array([t for t, _ in rgb]), np.array([t for t, _ in depth])
        if rgb_t.size == 0:
            dropped['rgb.txt lists no colour images'] = len(depth)
            rgb_t = np.full(1, np.inf)
        j = np.searchsorted(rgb_t, depth_t)
        lo, hi = np.clip(j - 1, 0, rgb_t.size - 1), np.clip(j, 0, rgb_t.size - 1)
        best = np.where(np.abs(rgb_t[hi] - depth_t) < np.abs(rgb_t[lo] - depth_t), hi, lo)
        paired = np.abs(rgb_t[best] - depth_t) <= max_difference_s
        for k in np.flatnonzero(paired):
            color_for[k] = root / rgb[best[k]][1]
        if rgb and not paired.all():
            dropped[f'no colour frame within {max_difference_s:g} s of the depth frame '
                    '(kept without colour)'] = int(np.count_nonzero(~paired))
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
            print(f'warning: no intrinsics for {root}: using the ROS default camera fx=fy=525 '
                  'cx=319.5 cy=239.5; pass --camera fr1|fr2|fr3 or --intrinsics FILE',
                  file=sys.stderr)
    return FrameSource(frames, intr, origin, size, depth_units_per_m=TUM_DEPTH_UNITS_PER_M,
                       depth_units_origin='the TUM format', dropped=dropped, notes=notes)


def stamps_from_names(root: Path, kind: str) -> list[tuple[float, str]]:
    """``(timestamp, file)`` of the PNGs in ``root/kind`` named ``<seconds>.png`` (TUM).

    Stands in for a missing ``depth.txt`` / ``rgb.txt``; EvaluationError says what to write.
    """
    folder = root / kind
    listed = root / f'{kind}.txt'
    found = sorted(p.name for p in folder.iterdir() if p.suffix.lower() == '.png') \
        if folder.is_dir() else []
    stamped = [(float(m.group(1)), f'{kind}/{name}') for name in found
               if (m := TUM_STAMP_NAME.match(name))]
    if found and len(stamped) == len(found):
        return sorted(stamped)
    raise EvaluationError(f'{listed}: not found, and no {folder}/<seconds>.png names give the '
                          f'stamps: write it, one "timestamp filename" line per {kind} image'
                          f'{" (rgb.txt likewise)" if kind == "depth" else ""}, or leave '
                          f'colour out with --no-color{_loose_frames_hint(root, kind)}')


def _loose_frames_hint(root: Path, kind: str) -> str:
    """Return a pointer to ``bag_convert folder`` when ``root`` holds unstamped depth images."""
    if kind != 'depth' or not split_depth_and_color(root)[0]:
        return ''
    return (f'; depth images without stamps (as depth_N.png beside color_N.png) convert with '
            f'bag_convert folder {root} OUTPUT --depth-scale 5000')


def read_depth_png(path: str | Path, *,
                   units_per_m: float = DEFAULT_DEPTH_UNITS_PER_M) -> np.ndarray:
    """Read a 16-bit single-channel depth PNG or PGM as (H, W) uint16 millimetres.

    ``units_per_m`` converts other units (5000 for TUM); EvaluationError when a value overflows.
    """
    path = Path(path)
    if not path.is_file():
        raise EvaluationError(f'{path}: depth image not found')
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise EvaluationError(f'{path}: cannot read depth image (not an image file?)')
    if image.dtype != np.uint16 or image.ndim != 2:
        raise EvaluationError(f'{path}: a depth image must be 16-bit single channel in '
                              f'millimetres, got {image.dtype} with shape {image.shape}')
    if units_per_m != DEFAULT_DEPTH_UNITS_PER_M:
        # multiplied before divided: exact for integer ratios (5000 units/m: v / 5)
        mm = np.floor(image.astype(np.float64) * 1000.0 / units_per_m + 0.5)
        if mm.max(initial=0.0) > np.iinfo(np.uint16).max:
            raise EvaluationError(f'{path}: at {units_per_m:g} depth units per metre its farthest '
                                  f'value is {mm.max() / 1000:.1f} m, beyond the 65.5 m a 16UC1 '
                                  'image in millimetres holds; check --depth-scale')
        image = mm.astype(np.uint16)
    return image


def read_color(path: Path, encoding: str) -> np.ndarray:
    """Read a colour image as (H, W, 3) uint8 in ``encoding`` ('bgr8' or 'rgb8')."""
    if not path.is_file():
        raise EvaluationError(f'{path}: colour image not found')
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise EvaluationError(f'{path}: cannot read colour image')
    if encoding == 'rgb8':
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return image

