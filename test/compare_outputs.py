#!/usr/bin/env python3
"""Compare the detector's outputs of this tree with those of another commit, bit for bit.

Not a test (pytest does not collect it): the check issue 9's speed work was held to. Every
frame of the robot-level suite (``evaluation.SUITES['robot']``, the default configuration
params/corridor.yaml with each frame's mount) at K = 5 and K = 17, and the benchmark's frames
(corridor, people, ramps, farm_row; seeds 0-2; 512x424 and 960x540), are processed by both
trees, each frame twice in a row (buffers reused across frames must not leak into results);
the SHA-256 of every output (labels, points, voxels, normals, neighbours, heights, drops, the
filtered depth, the costmap and its origin, the fitted floor) is compared. The other commit
is exported with ``git archive`` into a temporary folder; both trees run in fresh processes
with the same interpreter, compiled (numba) unless ``OBSTACLE_DETECTION_NO_JIT`` is set.

    .venv/bin/python test/compare_outputs.py 2f8c7d1      # prints one line per difference

Across a change of module paths (the other commit's digest mode cannot run this script's
imports), save the other tree's digests with its own copy of this script and compare:

    PYTHONPATH=. .venv/bin/python test/compare_outputs.py --digest before.json   # old tree
    .venv/bin/python test/compare_outputs.py --against before.json               # this tree

Exit status 0 when every output is identical, 1 otherwise (or on an error, one line).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
_FIELDS = ('obstacle_points', 'ground_points', 'labels', 'voxel_points', 'voxel_normals',
           'voxel_slope_obstacle', 'voxel_is_obstacle', 'voxel_neighbours', 'pixel_voxel',
           'depth_m', 'voxel_height_m', 'drop_points')


def _jobs():
    """Yield (name, depth, intrinsics, params) of every frame compared."""
    from obstacle_detection.evaluation import runner as evaluation
    from obstacle_detection.pipeline.params import KINECT_V2_SD, PRESETS, Intrinsics
    from obstacle_detection.ros.parameters import detector_params_from_ros, read_params_file
    from obstacle_detection.sim.scenes import render_scene, scene_params

    base = detector_params_from_ros(read_params_file(REPO / 'params' / 'corridor.yaml'))
    for scenario in evaluation.load_scenarios(evaluation.SUITES['robot']):
        for frame in evaluation.scenario_frames(scenario):
            params = frame.params(base)
            for k in (5, 17):
                yield (f'{scenario.name}/{frame.frame_id}/K{k}', frame.depth, frame.intrinsics,
                       params.replace(median_kernel=k))
    sizes = {(512, 424): KINECT_V2_SD,
             (960, 540): Intrinsics(fx=540.7, fy=540.7, cx=479.75, cy=269.75)}
    for size, intr in sizes.items():
        for name in ('corridor', 'people', 'ramps', 'farm_row'):
            for seed in range(3):
                frame = render_scene(name, seed=seed, intrinsics=intr, size=size)
                for k in (5, 17):
                    params = scene_params(frame, PRESETS['corridor'](median_kernel=k))
                    yield (f'bench/{size[0]}x{size[1]}/{name}/{seed}/K{k}', frame.depth_mm,
                           frame.intrinsics, params)


def digest(out: Path) -> int:
    """Process every frame with the obstacle_detection on sys.path; write {key: sha256}."""
    import numpy as np

    from obstacle_detection.pipeline.detector import Detector

    jobs = list(_jobs())
    Detector(jobs[0][3]).warm_up()
    detectors: dict = {}
    results = []
    for _ in range(2):
        for name, depth, intr, params in jobs:
            detector = detectors.setdefault(params, Detector(params))
            results.append((name, detector.process(depth, intr)))
    hashes: dict[str, str] = {}
    for index, (name, result) in enumerate(results):
        key = f'{index // len(jobs)}/{name}'
        arrays = {f: np.asarray(getattr(result, f)) for f in _FIELDS}
        arrays['costmap'] = result.costmap.data
        arrays['costmap_frame'] = np.array([result.costmap.resolution_m,
                                            *result.costmap.origin_xy_m])
        fit = result.floor
        arrays['floor'] = np.array([fit.refined, fit.height_m, fit.pitch_rad, fit.roll_rad,
                                    fit.d_height_m, fit.d_pitch_deg, fit.d_roll_deg,
                                    fit.samples], np.float64)
        for field, arr in arrays.items():
            h = hashlib.sha256(f'{arr.dtype.str}{arr.shape}'.encode())
            h.update(np.ascontiguousarray(arr).tobytes())
            hashes[f'{key}|{field}'] = h.hexdigest()
        hashes[f'{key}|floor_reason'] = fit.reason
    out.write_text(json.dumps(hashes))
    return 0


def _run_digest(tree: Path, out: Path) -> None:
    """Run this script's digest mode in a fresh process with ``tree`` first on sys.path."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    run = subprocess.run([sys.executable, str(Path(__file__).resolve()), '--digest', str(out)],
                         cwd=tree, env=env, capture_output=True, text=True)
    if run.returncode != 0:
        last = (run.stderr.strip().splitlines() or ['(no message)'])[-1]
        raise RuntimeError(f'{tree}: digest failed: {last}')


def main(argv: list[str] | None = None) -> int:
    """Compare this tree's outputs with those of the commit given; print the differences."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('commit', nargs='?', help='the commit to compare with')
    parser.add_argument('--digest', type=Path, help=argparse.SUPPRESS)
    parser.add_argument('--against', type=Path, metavar='JSON',
                        help='compare with digests saved by --digest instead of a commit')
    args = parser.parse_args(argv)
    if args.digest is not None:
        return digest(args.digest)
    if args.against is not None:
        with tempfile.TemporaryDirectory(prefix='compare_outputs_') as tmp:
            try:
                _run_digest(REPO, Path(tmp) / 'ours.json')
                theirs = json.loads(args.against.read_text())
            except (RuntimeError, OSError, ValueError) as error:
                print(f'error: {error}')
                return 1
            ours = json.loads((Path(tmp) / 'ours.json').read_text())
        return _report(theirs, ours, str(args.against))
    if not args.commit:
        parser.error('give the commit to compare with')
    with tempfile.TemporaryDirectory(prefix='compare_outputs_') as tmp:
        other = Path(tmp) / 'tree'
        other.mkdir()
        archive = subprocess.run(['git', '-C', str(REPO), 'archive', args.commit],
                                 capture_output=True)
        if archive.returncode != 0:
            print(f'error: {REPO}: git archive {args.commit}: '
                  f'{archive.stderr.decode().strip()}')
            return 1
        subprocess.run(['tar', '-x', '-C', str(other)], input=archive.stdout, check=True)
        try:
            _run_digest(other, Path(tmp) / 'theirs.json')
            _run_digest(REPO, Path(tmp) / 'ours.json')
        except RuntimeError as error:
            print(f'error: {error}')
            return 1
        theirs = json.loads((Path(tmp) / 'theirs.json').read_text())
        ours = json.loads((Path(tmp) / 'ours.json').read_text())
    return _report(theirs, ours, args.commit)


def _report(theirs: dict, ours: dict, other: str) -> int:
    """Print one line per differing output and a summary; 0 when all are identical."""
    keys = sorted(set(theirs) | set(ours))
    differ = [k for k in keys if theirs.get(k) != ours.get(k)]
    for key in differ:
        print(f'differs: {key}')
    frames = len({k.split('|')[0] for k in keys})
    print(f'{len(keys)} outputs of {frames} frame runs compared with {other}: '
          f'{len(differ)} differ')
    return 1 if differ else 0


if __name__ == '__main__':
    sys.exit(main())
