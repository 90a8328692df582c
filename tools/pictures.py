#!/usr/bin/env python3
"""Draw what the detector saw, without ROS: depth with obstacles marked + costmap, as PNG.

The options and examples: ``pictures.py --help`` (obstacle_detection.cli.picture_jobs).
"""

from __future__ import annotations

import sys
from typing import Sequence

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.picture_jobs import build_parser, write_pictures


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    try:
        done = write_pictures(args)
    except (ValueError, OSError, KeyError) as exc:
        return tool_support.report_error('pictures', exc)
    print(done)
    return 0


if __name__ == '__main__':
    sys.exit(main())
