"""Draw what the detector saw, without ROS: depth with obstacles marked + costmap, as PNG."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline import mount
from obstacle_detection.viz import pictures
from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.support import parse_intrinsics
from obstacle_detection.evaluation import EvaluationError
from obstacle_detection.evaluation.camera import read_camera_yaml
from obstacle_detection.evaluation.datasets import read_depth_png
from obstacle_detection.pipeline.depth import decode_depth
from obstacle_detection.pipeline.params import (SEED_TABLE_4_1, DetectorParams,
                                       Intrinsics)
from obstacle_detection.cli.evaluation_args import add_parameter_arguments, base_params


@dataclass
class _Job:
    name: str
    depth: np.ndarray
    intrinsics: Intrinsics | None
    params: DetectorParams
    depth_scale: float | None = None
    truth_labels: np.ndarray | None = None
    sequence: bool = False
    extra_lines: tuple[str, ...] = ()


@dataclass
class _Camera:
    """What ``--intrinsics`` gives: intrinsics, a depth scale and a mount when a YAML has them."""

    intrinsics: Intrinsics | None = None
    origin: str = ''
    depth_scale: float | None = None
    mount: tuple[float, float, float] | None = None  # height [m], pitch, roll [rad]


def parse_frames(text: str) -> range:
    """``a:b[:c]`` (stop excluded) or a single index -> range (argparse type)."""
    try:
        parts = [int(p) for p in text.split(':')]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected start:stop[:step], got {text!r}') from None
    if len(parts) == 1:
        return range(parts[0], parts[0] + 1)
    if len(parts) in (2, 3) and (len(parts) == 2 or parts[2] > 0):
        return range(*parts)
    raise argparse.ArgumentTypeError(f'expected start:stop[:step], got {text!r}')


def parse_camera(text: str) -> Intrinsics | Path:
    """``fx,fy,cx,cy`` [px] -> Intrinsics, else the Path of a camera YAML (argparse type)."""
    if ',' in text and not Path(text).exists():
        return parse_intrinsics(text)
    return Path(text)


def read_camera(path: Path) -> _Camera:
    """Intrinsics, and the depth scale and mount when given, of a camera YAML."""
    try:
        camera = read_camera_yaml(path)
    except OSError as exc:
        raise tool_support.ToolError(path, f'cannot read the camera YAML ({exc.strerror})') \
            from None
    except EvaluationError as exc:
        raise tool_support.ToolError(path, f'bad camera YAML: {exc.problem}') from None
    return _Camera(camera.intrinsics, f'from {path}', camera.depth_scale, camera.mount)


def camera_of(args: argparse.Namespace) -> _Camera:
    """Return the ``--intrinsics`` option as a _Camera (empty when not given)."""
    if isinstance(args.intrinsics, Intrinsics):
        return _Camera(args.intrinsics, 'from --intrinsics')
    if args.intrinsics is not None:
        return read_camera(args.intrinsics)
    return _Camera()


def mount_caption(estimate: mount.MountEstimate) -> str:
    """One caption line giving a mount estimated from the floor."""
    return (f'mount estimated from the floor: h {estimate.height_m:.2f} m, pitch '
            f'{estimate.pitch_deg:.1f} deg, roll {estimate.roll_deg:.1f} deg '
            f'({estimate.inlier_fraction:.0%} on the plane)')


#: The mount options: (argparse dest, DetectorParams field, conversion to the field's unit).
_MOUNT_OPTIONS = (('height', 'camera_height_m', float),
                  ('pitch_deg', 'camera_pitch_rad', math.radians),
                  ('roll_deg', 'camera_roll_rad', math.radians))
#: How to fix a mount that does not match the floor, for folders and bags.
_FIX_MOUNT = ('--estimate-mount (the first frame\'s floor), or --height, --pitch-deg and '
              '--roll-deg')


def _mount(args: argparse.Namespace, params: DetectorParams) -> DetectorParams:
    changes = {field: convert(getattr(args, dest)) for dest, field, convert in _MOUNT_OPTIONS
               if getattr(args, dest) is not None}
    return params.replace(**changes) if changes else params


def _given_mount_options(args: argparse.Namespace) -> list[str]:
    return [f'--{dest.replace("_", "-")}' for dest, _, _ in _MOUNT_OPTIONS
            if getattr(args, dest) is not None]


class _RealFrames:
    """Turns real depth frames into jobs, saying which intrinsics, scale and mount are used."""

    def __init__(self, args: argparse.Namespace, base: DetectorParams, camera: _Camera,
                 fix_mount: str) -> None:
        self.args = args
        self.camera = camera
        self.fix_mount = fix_mount
        self.params = base
        self.mount_origin = f'the {args.preset} preset\'s default: no mount given'
        if camera.mount is not None:
            height, pitch, roll = camera.mount
            self.params = base.replace(camera_height_m=height, camera_pitch_rad=pitch,
                                       camera_roll_rad=roll)
            self.mount_origin = camera.origin
        given = _given_mount_options(args)
        if given:
            self.params = _mount(args, self.params)
            self.mount_origin = ', '.join(given) + (
                f' over {camera.origin}' if camera.mount is not None else '')
        self.first = True
        self.estimate_line: str | None = None

    @staticmethod
    def _far_depth_hint(exc: ValueError, depth: np.ndarray, scale: float) -> str | None:
        """Return a unit hint when no floor was found because too little depth is within 4 m."""
        if depth.dtype.kind not in 'ui' or not str(exc).startswith('too few points'):
            return None
        return tool_support.depth_unit_warning(depth, scale, out_of_range_m=4.0)

    def job(self, name: str, depth: np.ndarray, intrinsics: Intrinsics | None,
            intrinsics_origin: str, depth_scale: float | None = None,
            scale_origin: str = '', truth_labels: np.ndarray | None = None,
            sequence: bool = False) -> _Job:
        """Return the job of one frame; warnings go to stderr (first frame) and the caption."""
        lines: list[str] = []
        warnings: list[str] = []
        if intrinsics is None:
            intrinsics = SEED_TABLE_4_1
            text = tool_support.intrinsics_text(intrinsics)
            warnings.append(f'no intrinsics ({intrinsics_origin or "none given"}): using the '
                            f"seed's Table 4.1 fallback ({text}); give --intrinsics "
                            'FX,FY,CX,CY or a camera YAML')
            intrinsics_origin = "the seed's Table 4.1 fallback"
        lines.append(f'intrinsics: {tool_support.intrinsics_text(intrinsics)} '
                     f'({intrinsics_origin})')
        if (text := tool_support.intrinsics_warning(intrinsics, depth.shape)) is not None:
            warnings.append(text)
        unit = ''
        unit_warning = None
        scale = 1000.0 if depth_scale is None else depth_scale
        if depth.dtype.kind in 'ui':
            unit = (f'; depth {scale:g} units/m ('
                    f'{scale_origin or "millimetres, the default: no --depth-scale"})')
            unit_warning = tool_support.depth_unit_warning(depth, scale)
            if unit_warning is not None:
                warnings.append(unit_warning)
        params = self.params
        if self.first:
            depth_m = decode_depth(depth, depth_scale=depth_scale)
            if self.args.estimate_mount:
                try:
                    estimate = mount.estimate_mount(depth_m, intrinsics)
                except ValueError as exc:
                    hint = unit_warning or self._far_depth_hint(exc, depth, scale)
                    raise ValueError(f'{name}: cannot estimate the mount: {exc}'
                                     + (f'; {hint}' if hint else '')) from None
                estimated = self.params.replace(camera_height_m=estimate.height_m,
                                                camera_pitch_rad=estimate.pitch_rad,
                                                camera_roll_rad=estimate.roll_rad)
                self.params = _mount(self.args, estimated)
                self.estimate_line = mount_caption(estimate)
                given = _given_mount_options(self.args)
                if given:
                    self.estimate_line += f'; {", ".join(given)} given instead'
                self.mount_origin = 'estimated from the floor' + (
                    ' of the first frame' if sequence else '') + (
                    f', {", ".join(given)} given instead' if given else '')
                params = self.params
            else:
                check = tool_support.check_mount(depth_m, intrinsics, params,
                                                 fix=self.fix_mount)
                if check.warning:
                    warnings.append(check.warning)
                elif check.estimate is None:
                    lines.append(f'mount not checked against the floor: {check.reason}')
                    hint = None if unit_warning else self._far_depth_hint(
                        ValueError(check.reason), depth, scale)
                    if hint:
                        warnings.append(hint)
        if self.estimate_line is not None:
            lines.insert(0, self.estimate_line + unit)
        else:
            lines.insert(1, f'mount: {tool_support.mount_text(params)} ({self.mount_origin})'
                         + unit)
        self.first = False
        lines.extend(f'warning: {text}' for text in warnings)
        return _Job(name, depth, intrinsics, params, depth_scale, truth_labels, sequence,
                    tuple(lines))


def jobs(args: argparse.Namespace, base: DetectorParams) -> Iterator[_Job]:
    """Return the frames to draw, from whichever source the options name."""
    if args.scene is not None:
        mount_values = {k: v for k, v in (('height_m', args.height),
                                          ('pitch_deg', args.pitch_deg),
                                          ('roll_deg', args.roll_deg)) if v is not None}
        scenario = evaluation.Scenario(
            name=args.scene, scene=args.scene, seeds=(args.seed,),
            frames=tuple(args.frames) if args.frames is not None else None,
            mount=tuple(sorted(mount_values.items())),
            truth=args.truth or ('robot' if getattr(base, 'robot_level', False) else 'seed'))
        for frame in evaluation.scenario_frames(scenario, max_frames=args.max_frames):
            yield _Job(f'{frame.scenario} {frame.frame_id}', frame.depth, frame.intrinsics,
                       frame.params(base), truth_labels=frame.truth_labels,
                       sequence=scenario.is_sequence)
    elif args.folder is not None:
        yield from folder_jobs(args, base)
    elif args.depth is not None:
        yield depth_job(args, base)
    else:
        real = _RealFrames(args, base, camera_of(args), fix_mount=_FIX_MOUNT)
        if real.camera.intrinsics is not None:
            raise tool_support.ToolError('--intrinsics does not apply to --bag: its '
                                         'CameraInfo gives them (see --info-topic)', usage=True)
        for frame in bag_frames(args.bag, args.depth_topic, args.info_topic,
                                every=args.every, max_frames=args.max_frames,
                                find_info_topic=True):
            yield real.job(frame.name, frame.depth, frame.intrinsics, frame.intrinsics_origin,
                           sequence=True)


def _is_labelled(folder: Path) -> bool:
    return (folder / 'intrinsics.yaml').is_file() and (folder / 'labels').is_dir() and \
        (folder / 'depth').is_dir()


def folder_jobs(args: argparse.Namespace, base: DetectorParams) -> Iterator[_Job]:
    """Frames of ``--folder``: a labelled folder, or a plain folder of 16-bit depth images."""
    folder: Path = args.folder
    if not folder.is_dir():
        raise tool_support.ToolError(folder, 'no such folder; expected a folder of 16-bit '
                                             'depth PNGs (or a labelled folder)')
    if _is_labelled(folder) and args.intrinsics is None and args.depth_scale is None:
        for frame in evaluation.load_labelled_folder(folder, max_frames=args.max_frames):
            yield _Job(f'{frame.scenario} {frame.frame_id}', frame.depth, frame.intrinsics,
                       frame.params(base), frame.depth_scale, frame.truth_labels, True)
        return
    camera = camera_of(args)
    if camera.intrinsics is None and (folder / 'intrinsics.yaml').is_file():
        camera = read_camera(folder / 'intrinsics.yaml')
    if camera.intrinsics is None:
        raise tool_support.ToolError(folder, 'no intrinsics: the folder has no '
                                             'intrinsics.yaml; give --intrinsics FX,FY,CX,CY '
                                             'or a camera YAML')
    images = folder / 'depth' if (folder / 'depth').is_dir() else folder
    files = sorted(p for p in images.iterdir() if p.suffix.lower() in ('.png', '.pgm'))
    depths = []
    skipped = []
    for path in files:
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if depth is None or depth.dtype != np.uint16 or depth.ndim != 2:
            skipped.append(path.name)
        else:
            depths.append((path, depth))
    if not depths:
        raise tool_support.ToolError(images, f'no 16-bit single-channel depth PNG or PGM '
                                             f'({len(files)} image file(s), none 16-bit)')
    if skipped:
        print(f'  {images}: skipped {len(skipped)} image(s) that are not 16-bit depth: '
              f'{", ".join(skipped[:3])}{", ..." if len(skipped) > 3 else ""}', file=sys.stderr)
    if not args.no_truth:
        print(f'  {folder}: no ground truth (labels/ with intrinsics.yaml and no '
              '--intrinsics): drawn without the truth panel', file=sys.stderr)
    scale, scale_origin = args.depth_scale, '--depth-scale'
    if scale is None and camera.depth_scale is not None:
        scale, scale_origin = camera.depth_scale, camera.origin
    real = _RealFrames(args, base, camera, fix_mount=_FIX_MOUNT)
    for path, depth in evaluation.subsample(depths, args.max_frames):
        yield real.job(path.name, depth, camera.intrinsics, camera.origin, scale,
                       scale_origin if scale is not None else '', sequence=True)


def depth_job(args: argparse.Namespace, base: DetectorParams) -> _Job:
    """Return the frame of ``--depth``: intrinsics, depth scale and mount from the options."""
    depth = read_depth_png(args.depth)
    camera = camera_of(args)
    if args.estimate_mount and camera.intrinsics is None:
        raise tool_support.ToolError('--estimate-mount needs the intrinsics of the depth '
                                     'image: give --intrinsics YAML or --intrinsics '
                                     'FX,FY,CX,CY', usage=True)
    scale, scale_origin = args.depth_scale, '--depth-scale'
    if scale is None and camera.depth_scale is not None:
        scale, scale_origin = camera.depth_scale, camera.origin
    intr = camera.intrinsics or SEED_TABLE_4_1
    command = (f'--estimate-mount, or python tools/estimate_mount.py --depth {args.depth} '
               f'--depth-scale {1000.0 if scale is None else scale:g} --intrinsics '
               f'{intr.fx:g},{intr.fy:g},{intr.cx:g},{intr.cy:g} --camera-yaml-out camera.yaml')
    real = _RealFrames(args, base, camera, fix_mount=command)
    return real.job(args.depth.name, depth, camera.intrinsics, camera.origin, scale,
                    scale_origin if scale is not None else '')


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog='pictures', description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawTextHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--scene', help='a scene of the generator (scenes.SCENE_NAMES)')
    parser.add_argument('--truth', choices=('robot', 'seed'),
                        help="a scene's ground truth: 'robot' (box tops, drops obstacles; "
                             "the default for robot-level parameters) or 'seed' (slope only; "
                             'the default for the seed presets)')
    source.add_argument('--depth', type=Path, metavar='PNG',
                        help='a 16-bit depth PNG or PGM (see --depth-scale)')
    source.add_argument('--folder', type=Path, metavar='DIR',
                        help='a folder of 16-bit depth PNGs/PGMs (with --intrinsics), or a '
                             'labelled folder\n(depth/, labels/, intrinsics.yaml: drawn with '
                             'its truth)')
    source.add_argument('--bag', type=Path, metavar='PATH',
                        help='a rosbag2 folder or a ROS 1 .bag file')
    parser.add_argument('--seed', type=int, default=0, help='scene seed [default: 0]')
    parser.add_argument('--frames', type=parse_frames, metavar='A:B[:C]',
                        help='scene frame indices (a sequence such as person_walking)')
    parser.add_argument('--intrinsics', type=parse_camera, metavar='YAML|FX,FY,CX,CY',
                        help='intrinsics of --depth / --folder [px], or a camera YAML (fx, fy, '
                             'cx, cy,\noptional depth_scale and camera_height_m, '
                             "camera_pitch_deg, camera_roll_deg);\nwithout it the seed's "
                             'Table 4.1 fallback is used, with a warning')
    parser.add_argument('--depth-scale', type=float, metavar='UNITS',
                        help='depth units per metre of --depth / --folder [default: the '
                             "YAML's, else 1000 (mm);\nTUM RGB-D: 5000]")
    parser.add_argument('--estimate-mount', action='store_true',
                        help='camera mount from the floor in view (of the first frame of a '
                             'folder or bag);\n--height etc. still override it')
    parser.add_argument('--depth-topic', default=tool_support.DEFAULT_DEPTH_TOPIC,
                        help=f'bag depth topic [default: {tool_support.DEFAULT_DEPTH_TOPIC}]')
    parser.add_argument('--info-topic',
                        help=f'bag CameraInfo topic [default: {tool_support.DEFAULT_INFO_TOPIC}'
                             ", else the bag's\nCameraInfo topic found by type]")
    parser.add_argument('--every', type=int, default=1, help='bag: one frame in N')
    parser.add_argument('--max-frames', type=int, metavar='N', help='at most N frames')
    parser.add_argument('--height', type=float, metavar='M', help='camera height [m]')
    parser.add_argument('--pitch-deg', type=float, help='camera pitch, + looks down [deg]')
    parser.add_argument('--roll-deg', type=float, help='camera roll [deg]')
    add_parameter_arguments(parser)
    parser.add_argument('--refiner', type=Path, metavar='MODEL',
                        help='draw the seed-4.5 refined result of this model instead')
    parser.add_argument('--caption', metavar='TEXT',
                        help='first caption line instead of the frame name')
    parser.add_argument('--no-truth', action='store_true',
                        help='leave out the comparison with the ground truth')
    parser.add_argument('--out', type=Path, required=True,
                        help='PNG: the picture (one frame) or the contact sheet')
    parser.add_argument('--frames-dir', type=Path, metavar='DIR',
                        help='also write every frame picture here (several frames)')
    parser.add_argument('--columns', type=int, default=4, help='contact sheet columns')
    parser.add_argument('--thumb-width', type=int, default=480,
                        help='contact sheet thumbnail width [px]')
    return parser


@dataclass
class _Detected:
    """One frame run through the pipeline, ready to draw."""

    job: _Job
    caption: str
    result: object
    labels: np.ndarray | None
    costmap: object
    truth: np.ndarray | None


def detect(args: argparse.Namespace) -> list[_Detected]:
    """Run the pipeline (and the refiner) over every frame the parsed options name, in order."""
    from obstacle_detection.pipeline import refine
    from obstacle_detection.pipeline.detector import Detector

    if args.scene is not None and (args.estimate_mount or args.depth_scale is not None
                                   or args.intrinsics is not None):
        raise tool_support.ToolError('--estimate-mount, --depth-scale and --intrinsics do not '
                                     'apply to --scene (the generator knows its camera)',
                                     usage=True)
    if args.bag is not None and args.depth_scale is not None:
        raise tool_support.ToolError('--depth-scale does not apply to --bag (16UC1 images '
                                     'are millimetres, 32FC1 metres)', usage=True)
    base = base_params(args)
    refiner = refine.LogisticRefiner.load(args.refiner) if args.refiner else None
    detected: list[_Detected] = []
    said: set[str] = set()
    previous: np.ndarray | None = None
    for job in jobs(args, base):
        result = Detector(job.params).process(job.depth, job.intrinsics,
                                              depth_scale=job.depth_scale)
        labels = costmap = None
        caption = job.name if args.caption is None else args.caption
        if refiner is not None:
            prev = previous if job.sequence and previous is not None and \
                previous.shape == result.labels.shape else None
            refined = refine.refine_result(result, refiner.predict_labels(result, prev),
                                           job.params)
            labels, costmap = refined.labels, refined.costmap
            caption += f' (refined by {args.refiner.name})'
        previous = refine.obstacle_mask(result)
        truth = None if args.no_truth else job.truth_labels
        detected.append(_Detected(job, caption, result, labels, costmap, truth))
        print(f'{caption}: {int(result.obstacle_points.shape[0])} obstacle voxels, '
              f'{result.timings_ms["total"]:.0f} ms', file=sys.stderr)
        for line in job.extra_lines:  # what was used: said once, again when it changes
            if line not in said:
                print(line if line.startswith('warning: ') else f'  {line}', file=sys.stderr)
                said.add(line)
    if not detected:
        raise ValueError('no frames to draw')
    return detected


def draw(frame: _Detected, *, with_legend: bool = True,
         max_depth_m: float | None = None, image_scale: float = 1.0) -> np.ndarray:
    """Return the picture of one detected frame (``pictures.side_by_side``), without title."""
    return pictures.side_by_side(frame.result, caption=frame.caption,
                                 truth_labels=frame.truth, labels=frame.labels,
                                 costmap=frame.costmap, extra_lines=frame.job.extra_lines,
                                 params=frame.job.params, with_legend=with_legend,
                                 max_depth_m=max_depth_m, image_scale=image_scale)


def rule_text(params: DetectorParams) -> str:
    """Name the obstacle rule of ``params`` for a title: robot level or the seed's slope test."""
    return 'robot level' if params.robot_level else "the seed's slope test"


def title(frame: _Detected) -> str:
    """Return the title of one frame's picture."""
    truth = ', against the ground truth' if frame.truth is not None else ''
    return (f'{frame.caption}: obstacles in the depth image and the costmap '
            f'({rule_text(frame.job.params)}{truth})')


def titled_frame(frame: _Detected, *, width: int | None = None) -> np.ndarray:
    """Return the titled picture of one frame; ``width``: drawn to fit it [px]."""
    if width is None:
        return pictures.titled(draw(frame), title(frame))
    return pictures.titled(pictures.fit_width(lambda scale: draw(frame, image_scale=scale),
                                              width), title(frame))


def _write_frames_dir(args: argparse.Namespace, detected: Sequence[_Detected]) -> None:
    if args.frames_dir is None:
        return
    for i, frame in enumerate(detected):
        safe = frame.job.name.replace(' ', '_').replace('/', '_').replace('#', '')
        pictures.write_png(args.frames_dir / f'{i:04d}_{safe}.png', titled_frame(frame))


def sheet(args: argparse.Namespace, detected: Sequence[_Detected]) -> np.ndarray:
    """Return the contact sheet of several frames, with one full-size legend underneath."""
    depths = [np.asarray(frame.result.depth_m) for frame in detected]
    farthest = max(float(d[np.isfinite(d) & (d > 0)].max(initial=0.0)) for d in depths) or 1.0
    images = [pictures.fit_width(
        lambda scale, frame=frame: draw(frame, with_legend=False, max_depth_m=farthest,
                                        image_scale=scale), args.thumb_width)
        for frame in detected]
    grid = pictures.contact_sheet(images, columns=args.columns, thumb_width=args.thumb_width)
    truth = any(f.truth is not None for f in detected)
    parts = 3 if truth else 2
    widths = [(grid.shape[1] - (parts - 1) * 6) // parts] * parts
    params = detected[0].job.params
    legend = pictures.legend_row(widths, farthest, truth=truth, params=params,
                                 above_robot=pictures.above_robot_pixels(
                                     detected[0].result, params) is not None)
    return pictures.titled(grid, f'{len(detected)} frames: obstacles in the depth image and '
                                 f'the costmap ({rule_text(params)})', below=legend)


def write_pictures(args: argparse.Namespace) -> str:
    """Draw the frames ``args`` select and write the PNG(s); return the line to print."""
    detected = detect(args)
    _write_frames_dir(args, detected)
    if len(detected) == 1:
        pictures.write_png(args.out, titled_frame(detected[0]))
    else:
        pictures.write_png(args.out, sheet(args, detected))
    return f'wrote {args.out} ({len(detected)} frame{"s" if len(detected) > 1 else ""})'


# --------------------------------------------------------------------------------------------
# Frames from bags


@dataclass
class DepthFrame:
    """A depth frame to draw: depth (H, W) uint16/float, its intrinsics, a name."""

    name: str
    depth: np.ndarray
    intrinsics: Intrinsics | None
    #: where the intrinsics came from (e.g. ``CameraInfo on /x (found by type)``), '' = none
    intrinsics_origin: str = ''


def bag_frames(path: str | Path, depth_topic: str, info_topic: str | None = None, *,
               every: int = 1, max_frames: int | None = None,
               find_info_topic: bool = False) -> Iterator[DepthFrame]:
    """Depth frames of a ROS 2 (or ROS 1) bag, in time order, with the latest camera info."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    from obstacle_detection.cli.support import IMAGE_TYPE, check_bag_path, choose_info_topic
    from obstacle_detection.ros.conversions import camera_info_to_intrinsics, image_to_array

    if every < 1:
        raise ValueError(f'every={every} must be >= 1')
    check_bag_path(path)
    try:
        reader = AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except AnyReaderError as exc:
        raise ValueError(f'{path}: cannot read the bag ({exc})') from None
    with contextlib.closing(reader):
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
