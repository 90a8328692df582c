"""The detector node as a child process on loopback DDS (tools/demo.py, tools/latency_bench.py)."""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from obstacle_detection.cli.support import PACKAGE_ROOT, ToolError
from obstacle_detection.ros.dds_env import CONFLICTING, loopback_env


def use_loopback(domain_id: int, log_dir: Path) -> dict[str, str]:
    """Put this process on loopback DDS in ``domain_id``; return the node's environment."""
    env = loopback_env(domain_id)
    for name in CONFLICTING:
        os.environ.pop(name, None)
    os.environ.update(env)
    path = os.pathsep.join(p for p in (str(PACKAGE_ROOT), env.get('PYTHONPATH', '')) if p)
    return dict(env, PYTHONPATH=path, PYTHONUNBUFFERED='1', RCUTILS_COLORIZED_OUTPUT='0',
                ROS_LOG_DIR=str(log_dir))


def mount_overrides(frame: Any) -> list[str]:
    """Node parameters ``name:=value`` for a rendered frame's camera mount."""
    return [f'camera_height_m:={float(frame.height_m)!r}',
            f'camera_pitch_deg:={round(math.degrees(frame.pitch_rad), 9)!r}',
            f'camera_roll_deg:={round(math.degrees(frame.roll_rad), 9)!r}']


def node_command(params: Path, overrides: Sequence[str], remaps: Sequence[str] = ()
                 ) -> list[str]:
    """Return the command that starts the node with a params file, topic remaps and overrides."""
    command = [sys.executable, '-m', 'obstacle_detection.ros.node', '--ros-args',
               '--params-file', str(params)]
    for remap in remaps:
        command += ['-r', remap]
    for item in overrides:
        command += ['-p', item]
    return command


def start_node(command: list[str], env: dict[str, str], log: Path) -> subprocess.Popen:
    """Start the node, its output into the file ``log``."""
    with log.open('w') as out:
        return subprocess.Popen(command, cwd=PACKAGE_ROOT, env=env, stdout=out,
                                stderr=subprocess.STDOUT)


def log_tail(path: Path, lines: int = 15) -> str:
    """Return the last ``lines`` lines of a log file, or ``(no log)``."""
    try:
        return '\n'.join(path.read_text(errors='replace').splitlines()[-lines:])
    except OSError:
        return '(no log)'


@contextlib.contextmanager
def probe_node(name: str, node: subprocess.Popen) -> Iterator[tuple[Any, Any, list[str]]]:
    """Yield a ROS node beside the detector ``node``: (probe, executor, status lines).

    On exit the probe is shut down and the detector stopped with Ctrl-C, as a user would.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    context = rclpy.Context()
    rclpy.init(context=context)
    probe = rclpy.create_node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe)
    status: list[str] = []
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)   # as the node's ~/status
    probe.create_subscription(String, '/obstacle_detector/status',
                              lambda msg: status.append(msg.data), latched)
    try:
        yield probe, executor, status
    finally:
        executor.shutdown()
        probe.destroy_node()
        context.try_shutdown()
        if node.poll() is None:
            node.send_signal(signal.SIGINT)
            try:
                node.wait(timeout=15)
            except subprocess.TimeoutExpired:
                node.kill()
                node.wait(timeout=5)


def wait_ready(executor: Any, node: subprocess.Popen, status: list[str], timeout_s: float,
               log: Path, ready: Callable[[str], bool] = lambda text: True) -> str:
    """Spin until the node's status says ``ready`` (and ``ready(status)``); return the status.

    ToolError with the end of ``log`` if the node exits or times out.
    """
    deadline = time.monotonic() + timeout_s
    while not (status and status[-1].startswith('ready') and ready(status[-1])):
        if node.poll() is not None or time.monotonic() > deadline:
            why = (f'exited with code {node.returncode} before it was ready'
                   if node.poll() is not None else
                   f'was not ready within {timeout_s:g} s')
            raise ToolError(log, f'the detector node {why}; the end of its '
                            'log:\n' + log_tail(log))
        executor.spin_once(timeout_sec=0.05)
    return status[-1]
