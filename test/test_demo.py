"""Tests of tools/demo.py: the bundled demo runs end to end on loopback DDS."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest
import ros_env
from rosbags.rosbag2 import Reader

from obstacle_detection.tools import demo


REPO = Path(__file__).resolve().parents[1]


def run_demo(tmp_path: Path, *args: str, timeout: float = 240.0,
             numba_cache: Path | None = None) -> subprocess.CompletedProcess:
    env = ros_env.loopback_env('test_demo', log_dir=tmp_path / 'ros_log')
    if numba_cache is not None:
        env['NUMBA_CACHE_DIR'] = str(numba_cache)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(REPO), env.get('PYTHONPATH')) if p)
    return subprocess.run(
        [sys.executable, str(REPO / 'tools' / 'demo.py'),
         '--domain-id', env['ROS_DOMAIN_ID'], *args],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=timeout)


def test_demo_end_to_end_writes_bags_and_pictures(tmp_path: Path) -> None:
    """A new user's first run: nothing in numba's cache (the kernels compile meanwhile)."""
    done = run_demo(tmp_path, '--frames', '10', '--save-every', '3',
                    numba_cache=tmp_path / 'empty_numba_cache')
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'node ready: ' in done.stdout
    out = tmp_path / 'out' / 'demo'
    assert f'everything is in {Path("out/demo")}/' in done.stdout
    assert 'depth frames sent: 10' in done.stdout
    assert 'node processing time: mean' in done.stdout
    with Reader(out / 'input_bag') as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == {
            '/kinect2/sd/image_depth_rect': 10, '/kinect2/sd/camera_info': 10,
            '/odom': 10}   # the default sequence carries its odometry
    with Reader(out / 'results_bag') as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts['/obstacles/costmap'] >= 1
    assert counts['/obstacles/points'] == counts['/obstacles/costmap']
    assert counts['/obstacles/fused_costmap'] == counts['/obstacles/costmap']
    pictures = sorted((out / 'pictures').glob('frame_*.png'))
    assert pictures, done.stdout
    picture = cv2.imread(str(pictures[0]))
    assert picture.shape[0] > 424 and picture.shape[1] > 512  # overlay + costmap + caption
    assert (picture[:30] < 100).any()  # a title in dark ink on top
    # the sheet keeps its text at full size: (up to) two thumbnails of SHEET_THUMB_PX a row
    sheet = cv2.imread(str(out / 'demo_sheet.png'))
    assert sheet.shape[1] == min(2, len(pictures)) * (demo.SHEET_THUMB_PX + 6)
    assert (out / 'node.log').read_text().count('ready:') == 1
    assert list((out / 'ros_log').glob('*.log'))  # the node's rcl log, in the output folder

    again = run_demo(tmp_path, '--frames', '2', '--save-every', '1')  # re-runnable
    assert again.returncode == 0, again.stderr
    assert len(list((out / 'pictures').glob('frame_*.png'))) <= 2


def test_demo_fails_clearly_when_the_node_does_not_run(tmp_path: Path) -> None:
    params = tmp_path / 'bad.yaml'
    params.write_text('obstacle_detector:\n  ros__parameters:\n    median_kernel: 4\n')
    done = run_demo(tmp_path, '--frames', '2', '--params', str(params))
    assert done.returncode == 1
    assert 'the detector node exited with code' in done.stderr
    assert 'median_kernel' in done.stderr  # the node's own message, from its log


def test_demo_refuses_a_folder_it_did_not_make(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    mine = tmp_path / 'mine'
    mine.mkdir()
    (mine / 'thesis.tex').write_text('keep')
    assert demo.main(['--output', str(mine), '--frames', '1']) == 1
    assert f'{mine}: exists and was not made by the demo' in capsys.readouterr().err
    assert (mine / 'thesis.tex').read_text() == 'keep'
