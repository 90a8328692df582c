#!/usr/bin/env python3
"""Run the obstacle detector over a whole rosbag2 bag offline, as fast as the machine allows.

Each depth frame goes through the node's code; the output bag holds the input and the node's
outputs. Many bags (a folder or a quoted glob) run as Dask tasks (docs/fleet.md).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.bag_processor import (DEFAULT_NAMESPACE, config_from_values,
                                                  node_param_values, process_bag)
from obstacle_detection.cli.bag_writer import STORAGES
from obstacle_detection.fleet import bags as fleet_bags
from obstacle_detection.fleet.cluster import add_fleet_arguments, fleet_options, open_fleet


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='bag_process', description=__doc__.split('\n\n')[0],
        epilog='Examples: python tools/bag_process.py in_bag out_bag --params-file '
               "params/corridor.yaml --overlay; python tools/bag_process.py 'bags/*' out/ "
               '--workers 2')
    parser.add_argument('bag', help='input rosbag2 folder; or many: a folder of bags or a glob '
                                    'pattern (quoted)')
    parser.add_argument('output', type=Path,
                        help='rosbag2 folder to create (must not exist); for many bags the '
                             'folder of the output bags (one per input, named after it)')
    parser.add_argument('--params-file', type=Path, action='append', default=[], metavar='YAML',
                        help="the node's parameter YAML, repeatable: a later file wins "
                             "(default: the node's defaults)")
    tool_support.add_topic_options(parser)
    parser.add_argument('--namespace', default=DEFAULT_NAMESPACE,
                        help='prefix of the output topics (default %(default)s)')
    parser.add_argument('--ground', action='store_true',
                        help='also write the ground cloud (or publish_ground in the params)')
    parser.add_argument('--overlay', action='store_true',
                        help='also write overlay images (or publish_overlay in the params)')
    parser.add_argument('--storage', choices=sorted(STORAGES), default='sqlite3',
                        help='output storage (default %(default)s)')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')
    parser.add_argument('--skip-existing', action='store_true',
                        help='many bags: keep the output bags an earlier (interrupted) run '
                             'finished and process the rest')
    add_fleet_arguments(parser)
    return parser


@tool_support.command('bag_process')
def main(argv: Sequence[str] | None = None) -> int:
    """Process a bag (or many); return the exit code (0 success, 1 bad input, 2 bad usage)."""
    args = build_parser().parse_args(argv)
    values = node_param_values(args.params_file)
    origin = ', '.join(str(p) for p in args.params_file) or 'defaults'
    config = config_from_values(values, origin)
    defaults = node_param_values([])
    mount_origin = (origin if any(values[name] != defaults[name] for name in (
        'camera_height_m', 'camera_pitch_deg', 'camera_roll_deg'))
        else "the node's defaults: no params file changes it")
    if fleet_bags.is_many(args.bag) or args.scheduler or args.workers:
        return _process_many(args, values, origin, mount_origin)
    summary = process_bag(
        Path(args.bag), args.output, config, depth_topic=args.depth_topic,
        info_topic=args.info_topic, namespace=args.namespace,
        with_ground=args.ground or config.publish_ground,
        with_overlay=args.overlay or config.publish_overlay, storage=args.storage,
        progress=not args.quiet, mount_origin=mount_origin)
    print('\n'.join(summary.lines()))
    return 0


def _process_many(args: argparse.Namespace, values: Mapping[str, Any], origin: str,
                  mount_origin: str) -> int:
    """Every bag one task (fleet.bags): the table and the run's speed; 1 when a bag failed."""
    # absolute: a worker resolves a relative path in its own folder, not in this one
    output = Path(os.path.abspath(args.output))
    if fleet_bags.is_many(args.bag):
        outputs = [(Path(os.path.abspath(bag)), output / name)
                   for bag, name in fleet_bags.find_bags(args.bag)]
    else:   # one bag on a cluster (--workers / --scheduler): the output is the one named
        outputs = [(Path(os.path.abspath(args.bag)), output)]
    # an output bag is written whole or not at all (staged, renamed): one that exists is complete
    done = [output for _, output in outputs if output.exists()]
    if done and not args.skip_existing:
        raise tool_support.ToolError(
            done[0], f'output already exists ({len(done)} of {len(outputs)}); --skip-existing '
                     'keeps them and processes the rest, or remove them')
    if done:
        print(f'kept {len(done)} output bag{"s" if len(done) != 1 else ""} from an earlier run: '
              f'{", ".join(str(p) for p in done)}', file=sys.stderr)
        outputs = [(bag, output) for bag, output in outputs if output not in done]
        if not outputs:
            return 0
    # one thread per task: the workers are the parallelism (same results: compare=False)
    values = {**values, 'compute_threads': 1}
    jobs = [fleet_bags.BagJob(
        bag, output, values, origin, mount_origin, depth_topic=args.depth_topic,
        info_topic=args.info_topic, namespace=args.namespace, with_ground=args.ground,
        with_overlay=args.overlay, storage=args.storage)
        for bag, output in outputs]
    began = time.perf_counter()
    try:
        auto = args.workers is None and args.scheduler is None
        work_s = fleet_bags.work_seconds(jobs, enough=60.0) if auto else None
        with open_fleet(**fleet_options(args), tasks=len(jobs), work_s=work_s) as fleet:
            print(f'{len(jobs)} bag{"s" if len(jobs) != 1 else ""} on {fleet.description}',
                  file=sys.stderr, flush=True)
            outcomes = fleet_bags.process_bags(jobs, fleet)
    except tool_support.ToolError:   # e.g. the cluster lost its workers: none half-written
        fleet_bags.remove_stale_staging(jobs)
        raise
    except KeyboardInterrupt:
        fleet_bags.remove_stale_staging(jobs)
        kept = [job.output for job in jobs if job.output.exists()]
        print('bag_process.py: interrupted; the output bags not complete were removed',
              file=sys.stderr)
        if kept:
            print(f'kept {len(kept)} finished output bag{"s" if len(kept) != 1 else ""}: '
                  f'{", ".join(str(p) for p in kept)}; the same command with --skip-existing '
                  f'processes the other {len(jobs) - len(kept)}', file=sys.stderr)
        return 130
    print(fleet_bags.format_table(outcomes))
    print('\n'.join(_used_lines(outcomes, values, mount_origin)))
    wall_s = time.perf_counter() - began
    frames = sum(o.processed for o in outcomes)
    print(f'{frames} frames in {wall_s:.1f} s: {frames / wall_s:.1f} frames/s overall')
    return 0 if all(o.error is None for o in outcomes) else 1


def _used_lines(outcomes: Sequence[Any], values: Mapping[str, Any],
                mount_origin: str) -> list[str]:
    """Say what the bags were processed with, as one bag's summary does: intrinsics, mount."""
    found: dict[str, list[str]] = {}
    for outcome in outcomes:
        if outcome.error is None:
            text = (f'CameraInfo on {outcome.info_topic} ({outcome.info_how})'
                    if outcome.info_topic else f'none recorded ({outcome.info_how})')
            found.setdefault(text, []).append(str(outcome.bag))
    config = config_from_values(values, 'the parameters')
    return ([f'intrinsics: {text}: {", ".join(bags)}' for text, bags in found.items()]
            + [f'camera mount: {tool_support.mount_text(config.detector.params)} '
               f'({mount_origin})'])


if __name__ == '__main__':
    sys.exit(main())
