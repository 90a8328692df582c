"""Score the detector on the real frames of ../shared/data/real (no labels: heights decide).

Per frame, the mount is fitted to the floor and the detector runs with the parameter file; of
the pixels inside the region of interest it prints the share of floor pixels (within 2 cm of
the floor) marked as obstacle, lower is better, and of standing pixels (5 cm above the floor up
to ``robot_height_m``) marked, higher is better; then the totals.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.evaluation_args import parse_assignment
from obstacle_detection.pipeline import geometry
from obstacle_detection.pipeline.depth import decode_depth
from obstacle_detection.evaluation.runner import apply_overrides, load_params_file
from obstacle_detection.pipeline.mount import estimate_mount
from obstacle_detection.pipeline.params import Intrinsics, corridor
from obstacle_detection.evaluation.datasets import read_depth_png
from obstacle_detection.labels import LABEL_OBSTACLE
from obstacle_detection.pipeline.detector import Detector

REPO = tool_support.PACKAGE_ROOT

#: The frames of ../shared/data/real/README.md: (folder, files, units per metre, intrinsics).
FRAMES = (
    ('tum_office', ('depth.png',), 5000.0, Intrinsics(535.4, 539.2, 320.1, 247.6)),
    ('tum_fr2_desk', ('depth_1.png', 'depth_2.png'), 5000.0,
     Intrinsics(520.9, 521.0, 325.1, 249.7)),
    ('dining_room', tuple(f'depth_{i}.pgm' for i in range(1, 6)), 1000.0,
     Intrinsics(518.0, 519.0, 325.5, 253.5)),
)
FLOOR_BAND_M = 0.02
STANDING_M = 0.05


def score(depth_m: np.ndarray, intr: Intrinsics, params) -> tuple[int, int, int, int, str]:
    """Return (floor, floor marked, standing, standing marked, mount text) of one frame."""
    est = estimate_mount(depth_m, intr)
    p = params.replace(camera_height_m=est.height_m, camera_pitch_rad=est.pitch_rad,
                       camera_roll_rad=est.roll_rad)
    result = Detector(p).process(depth_m, intr)
    rays = geometry.ground_rays(depth_m.shape, intr, p)
    d = depth_m.reshape(-1)
    x, y = d * rays[0], d * rays[1]
    z = d * rays[2] + np.float32(p.camera_height_m)
    inside = (d > 0) & (x >= p.min_range_m) & (x <= p.max_range_m) & (
        np.abs(y) <= p.lateral_limit_m)
    marked = result.labels.reshape(-1) == LABEL_OBSTACLE
    on_floor = inside & (np.abs(z) <= FLOOR_BAND_M)
    standing = inside & (z >= STANDING_M) & (z <= p.robot_height_m)
    mount = (f'h {est.height_m:.2f} m, pitch {est.pitch_deg:.1f} deg, '
             f'roll {est.roll_deg:.1f} deg; {result.floor.summary()}')
    return (int(on_floor.sum()), int((on_floor & marked).sum()), int(standing.sum()),
            int((standing & marked).sum()), mount)


def _with_path(path: Path, err: Exception) -> str:
    """Return the error's message, led by the path unless it already names it."""
    text = str(err)
    return text if text.startswith(str(path)) else f'{path}: {text}'


def main(argv: list[str] | None = None) -> int:
    """Command-line entry: print the per-frame and total shares."""
    parser = argparse.ArgumentParser(prog='real_frames', description=__doc__.splitlines()[0])
    parser.add_argument('--data', type=Path, default=REPO.parent / 'shared' / 'data' / 'real',
                        help='folder of the real frames [default: ../shared/data/real]')
    parser.add_argument('--params-file', type=Path,
                        default=tool_support.package_file('params/corridor.yaml'),
                        help='node parameter file [default: params/corridor.yaml]')
    parser.add_argument('--set', action='append', type=parse_assignment, default=[],
                        metavar='KEY=VALUE',
                        help='override one parameter (as tools/evaluate.py); repeatable')
    args = parser.parse_args(argv)
    try:
        params = load_params_file(args.params_file, corridor())
    except (OSError, ValueError) as err:
        print(f'error: {_with_path(args.params_file, err)}', file=sys.stderr)
        return 1
    try:
        params = apply_overrides(params, dict(args.set))
    except ValueError as err:
        print(f'error: --set: {err}', file=sys.stderr)
        return 1
    totals = np.zeros(4, np.int64)
    for folder, files, scale, intr in FRAMES:
        for name in files:
            path = args.data / folder / name
            try:
                depth = decode_depth(read_depth_png(path), depth_scale=scale)
                counts = score(depth, intr, params)
            except (OSError, ValueError) as err:
                print(f'error: {_with_path(path, err)}', file=sys.stderr)
                return 1
            totals += counts[:4]
            print(f'{folder}/{name}: floor marked {counts[1]}/{counts[0]} '
                  f'({100.0 * counts[1] / max(counts[0], 1):.2f} %), standing marked '
                  f'{counts[3]}/{counts[2]} ({100.0 * counts[3] / max(counts[2], 1):.1f} %)'
                  f'  [{counts[4]}]')
    print(f'total: floor marked {100.0 * totals[1] / max(totals[0], 1):.2f} % of '
          f'{totals[0]} px, standing marked {100.0 * totals[3] / max(totals[2], 1):.1f} % of '
          f'{totals[2]} px')
    return 0


if __name__ == '__main__':
    sys.exit(main())
