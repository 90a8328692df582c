#!/usr/bin/env python3
r"""Estimate the camera mount (height, pitch, roll) of a depth frame from the floor in view.

Prints the mount and the floor's share of the points (within 4 m); writes it as a node
parameter file (``--params-out``)::

    python tools/estimate_mount.py --depth depth.png --depth-scale 5000 \
        --intrinsics 535.4,539.2,320.1,247.6 --params-out mount.yaml

Point the camera at open floor: a hidden floor under a large table gives the table.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Sequence

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.support import parse_intrinsics
from obstacle_detection.pipeline.depth import decode_depth
from obstacle_detection.pipeline.mount import MountEstimate, estimate_mount
from obstacle_detection.evaluation.datasets import read_depth_png
from obstacle_detection.ros.parameters import PARAMS_FILE_KEY


def params_yaml(estimate: MountEstimate) -> str:
    """Node parameter file fragment holding the mount (angles in degrees, as the node's)."""
    return (f'# camera mount from the floor plane ({estimate.inlier_fraction:.0%} of the points '
            f'on it), tools/estimate_mount.py\n'
            f'{PARAMS_FILE_KEY}:\n'
            f'  ros__parameters:\n'
            f'    camera_height_m: {estimate.height_m:.4f}\n'
            f'    camera_pitch_deg: {estimate.pitch_deg:.3f}\n'
            f'    camera_roll_deg: {estimate.roll_deg:.3f}\n')


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(prog='estimate_mount',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--depth', type=Path, required=True, metavar='FILE',
                        help='16-bit depth PNG or PGM')
    parser.add_argument('--depth-scale', type=float, default=1000.0, metavar='UNITS',
                        help='depth units per metre [default: 1000, mm; TUM: 5000]')
    parser.add_argument('--intrinsics', type=parse_intrinsics, required=True,
                        metavar='FX,FY,CX,CY', help='pinhole intrinsics of the depth image [px]')
    parser.add_argument('--params-out', type=Path, metavar='YAML',
                        help='write a node parameter file fragment with the mount (for the '
                             'node, bag_process.py and pictures.py --params-file)')
    return parser


@tool_support.command('estimate_mount')
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input or no floor found, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    if not (math.isfinite(args.depth_scale) and args.depth_scale > 0.0):
        raise tool_support.ToolError(f'argument --depth-scale: {args.depth_scale} must be > 0',
                                     usage=True)
    raw = read_depth_png(args.depth)
    unit_warning = tool_support.depth_unit_warning(raw, args.depth_scale)
    try:
        estimate = estimate_mount(decode_depth(raw, depth_scale=args.depth_scale),
                                  args.intrinsics)
    except ValueError as exc:
        # the depth may be in range only at another scale
        hint = unit_warning or tool_support.depth_unit_warning(raw, args.depth_scale,
                                                               out_of_range_m=4.0)
        reason = f'{exc}; {hint}' if hint else str(exc)
        raise ValueError(f'{args.depth}: cannot estimate the mount: {reason}') from None
    if unit_warning:
        tool_support.warn(f'{args.depth}: {unit_warning}')
    print(f'{args.depth}: height {estimate.height_m:.3f} m, pitch {estimate.pitch_deg:.2f} deg, '
          f'roll {estimate.roll_deg:.2f} deg; floor holds {estimate.inlier_fraction:.1%} of '
          f'{estimate.n_points} points within 4 m')
    if args.params_out is not None:
        args.params_out.parent.mkdir(parents=True, exist_ok=True)
        args.params_out.write_text(params_yaml(estimate), encoding='utf-8')
        print(f'wrote {args.params_out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
