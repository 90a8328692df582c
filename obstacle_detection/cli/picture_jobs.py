"""Draw what the detector saw, without ROS: depth with obstacles marked + costmap, as PNG."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.evaluation_args import add_parameter_arguments, base_params
from obstacle_detection.cli.support import ToolError, parse_intrinsics
from obstacle_detection.evaluation import EvaluationError
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.evaluation.camera import read_camera_yaml
from obstacle_detection.evaluation.datasets import read_depth_png
from obstacle_detection.pipeline import mount
from obstacle_detection.pipeline.depth import decode_depth
from obstacle_detection.pipeline.params import SEED_TABLE_4_1, DetectorParams, Intrinsics
from obstacle_detection.viz import pictures


@dataclass
class _Job:
    name: str
    depth: np.ndarray
    intrinsics: Intrinsics | None
    params: DetectorParams
    depth_scale: float | None = None
    truth_labels: np.ndarray | None = None
    extra_lines: tuple[str, ...] = ()


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


def _camera(args: argparse.Namespace) -> tuple[Intrinsics | None, str, float | None, tuple | None]:
    """``--intrinsics``: (intrinsics, origin, depth scale, mount (height, pitch, roll) or None)."""
    if not isinstance(args.intrinsics, Path):
        return args.intrinsics, 'from --intrinsics' if args.intrinsics else '', None, None
    try:
        camera = read_camera_yaml(args.intrinsics)
    except OSError as exc:
        raise ToolError(args.intrinsics, f'cannot read the camera YAML ({exc.strerror})') \
            from None
    except EvaluationError as exc:
        raise ToolError(args.intrinsics, f'bad camera YAML: {exc.problem}') from None
    return camera.intrinsics, f'from {args.intrinsics}', camera.depth_scale, camera.mount


#: The mount options: (argparse dest, DetectorParams field, conversion to the field's unit).
_MOUNT_OPTIONS = (('height', 'camera_height_m', float),
                  ('pitch_deg', 'camera_pitch_rad', math.radians),
                  ('roll_deg', 'camera_roll_rad', math.radians))


def _given_mount(args: argparse.Namespace, params: DetectorParams
                 ) -> tuple[DetectorParams, list[str]]:
    """Return ``params`` with the mount options given, and those options' names."""
    given = [option for option in _MOUNT_OPTIONS if getattr(args, option[0]) is not None]
    params = params.replace(**{field: convert(getattr(args, dest))
                               for dest, field, convert in given})
    return params, [f'--{dest.replace("_", "-")}' for dest, _, _ in given]


class _RealFrames:
    """Turns real depth frames into jobs, saying which intrinsics, scale and mount are used."""

    def __init__(self, args: argparse.Namespace, base: DetectorParams,
                 camera_mount: tuple | None, camera_origin: str, fix_mount: str) -> None:
        self.args = args
        self.fix_mount = fix_mount
        origin = f'the {args.preset} preset\'s default: no mount given'
        if camera_mount is not None:
            height, pitch, roll = camera_mount
            base = base.replace(camera_height_m=height, camera_pitch_rad=pitch,
                                camera_roll_rad=roll)
            origin = camera_origin
        self.params, self.given = _given_mount(args, base)
        if self.given:
            origin = ', '.join(self.given) + (f' over {origin}' if camera_mount else '')
        self.mount_line = f'mount: {tool_support.mount_text(self.params)} ({origin})'
        self.first = True

    def job(self, name: str, depth: np.ndarray, intrinsics: Intrinsics | None,
            intrinsics_origin: str, depth_scale: float | None = None,
            scale_origin: str = '') -> _Job:
        """Return the job of one frame; its lines say what is used and warn."""
        warnings: list[str | None] = []
        if intrinsics is None:
            intrinsics = SEED_TABLE_4_1
            text = tool_support.intrinsics_text(intrinsics)
            warnings.append(f'no intrinsics ({intrinsics_origin or "none given"}): using the '
                            f"seed's Table 4.1 fallback ({text}); give --intrinsics "
                            'FX,FY,CX,CY or a camera YAML')
            intrinsics_origin = "the seed's Table 4.1 fallback"
        lines = [f'intrinsics: {tool_support.intrinsics_text(intrinsics)} ({intrinsics_origin})']
        warnings.append(tool_support.intrinsics_warning(intrinsics, depth.shape))
        scale = 1000.0 if depth_scale is None else depth_scale
        unit = ''
        unit_warning = None
        if depth.dtype.kind in 'ui':
            unit = (f'; depth {scale:g} units/m ('
                    f'{scale_origin or "millimetres, the default: no --depth-scale"})')
            unit_warning = tool_support.depth_unit_warning(depth, scale)
            warnings.append(unit_warning)
        if self.first:
            self.first = False
            depth_m = decode_depth(depth, depth_scale=depth_scale)
            far_hint = unit_warning or tool_support.depth_unit_warning(depth, scale,
                                                                       out_of_range_m=4.0)
            if self.args.estimate_mount:
                try:
                    estimate = mount.estimate_mount(depth_m, intrinsics)
                except ValueError as exc:
                    raise ValueError(f'{name}: cannot estimate the mount: {exc}'
                                     + (f'; {far_hint}' if far_hint else '')) from None
                self.params, _ = _given_mount(self.args, self.params.replace(
                    camera_height_m=estimate.height_m, camera_pitch_rad=estimate.pitch_rad,
                    camera_roll_rad=estimate.roll_rad))
                self.mount_line = (
                    f'mount estimated from the floor: h {estimate.height_m:.2f} m, pitch '
                    f'{estimate.pitch_deg:.1f} deg, roll {estimate.roll_deg:.1f} deg '
                    f'({estimate.inlier_fraction:.0%} on the plane)'
                    + (f'; {", ".join(self.given)} given instead' if self.given else ''))
            else:
                check = tool_support.check_mount(depth_m, intrinsics, self.params,
                                                 fix=self.fix_mount)
                warnings.append(check.warning)
                if check.estimate is None:
                    lines.append(f'mount not checked against the floor: {check.reason}')
                    warnings.append(None if unit_warning else far_hint)
        lines.insert(0, self.mount_line + unit)
        lines.extend(f'warning: {text}' for text in warnings if text)
        return _Job(name, depth, intrinsics, self.params, depth_scale, extra_lines=tuple(lines))


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
            truth='robot' if base.robot_level else 'seed')  # the rule the parameters follow
        for frame in evaluation.scenario_frames(scenario, max_frames=args.max_frames):
            yield _Job(f'{frame.scenario} {frame.frame_id}', frame.depth, frame.intrinsics,
                       frame.params(base), truth_labels=frame.truth_labels)
    elif args.depth is not None:
        yield depth_job(args, base)
    else:
        if args.intrinsics is not None:
            raise ToolError('--intrinsics does not apply to --bag: its CameraInfo gives them '
                            '(see --info-topic)', usage=True)
        real = _RealFrames(args, base, None, '', fix_mount='--estimate-mount (the first '
                           "frame's floor), or --height, --pitch-deg and --roll-deg")
        for frame in bag_frames(args.bag, args.depth_topic, args.info_topic,
                                every=args.every, max_frames=args.max_frames):
            yield real.job(frame.name, frame.depth, frame.intrinsics, frame.intrinsics_origin)


def depth_job(args: argparse.Namespace, base: DetectorParams) -> _Job:
    """Return the frame of ``--depth``: intrinsics, depth scale and mount from the options."""
    depth = read_depth_png(args.depth)
    intrinsics, origin, camera_scale, camera_mount = _camera(args)
    if args.estimate_mount and intrinsics is None:
        raise ToolError('--estimate-mount needs the intrinsics of the depth image: give '
                        '--intrinsics YAML or --intrinsics FX,FY,CX,CY', usage=True)
    scale, scale_origin = args.depth_scale, '--depth-scale' if args.depth_scale else ''
    if scale is None and camera_scale is not None:
        scale, scale_origin = camera_scale, origin
    intr = intrinsics or SEED_TABLE_4_1
    command = (f'--estimate-mount, or python tools/estimate_mount.py --depth {args.depth} '
               f'--depth-scale {1000.0 if scale is None else scale:g} --intrinsics '
               f'{intr.fx:g},{intr.fy:g},{intr.cx:g},{intr.cy:g} --camera-yaml-out camera.yaml')
    real = _RealFrames(args, base, camera_mount, origin, fix_mount=command)
    return real.job(args.depth.name, depth, intrinsics, origin, scale, scale_origin)


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog='pictures', description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawTextHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--scene', help='a scene of the generator (scenes.SCENE_NAMES)')
    source.add_argument('--depth', type=Path, metavar='PNG',
                        help='a 16-bit depth PNG or PGM (see --depth-scale)')
    source.add_argument('--bag', type=Path, metavar='PATH',
                        help='a rosbag2 folder or a ROS 1 .bag file')
    parser.add_argument('--seed', type=int, default=0, help='scene seed [default: 0]')
    parser.add_argument('--frames', type=parse_frames, metavar='A:B[:C]',
                        help='scene frame indices (a sequence such as person_walking)')
    parser.add_argument('--intrinsics', type=parse_camera, metavar='YAML|FX,FY,CX,CY',
                        help='intrinsics of --depth [px], or a camera YAML (fx, fy, cx, cy,\n'
                             'optional depth_scale and camera_height_m, camera_pitch_deg, '
                             "camera_roll_deg);\nwithout it the seed's Table 4.1 fallback is "
                             'used, with a warning')
    parser.add_argument('--depth-scale', type=float, metavar='UNITS',
                        help='depth units per metre of --depth [default: the YAML\'s, else '
                             '1000 (mm);\nTUM RGB-D: 5000]')
    parser.add_argument('--estimate-mount', action='store_true',
                        help='camera mount from the floor in view (of the first frame of a '
                             'bag);\n--height etc. still override it')
    tool_support.add_topic_options(parser)
    parser.add_argument('--every', type=tool_support.int_in(1), default=1,
                        help='bag: one frame in N')
    parser.add_argument('--max-frames', type=int, metavar='N', help='at most N frames')
    parser.add_argument('--height', type=float, metavar='M', help='camera height [m]')
    parser.add_argument('--pitch-deg', type=float, help='camera pitch, + looks down [deg]')
    parser.add_argument('--roll-deg', type=float, help='camera roll [deg]')
    add_parameter_arguments(parser)
    parser.add_argument('--caption', metavar='TEXT',
                        help='first caption line instead of the frame name')
    parser.add_argument('--no-truth', action='store_true',
                        help='leave out the comparison with the ground truth')
    parser.add_argument('--out', type=Path, required=True,
                        help='PNG: the picture (one frame) or the contact sheet')
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
    truth: np.ndarray | None


def detect(args: argparse.Namespace) -> list[_Detected]:
    """Run the pipeline over every frame the parsed options name, in order."""
    from obstacle_detection.pipeline.detector import Detector

    if args.scene is not None and (args.estimate_mount or args.depth_scale is not None
                                   or args.intrinsics is not None):
        raise ToolError('--estimate-mount, --depth-scale and --intrinsics do not apply to '
                        '--scene (the generator knows its camera)', usage=True)
    if args.bag is not None and args.depth_scale is not None:
        raise ToolError('--depth-scale does not apply to --bag (16UC1 images are millimetres, '
                        '32FC1 metres)', usage=True)
    detected: list[_Detected] = []
    said: set[str] = set()
    for job in jobs(args, base_params(args)):
        result = Detector(job.params).process(job.depth, job.intrinsics,
                                              depth_scale=job.depth_scale)
        caption = job.name if args.caption is None else args.caption
        truth = None if args.no_truth else job.truth_labels
        detected.append(_Detected(job, caption, result, truth))
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
                                 truth_labels=frame.truth, extra_lines=frame.job.extra_lines,
                                 params=frame.job.params, with_legend=with_legend,
                                 max_depth_m=max_depth_m, image_scale=image_scale)


def rule_text(params: DetectorParams) -> str:
    """Name the obstacle rule of ``params`` for a title: robot level or the seed's slope test."""
    return 'robot level' if params.robot_level else "the seed's slope test"


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
    """Draw the frames ``args`` select and write the PNG; return the line to print."""
    detected = detect(args)
    if len(detected) == 1:
        frame = detected[0]
        truth = ', against the ground truth' if frame.truth is not None else ''
        pictures.write_png(args.out, pictures.titled(draw(frame), (
            f'{frame.caption}: obstacles in the depth image and the costmap '
            f'({rule_text(frame.job.params)}{truth})')))
    else:
        pictures.write_png(args.out, sheet(args, detected))
    return f'wrote {args.out} ({len(detected)} frame{"s" if len(detected) > 1 else ""})'


@dataclass
class DepthFrame:
    """A depth frame of a bag: its name, depth (H, W), intrinsics and where they came from."""

    name: str
    depth: np.ndarray
    intrinsics: Intrinsics | None
    intrinsics_origin: str = ''


def bag_frames(path: str | Path, depth_topic: str, info_topic: str | None = None, *,
               every: int = 1, max_frames: int | None = None) -> Iterator[DepthFrame]:
    """Depth frames of a ROS 2 (or ROS 1) bag, in time order, with the latest camera info."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    from obstacle_detection.ros.conversions import camera_info_to_intrinsics, image_to_array

    tool_support.check_bag_path(path)
    try:
        reader = AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except AnyReaderError as exc:
        raise ValueError(f'{path}: cannot read the bag ({exc})') from None
    with contextlib.closing(reader):
        topics = {c.topic: c.msgtype for c in reader.connections}
        if depth_topic not in topics:
            images = sorted(t for t, kind in topics.items() if kind == tool_support.IMAGE_TYPE)
            raise ValueError(f'{path}: no topic {depth_topic!r}; its {tool_support.IMAGE_TYPE} '
                             f'topics: {", ".join(images) or "none"} (use --depth-topic)')
        try:
            info_topic, how = tool_support.choose_info_topic(topics, depth_topic, info_topic)
        except ValueError as exc:
            raise ValueError(f'{path}: {exc}') from None
        wanted = [c for c in reader.connections if c.topic in (depth_topic, info_topic)]
        intrinsics: Intrinsics | None = None
        seen = 0
        for connection, _, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, connection.msgtype)
            if connection.topic != depth_topic:
                intrinsics = camera_info_to_intrinsics(msg)
                continue
            seen += 1
            if (seen - 1) % every:
                continue
            origin = (f'CameraInfo on {info_topic} ({how})' if intrinsics is not None
                      else f'none: no CameraInfo on {info_topic} before the frame'
                      if info_topic else f'none: {how}')
            stamp = msg.header.stamp
            yield DepthFrame(f'{depth_topic} #{seen - 1} t={stamp.sec}.{stamp.nanosec:09d}',
                             image_to_array(msg), intrinsics, intrinsics_origin=origin)
            if max_frames is not None and (seen - 1) // every + 1 >= max_frames:
                return
