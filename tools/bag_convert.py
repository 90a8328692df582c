#!/usr/bin/env python3
"""Convert recorded RGB-D data into rosbag2 bags that the detector can replay.

Sources (one sub-command each):

``tum``
    RGB-D benchmark layout (TUM RGB-D; also ETH3D SLAM, Bonn, ICL-NUIM in TUM format):
    ``rgb.txt`` and ``depth.txt`` list ``timestamp filename`` lines (``#`` starts a comment;
    without them, the ``<seconds>.png`` names in ``depth/`` and ``rgb/`` give the stamps),
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
    A folder of 16-bit depth PNGs, in millimetres unless ``--depth-scale`` says otherwise (units
    per metre: 5000 for TUM frames), and optionally a colour folder with as many images, sorted
    by name and stamped ``start + k / rate``. A first frame that looks like another unit read
    as millimetres (e.g. TUM's) is refused, naming the scale that fits.
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
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from obstacle_detection.cli import support as tool_support
from obstacle_detection.evaluation.datasets import (DIML_DEPTH_KINDS, TUM_CAMERAS, EvaluationError,
                                                    FrameSource, diml_frames, diml_sample_frames,
                                                    folder_frames, tum_frames)
from obstacle_detection.cli.bag_writer import (DEFAULT_COLOR_TOPIC, DEFAULT_DEPTH_TOPIC,
                                               DEFAULT_FRAME_ID, DEFAULT_INFO_TOPIC, STORAGES,
                                               BagOptions, convert_ros1, write_frames)


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='bag_convert', description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='Run "bag_convert SOURCE -h" for the options of one source.')
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
    p.add_argument('sequence', type=Path, help='folder with depth.txt and rgb.txt (or depth/ and '
                   'rgb/ of <seconds>.png)')
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
                       help='a folder of 16-bit depth PNGs (+ a colour folder)',
                       description=folder_frames.__doc__)
    p.add_argument('depth_dir', type=Path, help='folder of 16-bit depth PNGs')
    p.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    p.add_argument('--color-dir', type=Path, help='folder with as many colour images')
    p.add_argument('--depth-scale', type=float, metavar='UNITS',
                   help='depth units per metre of the PNGs (default: 1000, millimetres; '
                        'TUM RGB-D: 5000)')

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
                                        start_s=args.start_time,
                                        depth_units_per_m=args.depth_scale),
    }
    try:
        if args.source == 'ros1':
            summary = convert_ros1(args.bag, args.output, storage=args.storage,
                                   topics=args.topics, progress=not args.quiet,
                                   decompress_depth=args.decompress_depth)
        else:
            source = sources[args.source]()
            summary = write_frames(source, args.output, options_from_args(args))
    except EvaluationError as err:
        return tool_support.report_error('bag_convert', err)
    print('\n'.join(summary.lines()))
    return 0


if __name__ == '__main__':
    sys.exit(main())
