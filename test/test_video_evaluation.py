"""Sequence scores of the fused costmap, on scripted observations whose answers are known."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from obstacle_detection.pipeline.costmap import build_costmap
from obstacle_detection.pipeline.fusion import FusionParams
from obstacle_detection.pipeline.params import DetectorParams
from obstacle_detection.evaluation.video import Observation, RunTracker, score_sequence

RES = 0.0625   # a power of two: poses on the lattice stay exact
PARAMS = DetectorParams(costmap_resolution_m=RES)
FUSION = FusionParams(resolution_m=RES)
REPO = __import__('pathlib').Path(__file__).resolve().parents[1]


def floor_points(spacing=RES):
    """Ground points at every cell centre of a 6 m x 6 m area around the odom origin."""
    xs = np.arange(-3.0, 3.0, spacing) + spacing / 2
    gx, gy = np.meshgrid(xs, xs)
    return np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)


def observe(index, pose, obstacles, *, false_hits=()):
    """Observe like a perfect detector with a Kinect-like view: 0.5-2 m ahead, |y| <= 2 m."""
    c, s = math.cos(pose[2]), math.sin(pose[2])

    def to_base(points):
        dx, dy = points[:, 0] - pose[0], points[:, 1] - pose[1]
        out = np.stack([c * dx + s * dy, -s * dx + c * dy, points[:, 2]], axis=1)
        seen = (out[:, 0] >= 0.5) & (out[:, 0] <= 2.0) & (np.abs(out[:, 1]) <= 2.0)
        return out[seen].astype(np.float32)

    obstacle = to_base(np.asarray(obstacles, dtype=np.float64).reshape(-1, 3))
    ground = to_base(floor_points())
    # ground under an obstacle is hidden
    taken = {(math.floor(x / RES), math.floor(y / RES)) for x, y, _ in obstacle}
    keep = [(math.floor(x / RES), math.floor(y / RES)) not in taken for x, y, _ in ground]
    ground = ground[np.asarray(keep, dtype=bool)]
    truth = build_costmap(obstacle, ground, PARAMS)
    detected = truth.data.copy()
    for x, y in false_hits:
        row, col, inside = truth.cell_of(np.array([[x, y]]))
        detected[row[0], col[0]] = 100
    costmap = type(truth)(detected, truth.resolution_m, truth.origin_xy_m)
    return Observation(index=index, pose_true=pose, pose_odom=pose,
                       costmap=costmap, truth_obstacle=obstacle, truth_traversable=ground,
                       truth_costmap=truth.data)


def box(x, y, half=0.09):
    """Points of a small obstacle (a 3 x 3 cell block) centred on (x, y), 0.2 m high."""
    offsets = np.arange(-half, half + 1e-9, RES / 2)
    return [(x + dx, y + dy, 0.2) for dx in offsets for dy in offsets]


def test_run_tracker_counts_frames_until_the_reaction_by_hand():
    tracker = RunTracker(3, ('fused', 'per_frame'), budget=3)
    #           cell 0: steady run t=2..8, detector from t=2, fused from t=3 -> 2 and 1
    #           cell 1: unsteady (detector at t=2 and 4 only) -> not scored
    #           cell 2: steady, the fused grid never reacts, run of 7 frames -> missed
    for t in range(12):
        in_run = np.array([2 <= t <= 8, 2 <= t <= 8, 2 <= t <= 8])
        per_frame = np.array([t >= 2, t in (2, 4), t >= 2])
        fused = np.array([t >= 3, t >= 5, False])
        tracker.step(t, in_run, in_run, {'fused': fused, 'per_frame': per_frame}, per_frame)
    tracker.finish(12)
    report = tracker.report()
    assert report['steady_runs'] == 2 and report['unsteady_runs'] == 1
    assert tracker.counts == {'fused': [2], 'per_frame': [1, 1]}
    assert report['fused']['missed'] == 1 and report['per_frame']['missed'] == 0


def test_a_perfect_detector_driving_to_an_obstacle_scores_perfectly_and_remembers_it():
    obstacle = box(1.59375, 0.03125)         # a block of cells, 1.6 m ahead of the start
    poses = [(RES * i, 0.0, 0.0) for i in range(19)]                 # up to x = 1.125 m
    report = score_sequence('drive', [observe(i, p, obstacle) for i, p in enumerate(poses)],
                            FUSION)
    assert report.per_frame.f1 == 1.0 and report.fused_view.f1 == 1.0
    assert report.fused_area.f1 == 1.0 and report.fused_area.fn == 0
    assert report.per_frame_area.fn > 0                   # out of view: forgotten per frame
    assert max(report.flicker_fused) == 0.0 and max(report.flicker_per_frame) == 0.0
    assert report.mark['fused']['max'] == 1 and report.mark['per_frame']['max'] == 1
    # from x = 1.0625 m the block is closer than 0.5 m: in the blind zone, unseen
    assert report.blind['cells'] > 0
    assert report.blind['fused'] == report.blind['cells']
    assert report.blind['per_frame'] == 0
    assert report.resets == 0 and report.in_place == 0


def test_a_vacated_cell_clears_after_the_computed_number_of_frames():
    obstacle = box(1.21875, -0.15625)
    observations = [observe(i, (0.0, 0.0, 0.0), obstacle if i < 12 else []) for i in range(30)]
    report = score_sequence('leave', observations, FUSION)
    clear = report.clear
    assert clear['steady_runs'] == 9                       # the 3 x 3 block
    assert clear['fused']['median'] == clear['fused']['max'] == FUSION.frames_to_clear() == 5
    assert clear['per_frame']['max'] == 1
    assert clear['fused']['missed'] == 0
    assert max(report.flicker_fused) == 0.0                # catching up is not flicker


def test_a_one_frame_false_alarm_flickers_per_frame_but_not_fused():
    observations = [observe(i, (0.0, 0.0, 0.0), [], false_hits=[(1.3, 0.4)] if i == 20 else [])
                    for i in range(25)]
    report = score_sequence('blip', observations, FUSION)
    known = np.count_nonzero(observations[0].costmap.data != -1)
    assert report.flicker_per_frame[19] == pytest.approx(1 / known)   # on at frame 20
    assert report.flicker_per_frame[20] == pytest.approx(1 / known)   # off at frame 21
    assert max(report.flicker_fused) == 0.0               # -1 + 1 = 0: never occupied
    assert report.fused_view.fp == 0 and report.per_frame.fp == 1


def test_the_report_is_json_and_the_sheet_an_image():
    observations = [observe(i, (RES * i, 0.0, 0.0), box(1.59375, 0.03125)) for i in range(6)]
    report = score_sequence('drive', observations, FUSION, sheet_frames=3)
    line = json.dumps(report.as_dict())
    back = json.loads(line)
    assert back['fused_area']['f1'] == 1.0 and back['frames'] == 6
    assert report.sheet is not None and report.sheet.dtype == np.uint8
    assert report.sheet.ndim == 3 and report.sheet.shape[2] == 3


def run_tool(*args):
    return subprocess.run([sys.executable, str(REPO / 'tools' / 'evaluate.py'), *args],
                          capture_output=True, text=True, timeout=300, cwd=REPO)


def test_tool_scores_a_few_frames_and_draws_the_sheet(tmp_path):
    sheet = tmp_path / 'sheet.png'
    run = run_tool('--sequence', 'person_crossing', '--frames', '4', '--sheet', str(sheet),
                   '--quiet')
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert report['sequences'][0]['sequence'] == 'person_crossing'
    assert report['sequences'][0]['frames'] == 4
    assert '| person_crossing | cell F1, area seen so far |' in run.stdout
    assert sheet.stat().st_size > 1000
    # the fusion settings read as words, not as a dataclass repr
    assert 'FusionParams(' not in run.stdout
    assert ('fusion: a 4 m window at 0.05 m a cell; log-odds +1 a hit, -0.4 a miss, kept in '
            '[-1, 2.4]; occupied from 0.5, free below -0.2') in run.stdout


@pytest.mark.parametrize('args, code, words', [
    (['--frames', '0'], 2, 'argument --frames'),
    (['--params-file', 'no/such.yaml'], 1, 'error: .*no/such.yaml'),
    (['--sheet', 'out.jpg'], 1, 'error: out.jpg: .*png'),
])
def test_tool_refuses_bad_input_with_one_line(args, code, words):
    run = run_tool('--sequence', 'all', *args)
    assert run.returncode == code
    assert 'Traceback' not in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1
    assert __import__('re').search(words, run.stderr)
