#!/usr/bin/env python3
"""Replay a rosbag2 bag on ROS 2 topics with its recorded timing (in place of ros2 bag play).

Every topic's messages go out as recorded (compressed depth too), with the sensor-data QoS unless
--reliable.
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.bag_player import PlayOptions, Player, open_bag


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='bag_play', description=__doc__.split('\n\n')[0],
        epilog='Example: python tools/bag_play.py out/demo/input_bag --rate 0.5 --loop (into a '
               'detector started with -r depth/image_raw:=/kinect2/sd/image_depth_rect '
               '-r depth/camera_info:=/kinect2/sd/camera_info)')
    parser.add_argument('bag', type=Path, help='rosbag2 folder (sqlite3 or mcap)')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='speed factor, 2 = twice as fast (default %(default)s)')
    parser.add_argument('--loop', action='store_true', help='play again and again until Ctrl-C')
    parser.add_argument('--reliable', action='store_true',
                        help='publish with reliable QoS (default: sensor data, best effort); '
                             'the subscriber must then be reliable too')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')
    return parser


@tool_support.command('bag_play')
def main(argv: Sequence[str] | None = None) -> int:
    """Play a bag; return the exit code (0 done, 1 bad bag, 2 bad usage, 130 Ctrl-C)."""
    args = build_parser().parse_args(argv)
    options = PlayOptions(rate=args.rate, loop=args.loop, reliable=args.reliable,
                          progress=not args.quiet)
    open_bag(args.bag).close()  # bad input fails before DDS starts

    import rclpy
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    # Ctrl-C is Python's KeyboardInterrupt, even in a job started with SIGINT ignored (a
    # script's `bag_play ... &`): rclpy's own handler would shut the context down under the
    # playing loop, whose next publish then dies with "publisher's context is invalid".
    signal.signal(signal.SIGINT, signal.default_int_handler)
    rclpy.init(args=None, signal_handler_options=SignalHandlerOptions.NO)
    node = Node('bag_player')
    player = None
    try:
        player = Player(node, args.bag, options)
        print('\n'.join(player.play().lines()))
    finally:
        if player is not None:
            player.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
