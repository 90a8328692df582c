#!/usr/bin/env python3
r"""Draw what the detector saw, without ROS: depth with obstacles marked + costmap, as PNG.

One frame gives one picture (the seed's figures 4.22-4.27 beside figure 4.23, with a caption:
frame, obstacle count, time); several frames (a sequence, a labelled folder, a bag) give a
contact sheet of thumbnails, and ``--frames-dir`` keeps every full-size picture too::

    python tools/pictures.py --scene corridor --out corridor.png
    python tools/pictures.py --scene person_walking --frames 0:84:6 --out walk_sheet.png
    python tools/pictures.py --depth frame.png --intrinsics intrinsics.yaml --out frame_out.png
    python tools/pictures.py --depth tum.png --intrinsics 535.4,539.2,320.1,247.6 \\
        --depth-scale 5000 --estimate-mount --out tum_out.png
    python tools/pictures.py --folder recordings/lab_run --out lab_sheet.png
    python tools/pictures.py --bag run.bag --depth-topic /kinect2/sd/image_depth \\
        --info-topic /kinect2/sd/camera_info --height 0.6 --every 10 --out bag_sheet.png

Frames with ground truth (scenes, labelled folders) get a third panel comparing the obstacle
pixels with the truth (hit red, false alarm orange, miss blue) unless ``--no-truth``.
A depth file whose camera mount is unknown can be drawn with ``--estimate-mount``: the mount
comes from the floor in view (``obstacle_detection.mount.estimate_mount``) and is written in
the caption.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

if __package__ in (None, ''):  # run as a script: make the repository root importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from obstacle_detection import evaluation, mount, pictures  # noqa: E402
from obstacle_detection.depth import decode_depth  # noqa: E402
from obstacle_detection.params import PRESETS, DetectorParams, Intrinsics  # noqa: E402
from tools.estimate_mount import parse_intrinsics  # noqa: E402
from tools.evaluate import base_params, parse_assignment  # noqa: E402


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


def mount_caption(estimate: mount.MountEstimate) -> str:
    """One caption line giving a mount estimated from the floor."""
    return (f'mount estimated from the floor: h {estimate.height_m:.2f} m, pitch '
            f'{estimate.pitch_deg:.1f} deg, roll {estimate.roll_deg:.1f} deg '
            f'({estimate.inlier_fraction:.0%} on the plane)')


def _mount(args: argparse.Namespace, params: DetectorParams) -> DetectorParams:
    changes: dict[str, float] = {}
    if args.height is not None:
        changes['camera_height_m'] = args.height
    if args.pitch_deg is not None:
        changes['camera_pitch_rad'] = math.radians(args.pitch_deg)
    if args.roll_deg is not None:
        changes['camera_roll_rad'] = math.radians(args.roll_deg)
    return params.replace(**changes) if changes else params


def jobs(args: argparse.Namespace, base: DetectorParams) -> Iterator[_Job]:
    """Return the frames to draw, from whichever source the options name."""
    if args.scene is not None:
        mount = {k: v for k, v in (('height_m', args.height), ('pitch_deg', args.pitch_deg),
                                   ('roll_deg', args.roll_deg)) if v is not None}
        scenario = evaluation.Scenario(
            name=args.scene, scene=args.scene, seeds=(args.seed,),
            frames=tuple(args.frames) if args.frames is not None else None,
            mount=tuple(sorted(mount.items())))
        for frame in evaluation.scenario_frames(scenario, max_frames=args.max_frames):
            yield _Job(f'{frame.scenario} {frame.frame_id}', frame.depth, frame.intrinsics,
                       frame.params(base), truth_labels=frame.truth_labels,
                       sequence=scenario.is_sequence)
    elif args.folder is not None:
        for frame in evaluation.load_labelled_folder(args.folder, max_frames=args.max_frames):
            yield _Job(f'{frame.scenario} {frame.frame_id}', frame.depth, frame.intrinsics,
                       frame.params(base), frame.depth_scale, frame.truth_labels, True)
    elif args.depth is not None:
        yield depth_job(args, base)
    else:
        params = _mount(args, base)
        for frame in pictures.bag_frames(args.bag, args.depth_topic, args.info_topic,
                                         every=args.every, max_frames=args.max_frames):
            yield _Job(frame.name, frame.depth, frame.intrinsics, params, sequence=True)


def depth_job(args: argparse.Namespace, base: DetectorParams) -> _Job:
    """Return the frame of ``--depth``: intrinsics, depth scale and mount from the options.

    Mount: the camera YAML's, or with ``--estimate-mount`` the floor's (which needs the
    intrinsics), then ``--height`` / ``--pitch-deg`` / ``--roll-deg``. Depth scale:
    ``--depth-scale``, else the YAML's, else millimetres. Raises ValueError (no floor found,
    no intrinsics for the estimate, a bad file).
    """
    depth = pictures.read_depth_png(args.depth)
    params, intrinsics, scale = base, None, None
    if isinstance(args.intrinsics, Intrinsics):
        intrinsics = args.intrinsics
    elif args.intrinsics is not None:
        camera = evaluation.read_camera_yaml(args.intrinsics)
        intrinsics, scale = camera['intrinsics'], camera['depth_scale']
        params = params.replace(camera_height_m=camera['height_m'],
                                camera_pitch_rad=camera['pitch_rad'],
                                camera_roll_rad=camera['roll_rad'])
    if args.depth_scale is not None:
        scale = args.depth_scale
    extra_lines: tuple[str, ...] = ()
    if args.estimate_mount:
        if intrinsics is None:
            raise ValueError('--estimate-mount needs the intrinsics of the depth image: give '
                             '--intrinsics YAML or --intrinsics FX,FY,CX,CY')
        try:
            estimate = mount.estimate_mount(decode_depth(depth, depth_scale=scale), intrinsics)
        except ValueError as exc:
            raise ValueError(f'{args.depth}: cannot estimate the mount: {exc}') from None
        params = params.replace(camera_height_m=estimate.height_m,
                                camera_pitch_rad=estimate.pitch_rad,
                                camera_roll_rad=estimate.roll_rad)
        line = mount_caption(estimate)
        given = [f'--{name}' for name, value in (('height', args.height),
                                                 ('pitch-deg', args.pitch_deg),
                                                 ('roll-deg', args.roll_deg))
                 if value is not None]
        if given:
            line += f'; {", ".join(given)} given instead'
        extra_lines = (line,)
    return _Job(args.depth.name, depth, intrinsics, _mount(args, params), scale,
                extra_lines=extra_lines)


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line interface."""
    parser = argparse.ArgumentParser(prog='pictures.py', description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawTextHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--scene', help='a scene of the generator (scenes.SCENE_NAMES)')
    source.add_argument('--depth', type=Path, metavar='PNG', help='a 16-bit depth PNG [mm]')
    source.add_argument('--folder', type=Path, metavar='DIR',
                        help='a labelled folder (depth/, labels/, intrinsics.yaml)')
    source.add_argument('--bag', type=Path, metavar='PATH', help='a ROS 2 (or ROS 1) bag')
    parser.add_argument('--seed', type=int, default=0, help='scene seed [default: 0]')
    parser.add_argument('--frames', type=parse_frames, metavar='A:B[:C]',
                        help='scene frame indices (a sequence such as person_walking)')
    parser.add_argument('--intrinsics', type=parse_camera, metavar='YAML|FX,FY,CX,CY',
                        help='intrinsics and mount of --depth (camera YAML, see '
                             'tools/evaluate.py), or the intrinsics alone [px]; '
                             "without it the seed's Table 4.1 fallback is used")
    parser.add_argument('--depth-scale', type=float, metavar='UNITS',
                        help='--depth units per metre [default: the YAML\'s, else 1000 (mm); '
                             'TUM: 5000]')
    parser.add_argument('--estimate-mount', action='store_true',
                        help='--depth: camera mount from the floor in view (needs '
                             '--intrinsics); --height etc. still override it')
    parser.add_argument('--depth-topic', default='/camera/depth/image_raw',
                        help='bag depth topic [default: /camera/depth/image_raw]')
    parser.add_argument('--info-topic', help='bag camera_info topic [default: none]')
    parser.add_argument('--every', type=int, default=1, help='bag: one frame in N')
    parser.add_argument('--max-frames', type=int, metavar='N', help='at most N frames')
    parser.add_argument('--height', type=float, metavar='M', help='camera height [m]')
    parser.add_argument('--pitch-deg', type=float, help='camera pitch, + looks down [deg]')
    parser.add_argument('--roll-deg', type=float, help='camera roll [deg]')
    parser.add_argument('--preset', choices=sorted(PRESETS), default='table_4_2')
    parser.add_argument('--params-file', type=Path, metavar='YAML',
                        help='node parameter file applied on top of the preset')
    parser.add_argument('--set', action='append', type=parse_assignment, default=[],
                        metavar='KEY=VALUE', help='override one parameter; repeatable')
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


def render(args: argparse.Namespace) -> list[tuple[str, np.ndarray]]:
    """(caption, RGB picture) of every frame the parsed options name, in order.

    Also writes ``--frames-dir`` and reports each frame on stderr; raises ValueError,
    OSError or KeyError on bad input.
    """
    from obstacle_detection import refine
    from obstacle_detection.pipeline import Detector

    if args.depth is None and (args.estimate_mount or args.depth_scale is not None):
        raise ValueError('--estimate-mount and --depth-scale apply to --depth only')
    base = base_params(args)
    refiner = refine.LogisticRefiner.load(args.refiner) if args.refiner else None
    drawn: list[tuple[str, np.ndarray]] = []
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
        image = pictures.side_by_side(result, caption=caption, truth_labels=truth,
                                      labels=labels, costmap=costmap,
                                      extra_lines=job.extra_lines)
        if args.frames_dir is not None:
            safe = job.name.replace(' ', '_').replace('/', '_').replace('#', '')
            pictures.write_png(args.frames_dir / f'{len(drawn):04d}_{safe}.png', image)
        drawn.append((caption, image))
        print(f'{caption}: {int(result.obstacle_points.shape[0])} obstacle voxels, '
              f'{result.timings_ms["total"]:.0f} ms', file=sys.stderr)
        for line in job.extra_lines:
            print(f'  {line}', file=sys.stderr)
    if not drawn:
        raise ValueError('no frames to draw')
    return drawn


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input)."""
    args = build_parser().parse_args(argv)
    try:
        drawn = render(args)
        if len(drawn) == 1:
            pictures.write_png(args.out, drawn[0][1])
        else:
            names, images = zip(*drawn)
            pictures.write_png(args.out, pictures.contact_sheet(
                images, labels=names, columns=args.columns, thumb_width=args.thumb_width))
    except (ValueError, OSError, KeyError) as exc:
        print(f'pictures.py: error: {exc}', file=sys.stderr)
        return 2
    print(f'wrote {args.out} ({len(drawn)} frame{"s" if len(drawn) > 1 else ""})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
