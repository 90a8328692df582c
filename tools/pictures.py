#!/usr/bin/env python3
"""Draw what the detector saw, without ROS: depth with obstacles marked + costmap, as PNG.

The options: ``pictures.py --help`` (obstacle_detection.cli.picture_jobs). ``--readme [DIR]``
draws this tool's pictures in the README and docs again: the synthetic one always, the
real-frame ones when the real frames are there (``--real-dir``).
"""

from __future__ import annotations

import sys
from dataclasses import astuple
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.evaluation_args import REAL_FRAMES
from obstacle_detection.cli.picture_jobs import build_parser, detect, draw, rule_text, \
    write_pictures
from obstacle_detection.viz import pictures

#: Width of the real-frame pictures [px] (keeps each PNG well under 200 KB).
REAL_WIDTH_PX = 860
#: The README's synthetic pictures: file name -> tools/pictures.py arguments.
SYNTHETIC = {'corridor.png': ['--scene', 'corridor', '--preset', 'corridor']}
#: Each real frame folder's camera options: intrinsics [px] and depth units per metre.
_CAMERA = {name: ('--intrinsics', ','.join(f'{v:g}' for v in astuple(intrinsics)),
                  '--depth-scale', f'{scale:g}') for name, _, scale, intrinsics in REAL_FRAMES}
_FAR = ('--set', 'max_range_m=4.0', '--set', 'costmap_length_m=4.0')
#: The two methods drawn: (caption, tools/pictures.py parameter options).
_SEED = ('the seed method (Table 4.2, K=5), range 4 m',
         ('--preset', 'table_4_2', '--set', 'median_kernel=5', *_FAR))
_ROBOT = ('the default, corridor.yaml (robot level), range 4 m', ('--preset', 'corridor', *_FAR))
#: The real-frame pictures: file name -> panels top to bottom (depth under --real-dir, camera
#: options, name, method), each drawn with its mount estimated from the floor.
REAL = {
    'real_tum_office.png': [('tum_office/depth.png', _CAMERA['tum_office'], 'TUM fr3 office',
                             method) for method in (_SEED, _ROBOT)],
    'real_tum_fr2_desk.png': [('tum_fr2_desk/depth_1.png', _CAMERA['tum_fr2_desk'],
                               'TUM fr2 desk', method) for method in (_SEED, _ROBOT)],
    'real_dining_room.png': [(f'dining_room/depth_{i}.pgm', _CAMERA['dining_room'],
                              f'dining room {i}', _ROBOT) for i in (1, 4)],
}


def recompress(path: Path) -> None:
    """Encode a PNG again at zlib level 9, losslessly (about a third smaller)."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
        raise OSError(f'could not compress {path}')
    print(f'compressed {path} to {path.stat().st_size // 1024} KB')


def real_picture(panels: Sequence[tuple], real_dir: Path) -> np.ndarray:
    """Return the panels drawn one above the other, REAL_WIDTH_PX wide."""
    images = []
    for depth, camera, name, (method, options) in panels:
        job, result = detect(build_parser().parse_args(
            ['--depth', str(real_dir / depth), *camera, '--estimate-mount', *options]))[0]
        job.name = f'{name}: {method}'
        rule = rule_text(job.params)
        images.append(pictures.titled(pictures.fit_width(
            lambda scale, job=job, result=result: draw(job, result, image_scale=scale),
            REAL_WIDTH_PX), job.name if rule in job.name else f'{job.name} ({rule})'))
    gap = np.full((6, REAL_WIDTH_PX, 3), 255, np.uint8)
    return np.vstack([part for image in images for part in (image, gap)][:-1])


def write_readme_pictures(out_dir: Path, real_dir: Path) -> None:
    """Write the README's pictures into ``out_dir``, the real ones from ``real_dir``."""
    real = REAL if real_dir.is_dir() else {}
    if not real:
        tool_support.warn(f'no real frames in {real_dir}; the real-frame pictures '
                          f'({", ".join(REAL)}) are left as they are')
    for name, options in SYNTHETIC.items():
        print(write_pictures(build_parser().parse_args([*options, '--out', str(out_dir / name)])))
        recompress(out_dir / name)
    for name, panels in real.items():
        missing = sorted({p[0] for p in panels if not (real_dir / p[0]).is_file()})
        if missing:
            tool_support.warn(f'{name} skipped, missing in {real_dir}: {", ".join(missing)}')
            continue
        pictures.write_png(out_dir / name, real_picture(panels, real_dir))
        recompress(out_dir / name)


@tool_support.command('pictures')
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    if args.readme is not None:
        write_readme_pictures(args.readme, args.real_dir)
    elif args.out is None:
        raise tool_support.ToolError('argument --out is required (except with --readme)',
                                     usage=True)
    else:
        print(write_pictures(args))
    return 0


if __name__ == '__main__':
    sys.exit(main())
