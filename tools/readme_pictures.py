#!/usr/bin/env python3
"""Make every picture of the README again, from the repository's own code.

The synthetic pictures always; the real-frame ones when the real frames are there (``--real-dir``,
default ``../shared/data/real`` beside the repository). Only the captions' timings change.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import astuple
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from obstacle_detection.viz import pictures
from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli import picture_jobs
from obstacle_detection.cli.evaluation_args import REAL_FRAMES

REPOSITORY = tool_support.PACKAGE_ROOT
DEFAULT_OUT_DIR = REPOSITORY / 'tools' / 'readme'
DEFAULT_REAL_DIR = REPOSITORY.parent / 'shared' / 'data' / 'real'
#: Width of the real-frame pictures [px] (keeps each PNG well under 200 KB).
REAL_WIDTH_PX = 860

#: ``tools/pictures.py`` arguments of the synthetic pictures (file name -> arguments).
SYNTHETIC = {
    'corridor.png': ['--scene', 'corridor', '--preset', 'corridor'],
    'person_walking_sheet.png': ['--scene', 'person_walking', '--frames', '0:90:15',
                                 '--no-truth', '--thumb-width', '600', '--columns', '2'],
}

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


def real_picture(panels: Sequence[tuple], real_dir: Path, width: int = REAL_WIDTH_PX
                 ) -> np.ndarray:
    """Return the panels drawn by ``tools/pictures.py``, one above the other, ``width`` wide."""
    parser = picture_jobs.build_parser()
    images = []
    for depth, camera, name, (method, options) in panels:
        caption = f'{name}: {method}'
        argv = ['--depth', str(real_dir / depth), *camera, '--estimate-mount', *options,
                '--caption', caption, '--out', '-']
        for frame in picture_jobs.detect(parser.parse_args(argv)):
            rule = picture_jobs.rule_text(frame.job.params)
            images.append(pictures.titled(pictures.fit_width(
                lambda scale, frame=frame: picture_jobs.draw(frame, image_scale=scale), width),
                caption if rule in caption else f'{caption} ({rule})'))
    gap = np.full((6, width, 3), 255, np.uint8)
    return np.vstack([part for image in images for part in (image, gap)][:-1])


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(prog='readme_pictures',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--out-dir', type=Path, default=DEFAULT_OUT_DIR, metavar='DIR',
                        help='where the PNGs go [default: tools/readme]')
    parser.add_argument('--real-dir', type=Path, default=DEFAULT_REAL_DIR, metavar='DIR',
                        help='the real frames (tum_office/, tum_fr2_desk/, dining_room/) '
                             '[default: ../shared/data/real beside the repository]')
    return parser


@tool_support.command('readme_pictures')
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 a picture could not be made)."""
    args = build_parser().parse_args(argv)
    parser = picture_jobs.build_parser()
    real = REAL if args.real_dir.is_dir() else {}
    if not real:
        tool_support.warn(f'no real frames in {args.real_dir}; the real-frame pictures '
                          f'({", ".join(REAL)}) are left as they are')
    for name, options in SYNTHETIC.items():
        out = args.out_dir / name
        print(picture_jobs.write_pictures(parser.parse_args([*options, '--out', str(out)])))
        recompress(out)
    for name, panels in real.items():
        missing = sorted({p[0] for p in panels if not (args.real_dir / p[0]).is_file()})
        if missing:
            tool_support.warn(f'{name} skipped, missing in {args.real_dir}: '
                              f'{", ".join(missing)}')
            continue
        pictures.write_png(args.out_dir / name, real_picture(panels, args.real_dir))
        recompress(args.out_dir / name)
    return 0


if __name__ == '__main__':
    sys.exit(main())
