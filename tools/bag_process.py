#!/usr/bin/env python3
"""Run the obstacle detector over a whole rosbag2 bag offline, as fast as the machine allows.

No DDS and no ROS graph: every depth frame of the bag goes through the same code as the node
(``Detector.process`` then ``conversions.result_to_messages``, with the node's parameters read
from its ``--params-file`` YAML), paired with the latest camera info recorded at or before it.
The output bag holds every input message unchanged plus, per processed frame, the obstacle cloud
(``<namespace>/points``), the costmap (``<namespace>/costmap``) and, if asked or set in the
params file, the ground cloud (``<namespace>/ground_points``) and the overlay image
(``<namespace>/overlay``); each output carries the source depth image's header stamp and bag
timestamp. Frames the node would skip (no camera info, size mismatch, unsupported encoding, no
valid depth) are skipped and counted with the reason.

The depth topic may be a raw ``sensor_msgs/Image`` or a ``sensor_msgs/CompressedImage``
(image_transport's ``.../compressedDepth``, iai_kinect2's ``.../compressed``): compressed frames
are decoded by ``obstacle_detection.ros.compressed_depth`` into the array the raw image gives
(16UC1
exactly), so both give the same outputs; a frame that cannot be decoded is skipped with the
reason (corrupt PNG, bad header, ...).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.bag_processor import (DEFAULT_NAMESPACE, ProcessError,
                                                  config_from_values, format_report,
                                                  load_params_file, process_bag)
from obstacle_detection.ros.parameters import (ALL_PARAMS, ParamsFileError,
                                           read_params_files)
from obstacle_detection.cli.bag_writer import DEFAULT_DEPTH_TOPIC, DEFAULT_INFO_TOPIC, STORAGES


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='bag_process.py', description=__doc__.split('\n\n')[0],
        epilog='Example: python tools/bag_process.py in_bag out_bag --params-file '
               'params/corridor.yaml --overlay')
    parser.add_argument('bag', type=Path, help='input rosbag2 folder')
    parser.add_argument('output', type=Path, help='rosbag2 folder to create (must not exist)')
    parser.add_argument('--params-file', type=Path, action='append', default=[],
                        metavar='YAML',
                        help="the node's parameter YAML (default: the node's defaults); "
                             'repeatable, merged in order as ROS does (a later file wins)')
    parser.add_argument('--depth-topic', default=DEFAULT_DEPTH_TOPIC,
                        help='depth topic: a sensor_msgs/Image, or a CompressedImage such as '
                             '.../compressed or .../compressedDepth (default %(default)s)')
    parser.add_argument('--info-topic',
                        help=f'CameraInfo topic (default: {DEFAULT_INFO_TOPIC}, else the bag\'s '
                             'CameraInfo topic found by type)')
    parser.add_argument('--namespace', default=DEFAULT_NAMESPACE,
                        help='prefix of the output topics (default %(default)s)')
    parser.add_argument('--ground', action='store_true',
                        help='also write the ground cloud (or publish_ground in the params)')
    parser.add_argument('--overlay', action='store_true',
                        help='also write overlay images (or publish_overlay in the params)')
    parser.add_argument('--storage', choices=sorted(STORAGES), default='sqlite3',
                        help='output storage (default %(default)s)')
    parser.add_argument('--quiet', action='store_true',
                        help='no per-frame lines (a progress bar on a terminal instead)')
    return parser


def _sets_mount(values: Mapping[str, Any], files: Sequence[Path]) -> bool:
    """Whether one of the params files sets a camera mount parameter."""
    names = ('camera_height_m', 'camera_pitch_deg', 'camera_roll_deg')
    try:
        return any(name in read_params_files(list(files)) for name in names)
    except ParamsFileError:
        return False


def main(argv: Sequence[str] | None = None) -> int:
    """Process a bag; return the exit code (0 success, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    try:
        if args.params_file:
            values = load_params_file(args.params_file)
            origin = ', '.join(str(p) for p in args.params_file)
        else:
            values, origin = {spec.name: spec.default for spec in ALL_PARAMS}, 'defaults'
        config = config_from_values(values, origin)
        summary = process_bag(
            args.bag, args.output, config, depth_topic=args.depth_topic,
            info_topic=args.info_topic, namespace=args.namespace,
            with_ground=args.ground or config.publish_ground,
            with_overlay=args.overlay or config.publish_overlay, storage=args.storage,
            progress=args.quiet,  # the bar only when per-frame lines are off
            on_frame=None if args.quiet else lambda r: print(format_report(r), flush=True),
            mount_origin=origin if args.params_file and _sets_mount(values, args.params_file)
            else "the node's defaults: no params file sets it")
    except ProcessError as err:
        return tool_support.report_error('bag_process.py', err)
    print('\n'.join(summary.lines()))
    return 0


if __name__ == '__main__':
    sys.exit(main())
