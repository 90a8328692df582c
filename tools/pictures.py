#!/usr/bin/env python3
"""Draw what the detector saw, without ROS: depth with obstacles marked + costmap, as PNG.

The options and examples: ``pictures.py --help`` (obstacle_detection.cli.picture_jobs).
"""

from __future__ import annotations

import sys
from typing import Sequence

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.picture_jobs import build_parser, write_pictures


@tool_support.command('pictures')
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    print(write_pictures(build_parser().parse_args(argv)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
