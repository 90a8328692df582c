"""Loopback-only DDS environment for tests that start rclpy in-process or in a subprocess.

Every process that calls ``rclpy.init()`` must keep DDS on 127.0.0.1: the Fast DDS profile
``obstacle_detection/ros/fastdds_loopback.xml`` under both environment variable names (the
Fast DDS 2.14 of the ROS wheels reads only the FASTRTPS one), rmw_fastrtps_cpp, and a ROS domain of
its own so that test modules and other people's runs on this machine never see each other.

Use::

    env = ros_env.loopback_env('test_node')   # dict for subprocess.Popen(env=...)
    ros_env.apply(env)                         # before rclpy.init() in this process
"""

from __future__ import annotations

import os
import shutil
import subprocess
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from obstacle_detection.ros import dds_env

REPO_ROOT = Path(__file__).resolve().parents[1]
LOOPBACK_PROFILE = dds_env.LOOPBACK_PROFILE
DOMAIN_MIN, DOMAIN_MAX = 100, 200  # inclusive; well inside Fast DDS's 0..232

_VARIABLES = ('FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE',
              'RMW_IMPLEMENTATION', 'ROS_DOMAIN_ID', 'ROS_LOCALHOST_ONLY',
              'ROS_AUTOMATIC_DISCOVERY_RANGE')


def domain_id(salt: str = '', pid: int | None = None) -> int:
    """Pick a ROS_DOMAIN_ID in [100, 200] from this process id and a per-module salt."""
    pid = os.getpid() if pid is None else pid
    key = zlib.crc32(f'{pid}:{salt}'.encode())
    return DOMAIN_MIN + key % (DOMAIN_MAX - DOMAIN_MIN + 1)


def loopback_env(salt: str = '', *, base: dict[str, str] | None = None,
                 log_dir: Path | str | None = None) -> dict[str, str]:
    """Return a full environment (``base`` or os.environ) with the loopback DDS settings.

    salt: distinguishes test modules of one process (each gets its own domain). log_dir: the
    ROS_LOG_DIR for rcl's log files (None leaves it as is). Output is unbuffered so a test can
    read a subprocess's log lines as they come.
    """
    env = dds_env.loopback_env(domain_id(salt), base)
    env.update({
        'PYTHONUNBUFFERED': '1',
        'RCUTILS_LOGGING_BUFFERED_STREAM': '0',
        'RCUTILS_COLORIZED_OUTPUT': '0',
    })
    if log_dir is not None:
        env['ROS_LOG_DIR'] = str(log_dir)
    return env


def apply(env: dict[str, str]) -> dict[str, str | None]:
    """Put the DDS variables of ``env`` into os.environ; returns the old values for restore."""
    old = {name: os.environ.get(name) for name in (*_VARIABLES, 'ROS_LOG_DIR')}
    for name in old:
        if name in env:
            os.environ[name] = env[name]
        else:
            os.environ.pop(name, None)
    return old


def restore(old: dict[str, str | None]) -> None:
    """Undo ``apply``."""
    for name, value in old.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


@contextmanager
def rclpy_context(salt: str) -> Iterator[Any]:
    """Yield an rclpy context of this process on loopback DDS, in the domain of ``salt``.

    The DDS variables are applied while it lives (restored after); rclpy's signal handlers
    are left alone, so pytest keeps its own.
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    env = loopback_env(salt)
    old = apply(env)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']),
               signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)
        restore(old)


def udp_sockets_of(pid: int) -> list[str] | None:
    """Local addresses (``ip:port``) of the UDP sockets of process ``pid``; None without ss."""
    if shutil.which('ss') is None:
        return None
    out = subprocess.run(['ss', '-uanp'], capture_output=True, text=True, check=True,
                         timeout=10).stdout
    addresses = []
    for line in out.splitlines():
        if f'pid={pid},' in line:
            columns = line.split()
            addresses.append(columns[3])  # State Recv-Q Send-Q Local:Port Peer:Port Process
    return addresses
