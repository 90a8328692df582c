#!/usr/bin/env python3
"""Play params/nav2_stvl.yaml's STVL at several costmap update rates (docs/stvl.md, third pass).

The runs and replay of test/test_stvl_sequences.py (the node's frame path, the STVL port),
with the update rates given instead of the file's: prints the figures' table, then per run
and rate the one-cell F1 to four places and the most voxels the grid held after an update::

    .venv/bin/python test/stvl_rates.py                       # 30, 15, 10, 7.5, 6, 5 Hz
    .venv/bin/python test/stvl_rates.py --runs drive_past_boxes --rates 10 5

Not a test (pytest does not collect it). About a minute a run on 2 cores.
"""

from __future__ import annotations

import argparse
import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import nav2_replay as replay
import stvl_layer as stvl
import test_stvl_sequences as sequences

from obstacle_detection.cli import bag_processor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', nargs='+', default=['drive_past_boxes', 'person_crossing'],
                        help='run names of test_stvl_sequences.RUNS, or "all"')
    parser.add_argument('--rates', nargs='+', type=float, default=[30, 15, 10, 7.5, 6, 5],
                        help='costmap update rates [Hz]; 30 / rate frames a period, rounded')
    args = parser.parse_args()
    names = [run.name for run in sequences.RUNS]
    chosen = names if args.runs == ['all'] else args.runs
    unknown = sorted(set(chosen) - set(names))
    if unknown:
        parser.error(f'unknown run {unknown}; the runs: {", ".join(names)}')
    config = stvl.read_stvl_costmap(sequences.STVL_YAML)
    values = bag_processor.node_param_values(sequences.CORRIDOR)
    periods = {f'{hz:g} Hz': max(1, round(replay.RATE_HZ / hz)) for hz in args.rates}
    reports = []
    with ProcessPoolExecutor(max_workers=2,
                             mp_context=multiprocessing.get_context('spawn')) as pool:
        for run in sequences.RUNS:
            if run.name in chosen:
                reports += sequences.play_runs([run], config, values, periods, pool)
    print(replay.format_table(reports))
    for f in reports:
        print(f'{f.name} | {f.layer} | F1 {f.f1:.4f} | at most {f.extra["max_voxels"]} voxels')


if __name__ == '__main__':
    main()
