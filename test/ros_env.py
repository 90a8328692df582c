"""Loopback-only DDS environment for tests that start rclpy in-process or in a subprocess.

Every process that calls ``rclpy.init()`` must keep DDS on 127.0.0.1: the Fast DDS profile
``obstacle_detection/ros/fastdds_loopback.xml`` under both environment variable names (the
Fast DDS 2.14 of the ROS wheels reads only the FASTRTPS one), rmw_fastrtps_cpp, and a ROS domain of
its own so that test modules and other people's runs on this machine never see each other.

Use::

    env = ros_env.loopback_env('test_node')   # dict for subprocess.Popen(env=...)
    ros_env.apply(env)                         # before rclpy.init() in this process

:class:`NodeProcess` runs the detector node as a process with a probe node in this one.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import zlib
from collections.abc import Callable, Iterator
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
def rclpy_context(salt: str, args: list[str] | None = None) -> Iterator[Any]:
    """Yield an rclpy context of this process on loopback DDS, in the domain of ``salt``.

    args: the command line rcl parses (``--ros-args`` ...), as a node's process gets it. The
    DDS variables are applied while it lives (restored after, also when rcl refuses the
    arguments); rclpy's signal handlers are left alone, so pytest keeps its own.
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    env = loopback_env(salt)
    old = apply(env)
    context = rclpy.Context()
    try:
        rclpy.init(args=args, context=context, domain_id=int(env['ROS_DOMAIN_ID']),
                   signal_handler_options=SignalHandlerOptions.NO)
        yield context
    finally:
        rclpy.try_shutdown(context=context)
        restore(old)


def sent(node: Any, topic: str, monkeypatch: Any) -> list[Any]:
    """Return the list the messages ``node`` publishes on ``topic`` (resolved) now go to."""
    messages: list[Any] = []
    publisher = next(p for p in node.publishers if p.topic_name == topic)
    monkeypatch.setattr(publisher, 'publish', messages.append)
    return messages


def deliver(node: Any, topic: str, msg: Any) -> None:
    """Hand ``msg`` to ``node``'s subscription on ``topic`` (resolved), as its executor would."""
    next(s for s in node.subscriptions if s.topic_name == topic).callback(msg)


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


def detector_command() -> list[str]:
    """Return the venv's ``detector`` console script (``pip install -e .``), else ``python -m``."""
    script = Path(sys.executable).with_name('detector')
    if script.is_file():
        return [str(script)]
    found = shutil.which('detector')
    return [found] if found else [sys.executable, '-m', 'obstacle_detection.ros.node']


def run_detector(tmp: Path, *args: str, salt: str) -> subprocess.CompletedProcess:
    """Run ``detector *args`` to its end on loopback DDS (domain of ``salt``), output captured."""
    env = loopback_env(salt, log_dir=tmp / 'ros_log')
    return subprocess.run(detector_command() + list(args), env=env, cwd=tmp,
                          capture_output=True, text=True, timeout=60, check=False)


def stamp_key(stamp: Any) -> tuple[int, int]:
    """(sec, nanosec) of a builtin_interfaces/Time: a dict key."""
    return (stamp.sec, stamp.nanosec)


class NodeProcess:
    """The detector node as a process on loopback DDS, its log, and a probe node here.

    The probe (``node``, spun by ``executor``) lives in an rclpy context of this process in
    the node's ROS domain (of ``salt``); a subclass adds its publishers and subscriptions,
    then :meth:`start` runs the node with its arguments. :meth:`close` stops both and writes
    the node's output to ``tmp/detector.log`` for a post-mortem.
    """

    def __init__(self, tmp: Path, salt: str, probe_name: str, *,
                 extra_env: dict[str, str] | None = None, spin_step_s: float = 0.05) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.tmp = tmp
        self.env = loopback_env(salt, log_dir=tmp / 'ros_log')
        self.env.update(extra_env or {})
        self._old_env = apply(self.env)
        self.spin_step_s = spin_step_s
        self.process: subprocess.Popen | None = None
        self.lines: list[str] = []
        self.received: dict[str, dict[tuple[int, int], Any]] = {}
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(self.env['ROS_DOMAIN_ID']),
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(probe_name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._next_sec = 100

    def start(self, args: list[str]) -> None:
        """Start ``detector *args``; its output lines collect in ``lines``."""
        self.process = subprocess.Popen(detector_command() + args, env=self.env, cwd=self.tmp,
                                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                        text=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.process.stdout:
            self.lines.append(line)

    def by_stamp(self, key: str, msg_type: type, topic: str, qos: Any) -> Any:
        """Subscribe to ``topic``: its messages go to ``received[key][stamp_key(stamp)]``."""
        store = self.received.setdefault(key, {})
        return self.node.create_subscription(
            msg_type, topic, lambda msg: store.__setitem__(stamp_key(msg.header.stamp), msg),
            qos)

    def log(self, start: int = 0) -> str:
        return ''.join(self.lines[start:])

    def spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        """Spin the probe until ``done()``, the deadline or the node's end (no blind sleep)."""
        deadline = time.monotonic() + timeout
        while not done():
            ended = self.process is not None and self.process.poll() is not None
            if time.monotonic() > deadline or ended:
                return done()
            self.executor.spin_once(timeout_sec=self.spin_step_s)
        return True

    def wait_for_log(self, text: str, start: int = 0, timeout: float = 20.0) -> bool:
        return self.spin_until(lambda: text in self.log(start), timeout)

    def call(self, client: Any, request: Any, timeout: float = 30.0) -> Any:
        """Call a service of the node; its reply."""
        assert self.spin_until(client.service_is_ready, timeout), self.log()
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), 'no reply from the node'
        return future.result()

    def next_stamp(self) -> Any:
        from builtin_interfaces.msg import Time

        self._next_sec += 1
        return Time(sec=self._next_sec, nanosec=250)

    def close(self) -> None:
        import rclpy

        try:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
            rclpy.try_shutdown(context=self.context)
        finally:
            if self.process is not None:
                if self.process.poll() is None:
                    self.process.send_signal(signal.SIGINT)
                    try:
                        self.process.wait(timeout=15)
                    except subprocess.TimeoutExpired:
                        self.process.kill()
                        self.process.wait(timeout=10)
                self._reader.join(timeout=5)
                (self.tmp / 'detector.log').write_text(self.log())
            restore(self._old_env)
