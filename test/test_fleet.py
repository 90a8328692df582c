"""Offline work at scale (obstacle_detection.fleet): many bags, sweeps and evaluations on Dask.

The unit tests run in this process (``--workers 0``); the ``integration`` ones start a local
Dask cluster of two worker processes and compare what it gives with one process.
"""

from __future__ import annotations

import functools
import json
import re
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any
from pathlib import Path

import numpy as np
import pytest

from obstacle_detection.cli import bag_processor
from obstacle_detection.cli import support as tool_support
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.evaluation import sweep as grid_search
from obstacle_detection.fleet import bags as fleet_bags
from obstacle_detection.fleet import cluster, scoring
from obstacle_detection.pipeline.params import table_4_2
from obstacle_detection.tools import bag_process, sweep
from test_bag_process import OUTPUT_TOPICS, frame_messages, output_messages, write_bag

REPO = Path(__file__).resolve().parents[1]
SMALL = (128, 106)
PARAMS_YAML = """\
obstacle_detector:
  ros__parameters:
    median_kernel: 5
    normal_neighbours: 8
    validation_neighbours: 6
    max_range_m: 2.5
    costmap_length_m: 2.5
"""


def make_bags(root: Path, depths: list[np.ndarray], count: int, *, repeat: int = 1,
              corrupt: bool = False) -> Path:
    """``root/bags``: ``count`` bags, bag i with the frames rotated by i (each its own)."""
    folder = root / 'bags'
    for i in range(count):
        order = (depths[i % len(depths):] + depths[:i % len(depths)]) * repeat
        write_bag(folder / f'bag{i}', frame_messages(order))
    if corrupt:   # a bag whose storage file is not a database
        (folder / 'corrupt').mkdir()
        (folder / 'corrupt' / 'metadata.yaml').write_text(
            (folder / 'bag0' / 'metadata.yaml').read_text())
        (folder / 'corrupt' / 'bag0.db3').write_bytes(b'not a database' * 64)
    return folder


def one_process_outputs(tmp: Path, bags: list[Path], params_file: Path
                        ) -> dict[str, dict[str, list[tuple[int, object]]]]:
    """Each bag through the one-bag command (one process): its output messages by bag name."""
    out = {}
    for bag in bags:
        target = tmp / 'single' / bag.name
        assert bag_process.main([str(bag), str(target), '--params-file', str(params_file),
                                 '--quiet']) == 0
        out[bag.name] = output_messages(target)
    return out


def no_partial_left(folder: Path) -> bool:
    return not list(folder.rglob('.*.partial'))


# --------------------------------------------------------------------------------------------
# Finding the bags


def test_a_folder_of_bags_keeps_their_paths_below_it(tmp_path: Path,
                                                     depths: list[np.ndarray]) -> None:
    for name in ('robot1/day1', 'robot1/day2', 'robot2/day1'):
        write_bag(tmp_path / 'in' / name, frame_messages(depths[:1]))
    (tmp_path / 'in' / 'notes.txt').write_text('not a bag')
    assert fleet_bags.is_many(tmp_path / 'in')
    assert not fleet_bags.is_many(tmp_path / 'in' / 'robot1' / 'day1')
    found = fleet_bags.find_bags(tmp_path / 'in')
    assert [str(name) for _, name in found] == ['robot1/day1', 'robot1/day2', 'robot2/day1']


def test_a_glob_names_bags(tmp_path: Path, depths: list[np.ndarray]) -> None:
    for name in ('a', 'b', 'c'):
        write_bag(tmp_path / name, frame_messages(depths[:1]))
    pattern = str(tmp_path / '[ab]')
    assert fleet_bags.is_many(pattern)
    assert [bag.name for bag, _ in fleet_bags.find_bags(pattern)] == ['a', 'b']
    with pytest.raises(tool_support.ToolError, match='the pattern matches nothing'):
        fleet_bags.find_bags(str(tmp_path / 'x*'))


def test_two_bags_of_one_name_are_refused(tmp_path: Path, depths: list[np.ndarray]) -> None:
    for name in ('x/run', 'y/run'):
        write_bag(tmp_path / name, frame_messages(depths[:1]))
    with pytest.raises(tool_support.ToolError, match='several bags are named run'):
        fleet_bags.find_bags(str(tmp_path / '*' / 'run'))


# --------------------------------------------------------------------------------------------
# Where the work runs


def test_workers_zero_is_this_process() -> None:
    with cluster.open_fleet(workers=0, tasks=10) as fleet:
        assert not fleet.distributed and fleet.description == 'this process'


def test_a_cluster_without_dask_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cluster, 'DASK_AVAILABLE', False)
    with pytest.raises(tool_support.ToolError, match=r'--workers 2 needs dask.distributed, which '
                                                 r'is not installed: pip install'):
        with cluster.open_fleet(workers=2):
            pass
    with cluster.open_fleet(tasks=10) as fleet:   # nothing asked: this process
        assert not fleet.distributed


def test_workers_and_scheduler_together_are_refused() -> None:
    with pytest.raises(tool_support.ToolError, match='give one of them'):
        with cluster.open_fleet(workers=2, scheduler='tcp://127.0.0.1:8786'):
            pass


@pytest.mark.integration
def test_a_scheduler_that_does_not_answer_is_a_clear_error() -> None:
    with pytest.raises(tool_support.ToolError, match='tcp://127.0.0.1:9: no Dask scheduler '
                                                 'answers'):
        with cluster.open_fleet(scheduler='tcp://127.0.0.1:9'):
            pass


def test_missing_dask_is_one_error_line_of_the_tool(tmp_path: Path, depths: list[np.ndarray],
                                                    monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(cluster, 'DASK_AVAILABLE', False)
    folder = make_bags(tmp_path, depths, 2)
    assert bag_process.main([str(folder), str(tmp_path / 'out'), '--workers', '2']) == 1
    err = capsys.readouterr().err
    assert err.startswith('error: --workers 2 needs dask.distributed') and err.count('\n') == 1
    assert not (tmp_path / 'out').exists()


def test_run_tasks_in_this_process_returns_failures_in_order() -> None:
    fleet = cluster.Fleet(None, 'this process', 1)

    def invert(x: float) -> float:
        return 1 / x
    results = cluster.run_tasks(fleet, invert, [(2,), (0,), (4,)], label='t', progress=False,
                                return_errors=True)
    assert results[0] == 0.5 and results[2] == 0.25
    assert results[1] == cluster.TaskError('ZeroDivisionError: division by zero')
    with pytest.raises(ZeroDivisionError):
        cluster.run_tasks(fleet, invert, [(0,)], label='t', progress=False)


# --------------------------------------------------------------------------------------------
# Many bags in this process


def test_many_bags_in_one_process_equal_one_bag_runs(tmp_path: Path, depths: list[np.ndarray],
                                                     params_file: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    folder = make_bags(tmp_path, depths, 3)
    assert bag_process.main([str(folder), str(tmp_path / 'out'), '--params-file',
                             str(params_file), '--workers', '0']) == 0
    out, err = capsys.readouterr()
    want = one_process_outputs(tmp_path, sorted(folder.iterdir()), params_file)
    for name, messages in want.items():
        assert output_messages(tmp_path / 'out' / name) == messages, name
    total = next(line for line in out.splitlines() if line.startswith('total ')).split()
    assert total[:3] == ['total', '9', '9'] and total[-4:] == ['3', 'ok,', '0', 'failed']
    assert '3 bags on this process' in err
    assert re.fullmatch(r'9 frames in \d+\.\d s: \d+\.\d frames/s overall', out.splitlines()[-1])


def test_a_corrupt_bag_fails_alone_with_its_reason(tmp_path: Path, depths: list[np.ndarray],
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    folder = make_bags(tmp_path, depths, 2, corrupt=True)
    assert bag_process.main([str(folder), str(tmp_path / 'out'), '--workers', '0']) == 1
    out = capsys.readouterr().out
    assert f'{folder / "corrupt"}: failed: {folder / "corrupt"}: cannot read bag' in out
    assert 'file is not a database' in out
    assert '2 ok, 1 failed' in out
    assert sorted(p.name for p in (tmp_path / 'out').iterdir()) == ['bag0', 'bag1']
    assert no_partial_left(tmp_path / 'out')


def test_the_table_counts_skipped_frames_with_the_reason(tmp_path: Path,
                                                         depths: list[np.ndarray],
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    items = frame_messages(depths)
    write_bag(tmp_path / 'bags' / 'late_info', items[1:])   # the first frame has no camera info
    write_bag(tmp_path / 'bags' / 'fine', items)
    assert bag_process.main([str(tmp_path / 'bags'), str(tmp_path / 'out'), '--workers',
                             '0']) == 0
    out = capsys.readouterr().out
    assert f'{tmp_path / "bags" / "late_info"}: skipped 1: no camera info recorded before ' \
           'the frame' in out
    row = next(line for line in out.splitlines() if line.startswith(str(tmp_path / 'bags' /
                                                                         'late_info')))
    assert row.split()[1:4] == ['3', '2', '1']


def test_ctrl_c_leaves_complete_outputs_and_no_partial_one(tmp_path: Path,
                                                           depths: list[np.ndarray],
                                                           monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]
                                                           ) -> None:
    folder = make_bags(tmp_path, depths, 2)
    real = bag_processor.process_frame
    calls = []

    def interrupted(*args: object, **kwargs: object) -> object:
        calls.append(1)
        if len(calls) == 5:   # the second frame of the second bag
            raise KeyboardInterrupt
        return real(*args, **kwargs)
    monkeypatch.setattr(bag_processor, 'process_frame', interrupted)
    assert bag_process.main([str(folder), str(tmp_path / 'out'), '--workers', '0']) == 130
    assert 'interrupted' in capsys.readouterr().err
    assert [p.name for p in (tmp_path / 'out').iterdir()] == ['bag0']
    assert no_partial_left(tmp_path / 'out')


def score_here(frames: list) -> Any:
    """Return a scorer that evaluates the points on ``frames`` with plain evaluate_frames."""
    return lambda points: [evaluation.evaluate_frames(frames, p).frames for p in points]


def test_sweep_tasks_in_one_process_equal_the_plain_run() -> None:
    sources = sequence_sources()
    frames_ = [f for _, _, lazy in sources for f in lazy]
    x, y = grid_search.Axis('theta_deg', ('20', '60')), grid_search.Axis('K', ('4', '5'))
    fleet = cluster.Fleet(None, 'this process', 1)
    got = grid_search.grid_sweep(functools.partial(scoring.score_points, fleet, sources,
                                                   progress=False), table_4_2(), x, y)
    want = grid_search.grid_sweep(score_here(frames_), table_4_2(), x, y)
    assert list(got.grids) == list(want.grids) == ['corridor', 'people', 'overall']
    for scene in want.grids:
        np.testing.assert_array_equal(got.grids[scene], want.grids[scene])
    assert np.isnan(got.grids['overall'][0]).all()   # K = 4 is refused: NaN, as in one process


# --------------------------------------------------------------------------------------------
# A local cluster of two worker processes


def sequence_sources() -> list[scoring.Source]:
    from obstacle_detection.cli.evaluation_args import LazyFrames

    scenarios = [evaluation.Scenario('corridor', 'corridor', seeds=(0, 1)),
                 evaluation.Scenario('people', 'people', seeds=(0,))]
    return [(s.name, s.frame_count, LazyFrames(evaluation.scenario_frames, s, size=SMALL))
            for s in scenarios]


@pytest.fixture(scope='module')
def two_workers() -> Iterator[cluster.Fleet]:
    with cluster.open_fleet(workers=2, tasks=2) as fleet:
        yield fleet


@pytest.mark.integration
def test_the_local_cluster_binds_loopback_and_runs_one_thread_per_worker(
        two_workers: cluster.Fleet) -> None:
    client = two_workers.client
    assert two_workers.distributed and two_workers.workers == 2
    info = client.scheduler_info()
    assert client.scheduler.address.startswith('tcp://127.0.0.1:')
    assert len(info['workers']) == 2
    assert all(address.startswith('tcp://127.0.0.1:') for address in info['workers'])
    assert {w['nthreads'] for w in info['workers'].values()} == {1}

    def threads() -> tuple[str, int]:
        import numba

        cluster.limit_threads()
        return os.environ.get('OMP_NUM_THREADS', ''), numba.get_num_threads()
    assert set(client.run(threads).values()) == {('1', 1)}


@pytest.mark.integration
def test_bags_on_two_workers_equal_one_process(tmp_path: Path, depths: list[np.ndarray],
                                               params_file: Path,
                                               two_workers: cluster.Fleet) -> None:
    folder = make_bags(tmp_path, depths, 4, corrupt=True)
    values = bag_processor.node_param_values(params_file)
    jobs = [fleet_bags.BagJob(bag, tmp_path / 'out' / name, values, str(params_file), 'test')
            for bag, name in fleet_bags.find_bags(folder)]
    outcomes = fleet_bags.process_bags(jobs, two_workers, progress=False)
    assert [o.error is None for o in outcomes] == [True] * 4 + [False]
    want = one_process_outputs(tmp_path, [folder / f'bag{i}' for i in range(4)], params_file)
    for name, messages in want.items():
        assert output_messages(tmp_path / 'out' / name) == messages, name
        assert all(len(messages[t]) == len(depths) for t in OUTPUT_TOPICS.values()
                   if t in ('/obstacles/points', '/obstacles/costmap'))
    assert 'cannot read bag' in outcomes[-1].error
    assert no_partial_left(tmp_path / 'out')


@pytest.mark.integration
def test_a_worker_killed_mid_task_costs_a_retry_not_the_run(
        tmp_path: Path, depths: list[np.ndarray], params_file: Path,
        two_workers: cluster.Fleet) -> None:
    client = two_workers.client
    folder = make_bags(tmp_path, depths, 3, repeat=20)   # 60 frames a bag
    values = bag_processor.node_param_values(params_file)
    jobs = [fleet_bags.BagJob(bag, tmp_path / 'out' / name, values, str(params_file), 'test')
            for bag, name in fleet_bags.find_bags(folder)]
    killed: list[str] = []
    done = threading.Event()

    def kill_a_busy_worker() -> None:   # the first worker seen running a bag's task
        while not done.is_set():
            busy = {w: keys for w, keys in client.processing().items()
                    if any('process_one' in str(k) for k in keys)}
            if busy:
                worker, keys = next(iter(busy.items()))
                pid = client.run(os.getpid, workers=[worker])[worker]
                os.kill(pid, signal.SIGKILL)
                killed.append(str(next(k for k in keys if 'process_one' in str(k))))
                return
            time.sleep(0.01)
    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    try:
        outcomes = fleet_bags.process_bags(jobs, two_workers, progress=False)
    finally:
        done.set()
        killer.join()
    assert killed, 'no task was seen running'
    assert [o.error for o in outcomes] == [None] * 3
    want = one_process_outputs(tmp_path, [folder / f'bag{i}' for i in range(3)], params_file)
    for name, messages in want.items():
        assert output_messages(tmp_path / 'out' / name) == messages, name
    assert no_partial_left(tmp_path / 'out')
    # the killed task ran twice: on the worker that died, then on another
    story = client.story(killed[0])
    assert sum(1 for event in story if len(event) > 2 and event[2] == 'processing') >= 2, story


@pytest.mark.integration
def test_ctrl_c_on_a_cluster_stops_cleanly_and_leaves_no_partial_bag(
        tmp_path: Path, depths: list[np.ndarray], params_file: Path) -> None:
    folder = make_bags(tmp_path, depths, 4, repeat=30)   # 90 frames a bag
    out = tmp_path / 'out'
    # its own session, as a terminal's foreground job; SIGINT as a shell would leave it
    run = subprocess.Popen(
        [sys.executable, str(REPO / 'tools' / 'bag_process.py'), str(folder), str(out),
         '--params-file', str(params_file), '--workers', '2'], cwd=REPO,
        start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        while not (out.exists() and list(out.glob('.*.partial'))):   # a bag being written
            assert run.poll() is None and time.monotonic() < deadline, run.stderr.read()
            time.sleep(0.05)
        os.killpg(run.pid, signal.SIGINT)   # Ctrl-C: every process of the group
        _, err = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    assert run.returncode == 130
    lines = err.splitlines()
    interrupted = lines.index('bag_process.py: interrupted; the output bags not complete '
                              'were removed')
    done = sorted(p.name for p in out.iterdir())
    # then, when some finished, one line naming them and how to resume
    assert lines[interrupted + 1:] == ([] if not done else [
        f'kept {len(done)} finished output bag{"s" if len(done) != 1 else ""}: '
        f'{", ".join(str(out / name) for name in done)}; the same command with '
        f'--skip-existing processes the other {4 - len(done)}'])
    assert 'Traceback' not in err
    assert no_partial_left(out)
    want = one_process_outputs(tmp_path, [folder / name for name in done], params_file)
    for name in done:   # what is there is complete
        assert output_messages(out / name) == want[name], name


@pytest.mark.integration
def test_sweep_on_two_workers_equals_one_process(two_workers: cluster.Fleet) -> None:
    sources = sequence_sources()
    frames_ = [f for _, _, lazy in sources for f in lazy]
    x, y = grid_search.Axis('theta_deg', ('10', '30', '80')), grid_search.Axis('N1', ('0', '12'))
    got = grid_search.grid_sweep(functools.partial(scoring.score_points, two_workers, sources,
                                                   progress=False), table_4_2(), x, y)
    want = grid_search.grid_sweep(score_here(frames_), table_4_2(), x, y)
    assert list(got.grids) == list(want.grids)
    for scene in want.grids:
        np.testing.assert_array_equal(got.grids[scene], want.grids[scene])
        np.testing.assert_array_equal(got.false_alarms[scene], want.false_alarms[scene])
    assert got.positives == want.positives and got.best('overall') == want.best('overall')


@pytest.mark.integration
def test_evaluate_on_two_workers_equals_one_process(two_workers: cluster.Fleet) -> None:
    sources = sequence_sources()
    frames_ = [f for _, _, lazy in sources for f in lazy]
    got = scoring.evaluate_on_fleet(two_workers, sources, table_4_2(), label='x',
                                    progress=False)
    want = evaluation.evaluate_frames(frames_, table_4_2(), label='x')

    def scores(report: evaluation.Report) -> dict:
        data = report.as_dict()
        for summary in [*data['scenes'].values(), data['overall']]:
            summary.pop('mean_ms')   # times differ between runs
        data.pop('seconds')
        return data
    assert scores(got) == scores(want)
    assert [(f.scenario, f.frame_id, f.pixel, f.cell) for f in got.frames] == \
        [(f.scenario, f.frame_id, f.pixel, f.cell) for f in want.frames]


@pytest.mark.integration
def test_the_sweep_command_on_two_workers_writes_the_one_process_json(tmp_path: Path) -> None:
    common = ['--x', 'theta_deg=20,60', '--y', 'N1=0,12', '--scene', 'ramps', '--scene',
              'corridor', '--out', str(tmp_path / 'heat.png')]
    assert sweep.main([*common, '--json', str(tmp_path / 'one.json'), '--workers', '0']) == 0
    assert sweep.main([*common, '--json', str(tmp_path / 'two.json'), '--workers', '2']) == 0
    assert json.loads((tmp_path / 'two.json').read_text()) == \
        json.loads((tmp_path / 'one.json').read_text())


# --------------------------------------------------------------------------------------------
# One process or a cluster, when neither --workers nor --scheduler is given


def test_a_local_cluster_only_when_the_work_pays_its_start() -> None:
    start = cluster.LOCAL_CLUSTER_START_S
    assert not cluster.local_cluster_pays(1.9 * start, 2)   # 4 + 3.8 s > 7.6 s
    assert cluster.local_cluster_pays(2.1 * start, 2)
    assert not cluster.local_cluster_pays(1000.0, 1)
    with cluster.open_fleet(tasks=10, work_s=start) as fleet:
        assert not fleet.distributed
        if len(os.sched_getaffinity(0)) > 1:
            assert fleet.description.startswith(f'this process (about {start:.0f} s of work: a '
                                                'local cluster of ')


def test_small_bags_run_in_this_process_and_say_why(tmp_path: Path, depths: list[np.ndarray],
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    folder = make_bags(tmp_path, depths, 3)
    jobs = [fleet_bags.BagJob(bag, tmp_path / 'out' / name, {}, 'test', 'test')
            for bag, name in fleet_bags.find_bags(folder)]
    work_s = fleet_bags.work_seconds(jobs)   # 3 bags of 3 frames of 128 x 106
    assert work_s == pytest.approx(3 * (fleet_bags.BAG_S + 3 * (
        fleet_bags.FRAME_S + fleet_bags.PIXEL_S * SMALL[0] * SMALL[1])))
    assert bag_process.main([str(folder), str(tmp_path / 'out'), '--quiet']) == 0
    err = capsys.readouterr().err
    if len(os.sched_getaffinity(0)) > 1:
        assert f'3 bags on this process (about {work_s:.0f} s of work: a local cluster' in err


# --------------------------------------------------------------------------------------------
# Reproducible output bags


def test_equal_messages_serialize_to_equal_bytes() -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    from builtin_interfaces.msg import Time

    from obstacle_detection.cli.bag_writer import cdr_bytes
    from obstacle_detection.ros.conversions import points_to_pointcloud2

    points = np.arange(30, dtype=np.float32).reshape(10, 3)
    one, two = (points_to_pointcloud2(points.copy(), stamp=Time(sec=1), frame_id='base_link')
                for _ in range(2))
    ours, rmw = cdr_bytes(one), serialize_message(one)
    assert ours == cdr_bytes(two) and len(ours) == len(rmw)
    assert deserialize_message(ours, PointCloud2) == deserialize_message(rmw, PointCloud2)
    # what differs from rmw's bytes is padding: zero in ours, whatever rmw left in its
    assert all(ours[i] == 0 for i in range(len(ours)) if ours[i] != rmw[i])


def test_the_same_input_gives_the_same_bag_files(tmp_path: Path, depths: list[np.ndarray],
                                                 params_file: Path) -> None:
    import hashlib

    folder = make_bags(tmp_path, depths, 1)
    for run in ('a', 'b'):
        assert bag_process.main([str(folder / 'bag0'), str(tmp_path / run / 'out'), '--quiet',
                                 '--params-file', str(params_file), '--ground',
                                 '--overlay']) == 0

    def digests(bag: Path) -> dict[str, str]:
        return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in bag.iterdir()}
    assert digests(tmp_path / 'a' / 'out') == digests(tmp_path / 'b' / 'out')


# --------------------------------------------------------------------------------------------
# evaluate --real: the JSON report, and --scheduler honoured


def write_real_frames(folder: Path) -> None:
    """Write the files of evaluation_args.REAL_FRAMES: a rendered corridor in their units."""
    import cv2

    from obstacle_detection.cli.evaluation_args import REAL_FRAMES
    from obstacle_detection.sim.scenes import render_scene

    for name, files, scale, intrinsics in REAL_FRAMES:
        (folder / name).mkdir(parents=True)
        for k, file in enumerate(files):
            depth_m = render_scene('corridor', seed=k, intrinsics=intrinsics,
                                   size=(640, 480)).depth_mm / 1000.0
            units = np.minimum(np.round(depth_m * scale), 65535).astype(np.uint16)
            assert cv2.imwrite(str(folder / name / file), units)


def test_evaluate_real_writes_its_json_and_honours_the_scheduler(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from obstacle_detection.tools import evaluate

    write_real_frames(tmp_path / 'real')
    report = tmp_path / 'real.json'
    assert evaluate.main(['--real', str(tmp_path / 'real'), '--json', str(report), '--quiet',
                          '--workers', '0']) == 0
    out = capsys.readouterr().out
    data = json.loads(report.read_text())
    assert [row['frame'] for row in data['frames']] == [
        'tum_office/depth.png', 'tum_fr2_desk/depth_1.png', 'tum_fr2_desk/depth_2.png',
        *(f'dining_room/depth_{i}.pgm' for i in range(1, 6))]
    for row in data['frames']:
        assert f"{row['frame']}: floor marked {row['floor_marked']}/{row['floor']} " in out
    assert data['total']['floor'] == sum(row['floor'] for row in data['frames']) > 0
    assert data['total']['standing_marked'] == sum(r['standing_marked'] for r in data['frames'])
    assert evaluate.main(['--real', str(tmp_path / 'real'), '--quiet', '--scheduler',
                          'tcp://127.0.0.1:9']) == 1
    assert 'tcp://127.0.0.1:9: no Dask scheduler answers' in capsys.readouterr().err
