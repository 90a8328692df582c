"""Draw what the detector saw, without ROS: depth with obstacles marked + costmap, as PNG."""

from __future__ import annotations

import argparse
import contextlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.evaluation_args import add_parameter_arguments, base_params
from obstacle_detection.cli.support import ToolError, parse_intrinsics
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.evaluation.datasets import read_depth_png
from obstacle_detection.pipeline import mount
from obstacle_detection.pipeline.depth import decode_depth
from obstacle_detection.pipeline.params import DetectorParams, Intrinsics
from obstacle_detection.viz import pictures

#: Where ``--readme`` writes the README's pictures, and where it finds the real frames.
README_DIR = tool_support.PACKAGE_ROOT / 'tools' / 'readme'
REAL_DIR = tool_support.PACKAGE_ROOT.parent / 'shared' / 'data' / 'real'
#: Contact sheets (several frames): thumbnails this wide [px], this many a row.
SHEET_THUMB_PX = 600
SHEET_COLUMNS = 2
#: What to do when the floor disagrees with the mount in use.
FIX_MOUNT = ('--estimate-mount (from the first frame\'s floor), or python tools/estimate_mount.py '
             '--params-out mount.yaml, then --params-file mount.yaml')


@dataclass
class _Job:
    name: str
    depth: np.ndarray
    intrinsics: Intrinsics
    params: DetectorParams
    depth_scale: float | None = None
    truth_labels: np.ndarray | None = None
    extra_lines: tuple[str, ...] = ()


def parse_frames(text: str) -> range:
    """``a:b[:c]`` (stop excluded) or a single index -> range (argparse type)."""
    try:
        parts = [int(p) for p in text.split(':')]
        frames = range(parts[0], parts[0] + 1) if len(parts) == 1 else range(*parts)
    except (ValueError, TypeError):   # not integers, a zero step or more than three parts
        frames = None
    if frames is None or frames.step < 1:
        raise argparse.ArgumentTypeError(f'expected start:stop[:step], got {text!r}')
    return frames


class _RealFrames:
    """Turns real depth frames into jobs, saying which intrinsics, scale and mount are used."""

    def __init__(self, args: argparse.Namespace, params: DetectorParams) -> None:
        self.args, self.params = args, params
        self.mount_line = (f'mount: {tool_support.mount_text(params)} (the parameters\' '
                           f'--preset {args.preset}, --params-file, --set)')
        self.first = True

    def job(self, name: str, depth: np.ndarray, intrinsics: Intrinsics,
            intrinsics_origin: str, depth_scale: float | None = None,
            scale_origin: str = '') -> _Job:
        """Return the job of one frame; its lines say what is used and warn."""
        lines = [f'intrinsics: {tool_support.intrinsics_text(intrinsics)} ({intrinsics_origin})']
        warnings = [tool_support.intrinsics_warning(intrinsics, depth.shape)]
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
                self.params = self.params.replace(
                    camera_height_m=estimate.height_m, camera_pitch_rad=estimate.pitch_rad,
                    camera_roll_rad=estimate.roll_rad)
                self.mount_line = (
                    f'mount estimated from the floor: h {estimate.height_m:.2f} m, pitch '
                    f'{estimate.pitch_deg:.1f} deg, roll {estimate.roll_deg:.1f} deg '
                    f'({estimate.inlier_fraction:.0%} on the plane)')
            else:
                check = tool_support.check_mount(depth_m, intrinsics, self.params, FIX_MOUNT)
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
        scenario = evaluation.Scenario(
            name=args.scene, scene=args.scene, seeds=(args.seed,),
            frames=tuple(args.frames) if args.frames is not None else None,
            truth='robot' if base.robot_level else 'seed')  # the rule the parameters follow
        for frame in evaluation.scenario_frames(scenario):
            yield _Job(f'{frame.scenario} {frame.frame_id}', frame.depth, frame.intrinsics,
                       frame.params(base), truth_labels=frame.truth_labels)
    elif args.depth is not None:
        yield depth_job(args, base)
    else:
        real = _RealFrames(args, base)
        for frame in bag_frames(args.bag, args.depth_topic, args.info_topic, args.frames):
            yield real.job(*frame)


def depth_job(args: argparse.Namespace, base: DetectorParams) -> _Job:
    """Return the frame of ``--depth``: intrinsics, depth scale and mount from the options."""
    if args.intrinsics is None:
        raise ToolError('--depth needs --intrinsics FX,FY,CX,CY (of the depth image, in pixels)',
                        usage=True)
    return _RealFrames(args, base).job(args.depth.name, read_depth_png(args.depth),
                                       args.intrinsics, 'from --intrinsics', args.depth_scale,
                                       '--depth-scale' if args.depth_scale else '')


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog='pictures', description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawTextHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--scene', help='a scene of the generator (scenes.SCENE_NAMES)')
    source.add_argument('--depth', type=Path, metavar='PNG',
                        help='a 16-bit depth PNG or PGM (with --intrinsics, see --depth-scale)')
    source.add_argument('--bag', type=Path, metavar='PATH',
                        help='a rosbag2 folder or a ROS 1 .bag file')
    source.add_argument('--readme', type=Path, nargs='?', const=README_DIR, metavar='DIR',
                        help="draw this tool's pictures in the README and docs again, into "
                             'DIR [default: tools/readme]')
    parser.add_argument('--real-dir', type=Path, default=REAL_DIR, metavar='DIR',
                        help='--readme: the real frames (tum_office/, tum_fr2_desk/, '
                             'dining_room/)\n[default: ../shared/data/real beside the '
                             'repository]')
    parser.add_argument('--seed', type=int, default=0, help='scene seed [default: 0]')
    parser.add_argument('--frames', type=parse_frames, metavar='A:B[:C]',
                        help='frame indices of a scene sequence (such as person_walking) or '
                             'of a bag')
    parser.add_argument('--intrinsics', type=parse_intrinsics, metavar='FX,FY,CX,CY',
                        help='pinhole intrinsics of --depth [px]')
    parser.add_argument('--depth-scale', type=float, metavar='UNITS',
                        help='depth units per metre of --depth [default: 1000 (mm); TUM RGB-D: '
                             '5000]')
    parser.add_argument('--estimate-mount', action='store_true',
                        help='camera mount from the floor in view (of the first frame of a '
                             'bag);\nwithout it, the mount of the parameters (--params-file, '
                             '--set)')
    tool_support.add_topic_options(parser)
    add_parameter_arguments(parser)
    parser.add_argument('--out', type=Path,
                        help='PNG: the picture (one frame) or the contact sheet')
    return parser


def detect(args: argparse.Namespace) -> list[tuple[_Job, Any]]:
    """Run the pipeline over every frame the parsed options name, in order: (job, result)."""
    from obstacle_detection.pipeline.detector import Detector

    if args.scene is not None and (args.estimate_mount or args.depth_scale is not None
                                   or args.intrinsics is not None):
        raise ToolError('--estimate-mount, --depth-scale and --intrinsics do not apply to '
                        '--scene (the generator knows its camera)', usage=True)
    if args.bag is not None and (args.depth_scale is not None or args.intrinsics is not None):
        raise ToolError('--depth-scale and --intrinsics do not apply to --bag (its CameraInfo '
                        'gives the intrinsics; 16UC1 images are millimetres, 32FC1 metres)',
                        usage=True)
    detected = []
    said: set[str] = set()
    for job in jobs(args, base_params(args)):
        result = Detector(job.params).process(job.depth, job.intrinsics,
                                              depth_scale=job.depth_scale)
        detected.append((job, result))
        print(f'{job.name}: {int(result.obstacle_points.shape[0])} obstacle voxels, '
              f'{result.timings_ms["total"]:.0f} ms', file=sys.stderr)
        for line in job.extra_lines:  # what was used: said once, again when it changes
            if line not in said:
                print(line if line.startswith('warning: ') else f'  {line}', file=sys.stderr)
                said.add(line)
    if not detected:
        raise ValueError('no frames to draw: --frames selects none (a bag\'s frames before its '
                         'first CameraInfo are left out)')
    return detected


def draw(job: _Job, result: Any, **options: Any) -> np.ndarray:
    """Return the picture of one detected frame (``pictures.side_by_side``), without title."""
    options.setdefault('extra_lines', job.extra_lines)
    return pictures.side_by_side(result, job.params, caption=job.name, **options)


def rule_text(params: DetectorParams) -> str:
    """Name the obstacle rule of ``params`` for a title: robot level or the seed's slope test."""
    return 'robot level' if params.robot_level else "the seed's slope test"


def sheet(detected: Sequence[tuple[_Job, Any]]) -> np.ndarray:
    """Return the contact sheet of several frames, with one full-size legend underneath."""
    depths = [np.asarray(result.depth_m) for _, result in detected]
    farthest = max(float(d[np.isfinite(d) & (d > 0)].max(initial=0.0)) for d in depths) or 1.0
    # the lines every frame shares (mount, intrinsics) once under the sheet, not per thumbnail
    shared = [line for line in detected[0][0].extra_lines
              if all(line in job.extra_lines for job, _ in detected)]
    images = [pictures.fit_width(
        lambda scale, job=job, result=result: draw(
            job, result, with_legend=False, max_depth_m=farthest, image_scale=scale,
            extra_lines=[line for line in job.extra_lines if line not in shared]),
        SHEET_THUMB_PX) for job, result in detected]
    grid = pictures.tile(images, columns=SHEET_COLUMNS)
    job, result = detected[0]
    legend = pictures.legend_row([(grid.shape[1] - 6) // 2] * 2, job.params,
                                 truth=False, above_robot=pictures.above_robot_pixels(
                                     result, job.params) is not None)
    if shared:
        legend = np.vstack([legend, pictures.caption_band(
            pictures.wrap(shared, legend.shape[1]),
            legend.shape[1])])
    return pictures.titled(grid, f'{len(detected)} frames: obstacles in the depth image and '
                                 f'the costmap ({rule_text(job.params)})', below=legend)


def write_pictures(args: argparse.Namespace) -> str:
    """Draw the frames ``args`` select and write the PNG; return the line to print."""
    detected = detect(args)
    if len(detected) == 1:
        job, result = detected[0]
        truth = ', against the ground truth' if job.truth_labels is not None else ''
        pictures.write_png(args.out, pictures.titled(draw(
            job, result, truth_labels=job.truth_labels), (
            f'{job.name}: obstacles in the depth image and the costmap '
            f'({rule_text(job.params)}{truth})')))
    else:
        pictures.write_png(args.out, sheet(detected))
    return f'wrote {args.out} ({len(detected)} frame{"s" if len(detected) > 1 else ""})'


def bag_frames(path: str | Path, depth_topic: str, info_topic: str | None = None,
               frames: range | None = None) -> Iterator[tuple[str, np.ndarray, Intrinsics, str]]:
    """Depth frames of a ROS 2 (or ROS 1) bag, in time order, with the latest camera info.

    Yields (name, depth, intrinsics, where they came from); frames: indices among the depth
    messages [default: all]; those before the first CameraInfo are left out.
    """
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
        if info_topic is None:
            raise ValueError(f'{path}: no intrinsics: {how}')
        wanted = [c for c in reader.connections if c.topic in (depth_topic, info_topic)]
        intrinsics: Intrinsics | None = None
        index = -1
        first_ns: int | None = None
        for connection, _, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, connection.msgtype)
            if connection.topic != depth_topic:
                intrinsics = camera_info_to_intrinsics(msg)
                continue
            index += 1
            stamp_ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            first_ns = stamp_ns if first_ns is None else first_ns
            if frames is not None and index >= frames.stop:
                return
            if intrinsics is None or (frames is not None and index not in frames):
                continue
            yield (f'{depth_topic} #{index}, {tool_support.time_text(stamp_ns, first_ns)}',
                   image_to_array(msg), intrinsics, f'CameraInfo on {info_topic} ({how})')
