"""Tests of tools/latency_bench.py: the node fed through DDS by a separate camera process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import ros_env


REPO = Path(__file__).resolve().parents[1]


def test_short_run_measures_every_frame_it_sent(tmp_path: Path) -> None:
    env = ros_env.loopback_env('test_latency_bench', log_dir=tmp_path / 'ros_log')
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(REPO), env.get('PYTHONPATH')) if p)
    done = subprocess.run(
        [sys.executable, str(REPO / 'tools' / 'latency_bench.py'), '--duration', '8',
         '--rate', '10', '--set', 'median_kernel:=5',
         '--domain-id', env['ROS_DOMAIN_ID']],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    line = next(ln for ln in done.stdout.splitlines() if ln.startswith('JSON '))
    fig = json.loads(line[5:])

    assert fig['rate_hz'] == 10.0 and fig['overrides'] == ['median_kernel:=5']
    assert 25 <= fig['frames_sent'] <= 31          # 3 counted seconds at 10 Hz
    assert fig['frames_without_output'] == fig['frames_sent'] - fig['costmaps_received']
    assert fig['costmaps_received'] >= fig['frames_sent'] - 3    # 10 Hz on loopback: few drops
    latency, processing = fig['latency_ms'], fig['processing_ms']
    assert 0.0 < processing['median'] <= latency['median']   # the latency includes processing
    assert latency['median'] <= latency['p90'] <= latency['p99'] <= latency['max']
    assert fig['node_rss_mib']['end'] > 50.0
    assert '| frames without a costmap |' in done.stdout
