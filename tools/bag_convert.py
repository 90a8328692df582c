#!/usr/bin/env python3
"""Convert recorded RGB-D data into rosbag2 bags that the detector can replay.

One sub-command per source (``bag_convert SOURCE -h``): per frame a 16UC1 depth image [mm], a
CameraInfo and a colour image on the Kinect v2 driver's SD topics; a ROS 1 bag message for message.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from obstacle_detection.cli import support as tool_support
from obstacle_detection.evaluation.datasets import (DIML_DEPTH_KINDS, TUM_CAMERAS, diml_frames,
                                                    folder_frames, tum_frames)
from obstacle_detection.cli.bag_writer import STORAGES, BagOptions, convert_ros1, write_frames
from obstacle_detection.pipeline.params import Intrinsics


def intrinsics_or_file(text: str) -> Path | Intrinsics:
    """``--intrinsics``: ``fx,fy,cx,cy`` [px] as four numbers, else a file path."""
    if text.count(',') == 3:
        return tool_support.parse_intrinsics(text)
    return Path(text)


TUM_HELP = '''Convert a sequence in the TUM RGB-D layout (TUM, ETH3D SLAM, Bonn, ICL-NUIM).

Depth frames listed in depth.txt (or named depth/<seconds>.png), 5000 units per metre, each with
the colour frame nearest in time (within 0.02 s; rgb.txt or rgb/<seconds>.png). Loose frames
without stamps (depth_N.png beside color_N.png): use "bag_convert folder".'''

DIML_HELP = '''Convert one DIML/CVL indoor sequence folder (<scene>/<date>/<n>).

The release has no stamps: frame i (the number before the file suffix) is stamped
--start-time + i / --rate. Depth in millimetres; colour from col/.'''

ROS1_HELP = '''Convert a ROS 1 bag (.bag, e.g. recorded with iai_kinect2) to a rosbag2 bag.

Every message is converted to its ROS 2 Jazzy type. Compressed depth topics are kept as recorded
(the node, with its depth_transport parameter, and bag_process --depth-topic read them). A rosbag2
bag needs no conversion: bag_play, bag_process and pictures --bag read it.'''

FOLDER_HELP = '''Convert a folder of 16-bit depth images (PNG or PGM), in name order, at --rate.

Colour comes from --color-dir (as many images, in name order) or from the same folder: color_N.png
(or colour_N, rgb_N) beside depth_N.png / depth_N.pgm, as the real frames of ../shared/data/real
ship. Depth is read in millimetres unless --depth-scale says otherwise (TUM frames: 5000); a first
frame that looks like another unit is refused with the scale that fits.'''


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='bag_convert', description=__doc__.split('\n\n')[0],
        epilog='Run "bag_convert SOURCE -h" for the options of one source.')
    sub = parser.add_subparsers(dest='source', required=True, metavar='SOURCE')

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument('--storage', choices=sorted(STORAGES), default='sqlite3',
                        help='rosbag2 storage (default: %(default)s)')
    common.add_argument('--quiet', action='store_true', help='no progress bar')

    frames = argparse.ArgumentParser(add_help=False)
    frames.add_argument('--no-color', dest='with_color', action='store_false',
                        help='write depth and camera info only')
    frames.add_argument('--intrinsics', dest='intrinsics_path', type=intrinsics_or_file,
                        metavar='FILE|FX,FY,CX,CY',
                        help='the depth camera [px]: four numbers, a YAML with fx, fy, cx, cy[, '
                             'width, height], a ROS camera_info YAML or an ETH3D '
                             'calibration.txt; else Kinect v2 defaults (tum: --camera), with a '
                             'warning')

    timed = argparse.ArgumentParser(add_help=False)
    timed.add_argument('--rate', dest='rate_hz', type=float, default=30.0, metavar='RATE',
                       help='frame rate [Hz] used to stamp frames (default %(default)s)')
    timed.add_argument('--start-time', dest='start_s', type=float, default=0.0, metavar='S',
                       help='stamp of frame 0 [s since the epoch] (default %(default)s)')

    p = sub.add_parser('tum', parents=[common, frames], help='TUM RGB-D format '
                       '(TUM, ETH3D SLAM, Bonn, ICL-NUIM)', description=TUM_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('path', metavar='sequence', type=Path, help='folder with depth.txt and rgb.txt '
                   '(or depth/ and rgb/ of <seconds>.png)')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.set_defaults(read=tum_frames)
    p.add_argument('--camera', choices=sorted(TUM_CAMERAS),
                   help='TUM camera intrinsics (fr1, fr2, fr3, or ros = 525/525/319.5/239.5)')

    p = sub.add_parser('diml', parents=[common, frames, timed],
                       help='DIML/CVL indoor sequence folder <scene>/<date>/<n>',
                       description=DIML_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('path', metavar='sequence', type=Path,
                   help='folder holding col/ and raw_png/ (up, warp)')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.set_defaults(read=diml_frames)
    p.add_argument('--depth', dest='depth_kind', choices=sorted(DIML_DEPTH_KINDS), default='raw',
                   help='raw (_rd), up (_ud, upsampled) or warp (_wd, in the colour view) '
                        'depth (default %(default)s)')

    p = sub.add_parser('folder', parents=[common, frames, timed],
                       help='a folder of 16-bit depth PNG/PGM images (colour beside or in '
                            '--color-dir)', description=FOLDER_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('path', metavar='depth_dir', type=Path,
                   help='folder of 16-bit depth images (PNG or PGM), colour images beside them '
                        'allowed')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.set_defaults(read=folder_frames)
    p.add_argument('--color-dir', type=Path, help='folder with as many colour images')
    p.add_argument('--depth-scale', dest='depth_units_per_m', type=float, metavar='UNITS',
                   help='depth units per metre of the images (default: 1000, millimetres; '
                        'TUM RGB-D: 5000)')

    p = sub.add_parser('ros1', parents=[common], help='a ROS 1 bag (e.g. iai_kinect2)',
                       description=ROS1_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('path', metavar='bag', type=Path, help='ROS 1 .bag file')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.set_defaults(read=convert_ros1)
    p.add_argument('--topics', nargs='+', default=(), metavar='TOPIC',
                   help='convert only these topics (default: all)')
    return parser


@tool_support.command('bag_convert')
def main(argv: Sequence[str] | None = None) -> int:
    """Run the converter; return the exit code (0 success, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    # the options named as the reader's keywords
    options = {key: value for key, value in vars(args).items() if key not in (
        'source', 'read', 'path', 'output', 'storage', 'quiet')}
    if args.source == 'ros1':
        summary = convert_ros1(args.path, args.output, storage=args.storage,
                               progress=not args.quiet, **options)
    else:
        summary = write_frames(args.read(args.path, **options), args.output, BagOptions(
            args.storage, with_color=args.with_color, progress=not args.quiet))
    print('\n'.join(summary.lines()))
    return 0


if __name__ == '__main__':
    sys.exit(main())
