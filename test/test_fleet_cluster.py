"""The tools on a real Dask cluster: ``dask scheduler`` and ``dask worker`` processes (issue 32).

Every process is Dask's own command line, bound to 127.0.0.1, started in a folder of its own
(as on other machines: a relative path there is not the client's), and killed at the end of
the module. Cluster ``shared``: a scheduler and two workers that see this machine's files.
Scheduler ``bare``: no worker at first; each test then attaches the worker it needs (none, one
without obstacle_detection, one with other code, one that does not share a folder).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from obstacle_detection.cli import support as tool_support
from obstacle_detection.fleet import bags as fleet_bags
from obstacle_detection.fleet import cluster
from obstacle_detection.tools import bag_process, evaluate
from test_bag_process import output_messages
# PARAMS_YAML: conftest's params_file fixture reads it from this module
from test_fleet import PARAMS_YAML, make_bags, one_process_outputs  # noqa: F401

pytestmark = pytest.mark.integration
REPO = Path(__file__).resolve().parents[1]
DASK = Path(sys.executable).parent / 'dask'
#: Bound of every wait for a process of the cluster.
START_S = 120.0
#: sitecustomize of a worker without obstacle_detection: this venv's editable install is a
#: finder in sys.meta_path (setuptools' __editable__ module); a machine without the package
#: has none.
HIDE_PACKAGE = """\
import sys
sys.meta_path[:] = [f for f in sys.meta_path
                    if not getattr(f, '__module__', '').startswith('__editable__')]
"""


def bounded(function: Callable[[], Any], seconds: float) -> Any:
    """Return ``function()``, or fail the test when it has not returned in ``seconds``."""
    box: dict[str, Any] = {}

    def run() -> None:
        try:
            box['value'] = function()
        except BaseException as err:   # noqa: BLE001 - re-raised in the test's thread
            box['error'] = err
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f'still waiting after {seconds} s'
    if 'error' in box:
        raise box['error']
    return box.get('value')


class Processes:
    """Processes started for a test module, each in its own session; killed by ``close``."""

    def __init__(self) -> None:
        self.running: list[subprocess.Popen] = []

    def start(self, command: list[str], cwd: Path, env: dict[str, str] | None = None
              ) -> subprocess.Popen:
        cwd.mkdir(parents=True, exist_ok=True)
        process = subprocess.Popen(command, cwd=cwd, env=env, start_new_session=True,
                                   stdout=subprocess.DEVNULL,
                                   stderr=(cwd / 'log').open('w'))
        self.running.append(process)
        return process

    def stop(self, process: subprocess.Popen) -> None:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait(timeout=30)

    def close(self) -> None:
        for process in reversed(self.running):
            self.stop(process)


def start_scheduler(processes: Processes, folder: Path) -> dict[str, Any]:
    """Start ``dask scheduler`` in ``folder``; return its scheduler file's content."""
    file = folder / 'scheduler.json'
    run = processes.start([str(DASK), 'scheduler', '--host', '127.0.0.1', '--port', '0',
                           '--dashboard-address', '127.0.0.1:0', '--scheduler-file',
                           str(file)], folder)
    deadline = time.monotonic() + START_S
    while not file.is_file() or not file.read_text().strip():
        assert run.poll() is None and time.monotonic() < deadline, (folder / 'log').read_text()
        time.sleep(0.2)
    time.sleep(0.2)   # written whole
    return {**json.loads(file.read_text()), 'file': str(file)}


def start_worker(processes: Processes, scheduler: dict[str, Any], folder: Path, *,
                 env: dict[str, str] | None = None, prefix: tuple[str, ...] = ()
                 ) -> subprocess.Popen:
    """Start ``dask worker`` (one process, one thread) in ``folder`` and wait until it joined."""
    before = workers_of(scheduler)
    run = processes.start([*prefix, str(DASK), 'worker', '--host', '127.0.0.1', '--nthreads',
                           '1', '--nworkers', '1', '--scheduler-file', scheduler['file']],
                          folder, env)
    deadline = time.monotonic() + START_S
    while workers_of(scheduler) <= before:
        assert run.poll() is None and time.monotonic() < deadline, (folder / 'log').read_text()
        time.sleep(0.3)
    return run


def workers_of(scheduler: dict[str, Any]) -> int:
    """Return the number of workers the scheduler has now."""
    from distributed import Client

    with Client(scheduler['address'], timeout='30s') as client:
        return len(client.scheduler_info()['workers'])


def stop_worker(processes: Processes, scheduler: dict[str, Any], run: subprocess.Popen) -> None:
    """Stop a worker and wait until the scheduler has none."""
    processes.stop(run)
    deadline = time.monotonic() + START_S
    while workers_of(scheduler):
        assert time.monotonic() < deadline
        time.sleep(0.3)


@pytest.fixture(scope='module')
def processes() -> Iterator[Processes]:
    running = Processes()
    try:
        yield running
    finally:
        running.close()


@pytest.fixture(scope='module')
def shared(processes: Processes, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Start a scheduler and two workers, each in its own folder, that see this machine's files."""
    root = tmp_path_factory.mktemp('shared')
    scheduler = start_scheduler(processes, root / 'scheduler')
    for name in ('worker1', 'worker2'):
        start_worker(processes, scheduler, root / name)
    return scheduler


@pytest.fixture(scope='module')
def bare(processes: Processes, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Start a scheduler without workers (the tests attach theirs)."""
    return start_scheduler(processes, tmp_path_factory.mktemp('bare') / 'scheduler')


@pytest.fixture()
def quick(monkeypatch: pytest.MonkeyPatch) -> None:
    """Short waits for a scheduler's answer and a first worker."""
    monkeypatch.setattr(cluster, 'CONNECT_TIMEOUT_S', 2.0, raising=False)
    monkeypatch.setattr(cluster, 'WORKERS_TIMEOUT_S', 3.0, raising=False)


# --------------------------------------------------------------------------------------------
# Paths, the same on the client and the workers


def test_relative_paths_are_the_clients_and_the_outputs_are_reproducible(
        shared: dict[str, Any], tmp_path: Path, depths: list[np.ndarray], params_file: Path,
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    make_bags(tmp_path / 'client', depths, 3)
    monkeypatch.chdir(tmp_path / 'client')
    code = bag_process.main(['bags', 'out', '--params-file', str(params_file), '--quiet',
                             '--scheduler', shared['address']])
    out, err = capsys.readouterr()
    assert code == 0, out + err
    assert '3 ok, 0 failed' in out
    assert f'3 bags on the Dask cluster at {shared["address"]} (2 workers)' in err
    assert 'warming up 2 workers' in err and 'workers warm in' in err
    for worker in ('worker1', 'worker2'):   # nothing landed in a worker's own folder
        assert not (Path(shared['file']).parents[1] / worker / 'out').exists()
    bags = sorted((tmp_path / 'client' / 'bags').iterdir())
    want = one_process_outputs(tmp_path, bags, params_file)   # tmp_path/single/<bag>
    for bag in bags:
        assert output_messages(tmp_path / 'client' / 'out' / bag.name) == want[bag.name]
        # the same bag files, byte for byte, from another process and worker
        for file in (tmp_path / 'single' / bag.name).iterdir():
            got = tmp_path / 'client' / 'out' / bag.name / file.name
            assert hashlib.sha256(got.read_bytes()).digest() == \
                hashlib.sha256(file.read_bytes()).digest(), got


# --------------------------------------------------------------------------------------------
# Addresses that are not a scheduler: one line, in a bounded time


def test_the_dashboard_port_is_named_for_what_it_is(shared: dict[str, Any], quick: None
                                                    ) -> None:
    dashboard = f'tcp://127.0.0.1:{shared["services"]["dashboard"]}'   # the 8787 typo

    def connect() -> None:
        with cluster.open_fleet(scheduler=dashboard):
            pass
    with pytest.raises(tool_support.ToolError, match=rf'{dashboard}: is a web server \(HTTP\), '
                                                     'not a Dask scheduler: 8787 is usually'):
        bounded(connect, 60)


def test_a_listener_that_never_answers_is_refused_in_bounded_time(quick: None) -> None:
    with socket.create_server(('127.0.0.1', 0)) as server:
        accepted: list[socket.socket] = []
        threading.Thread(target=lambda: accepted.append(server.accept()[0]),
                         daemon=True).start()
        address = f'tcp://127.0.0.1:{server.getsockname()[1]}'

        def connect() -> None:
            with cluster.open_fleet(scheduler=address):
                pass
        with pytest.raises(tool_support.ToolError, match=f'{address}: accepts connections but '
                                                         'says nothing in 2 s'):
            bounded(connect, 60)
        for sock in accepted:
            sock.close()


def test_tls_without_settings_is_one_line(shared: dict[str, Any],
                                          capsys: pytest.CaptureFixture[str]) -> None:
    address = shared['address'].replace('tcp://', 'tls://')
    assert bounded(lambda: evaluate.main(['--scene', 'corridor', '--max-frames', '1',
                                          '--scheduler', address]), 60) == 1
    err = capsys.readouterr().err
    assert err == (f"error: {address}: tls:// needs Dask's TLS settings: "
                   'distributed.comm.tls.ca-file, distributed.comm.tls.client.cert and .key in '
                   'its configuration (~/.config/dask/*.yaml or '
                   'DASK_DISTRIBUTED__COMM__TLS__CA_FILE, ...)\n')


# --------------------------------------------------------------------------------------------
# evaluate's other modes on the cluster


def test_evaluate_sequence_runs_on_the_scheduler_given(shared: dict[str, Any], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    common = ['--sequence', 'person_crossing', '--frames', '3', '--quiet']
    assert evaluate.main([*common, '--json', str(tmp_path / 'one.json'), '--workers', '0']) == 0
    capsys.readouterr()
    assert evaluate.main([*common, '--json', str(tmp_path / 'dask.json'), '--scheduler',
                          shared['address']]) == 0
    assert 'workers warm in' in capsys.readouterr().err

    def scores(path: Path) -> dict:
        data = json.loads(path.read_text())
        for sequence in data['sequences']:   # times differ between runs
            sequence.pop('fusion_ms', None)
            sequence.pop('pipeline_ms', None)
        return data
    assert scores(tmp_path / 'dask.json') == scores(tmp_path / 'one.json')
    assert evaluate.main([*common, '--scheduler', 'tcp://127.0.0.1:9']) == 1
    assert 'no Dask scheduler answers' in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# Workers that cannot run the tasks


def test_a_scheduler_without_workers_is_said_in_bounded_time(bare: dict[str, Any],
                                                             quick: None) -> None:
    def connect() -> None:
        with cluster.open_fleet(scheduler=bare['address']):
            pass
    with pytest.raises(tool_support.ToolError, match=rf'{bare["address"]}: the scheduler has no '
                                                     r'workers \(none joined in 3 s\)'):
        bounded(connect, 60)


def hidden_package_env(folder: Path, package_copy: Path | None = None) -> dict[str, str]:
    """Return the environment of a worker that cannot import this checkout's package.

    ``package_copy``: a folder whose obstacle_detection it imports instead.
    """
    folder.mkdir(parents=True, exist_ok=True)
    (folder / 'sitecustomize.py').write_text(HIDE_PACKAGE)
    path = [str(folder)] + ([str(package_copy)] if package_copy else [])
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join(path)}
    check = subprocess.run([sys.executable, '-c', 'import obstacle_detection as p; '
                            'print(p.__file__)'], cwd=folder, env=env, capture_output=True,
                           text=True, timeout=60, check=False)
    if package_copy is None:   # the premise: this environment has no obstacle_detection
        assert 'No module named' in check.stderr, check.stdout
    else:
        assert check.stdout.startswith(str(package_copy)), check.stderr
    return env


def test_a_worker_without_the_package_is_named_not_waited_for(
        bare: dict[str, Any], processes: Processes, tmp_path: Path, depths: list[np.ndarray],
        capsys: pytest.CaptureFixture[str]) -> None:
    run = start_worker(processes, bare, tmp_path / 'worker',
                       env=hidden_package_env(tmp_path / 'hide'))
    try:
        folder = make_bags(tmp_path, depths, 2)
        code = bounded(lambda: bag_process.main([str(folder), str(tmp_path / 'out'),
                                                 '--scheduler', bare['address']]), 120)
        err = capsys.readouterr().err
        assert code == 1
        assert err.startswith('error: the workers must run the obstacle_detection of this '
                              'machine, ') and err.count('\n') == 1
        assert "cannot import obstacle_detection (ModuleNotFoundError: No module named " \
               "'obstacle_detection')" in err
        assert not (tmp_path / 'out').exists()
    finally:
        stop_worker(processes, bare, run)


def test_a_worker_with_other_code_is_named(bare: dict[str, Any], processes: Processes,
                                           tmp_path: Path) -> None:
    copy = tmp_path / 'other' / 'obstacle_detection'
    shutil.copytree(REPO / 'obstacle_detection', copy,
                    ignore=shutil.ignore_patterns('__pycache__', '*.nbi', '*.nbc'))
    (copy / 'labels.py').write_text((copy / 'labels.py').read_text() + '\n# another version\n')
    run = start_worker(processes, bare, tmp_path / 'worker',
                       env=hidden_package_env(tmp_path / 'hide', tmp_path / 'other'))
    try:
        def connect() -> None:
            with cluster.open_fleet(scheduler=bare['address']):
                pass
        with pytest.raises(tool_support.ToolError) as caught:
            bounded(connect, 120)
        assert f'in {copy}' in str(caught.value) and '(source ' in str(caught.value)
    finally:
        stop_worker(processes, bare, run)


def unshared_prefix(folder: Path) -> tuple[str, ...]:
    """Return a command prefix: the process gets its own empty ``folder`` (a tmpfs over it).

    Skips the test where unprivileged mount namespaces are not allowed.
    """
    prefix = ('unshare', '--map-root-user', '--mount', 'sh', '-c',
              f'mount -t tmpfs none {folder} && exec "$0" "$@"')
    if shutil.which('unshare') is None or subprocess.run(
            [*prefix, 'true'], capture_output=True, timeout=30, check=False).returncode:
        pytest.skip('no mount namespaces here (unshare)')
    return prefix


def test_a_worker_that_does_not_share_the_output_folder_fails_loudly(
        bare: dict[str, Any], processes: Processes, tmp_path: Path, depths: list[np.ndarray],
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / 'results').mkdir()
    run = start_worker(processes, bare, tmp_path / 'worker',
                       prefix=unshared_prefix(tmp_path / 'results'))
    try:
        folder = make_bags(tmp_path, depths, 2)
        out = tmp_path / 'results' / 'out'
        argv = [str(folder), str(out), '--quiet', '--scheduler', bare['address']]
        assert bounded(lambda: bag_process.main(argv), 120) == 1
        err = capsys.readouterr().err
        assert f'does not see the output folder {out}: the workers must see the bags and the ' \
               'output folder at the same paths as this machine' in err
        assert not out.exists()
        # were the check passed (a worker that joined later), the outputs are checked after
        monkeypatch.setattr(fleet_bags, 'check_shared_files', lambda fleet, jobs: None)
        assert bounded(lambda: bag_process.main(argv), 120) == 1
        report = capsys.readouterr().out
        assert '0 ok, 2 failed' in report
        assert f'wrote {out / "bag0"}, but this machine does not see it there' in report
    finally:
        stop_worker(processes, bare, run)


def test_a_cluster_that_loses_its_last_worker_stops_the_run(
        bare: dict[str, Any], processes: Processes, tmp_path: Path, depths: list[np.ndarray],
        quick: None, capsys: pytest.CaptureFixture[str]) -> None:
    run = start_worker(processes, bare, tmp_path / 'worker')
    try:
        folder = make_bags(tmp_path, depths, 2, repeat=20)   # 60 frames a bag
        out = tmp_path / 'out'
        result: list[int] = []
        tool = threading.Thread(target=lambda: result.append(bag_process.main(
            [str(folder), str(out), '--quiet', '--scheduler', bare['address']])), daemon=True)
        tool.start()
        deadline = time.monotonic() + START_S
        while not (out.exists() and list(out.glob('.*.partial'))):   # a bag being written
            assert tool.is_alive() and time.monotonic() < deadline, capsys.readouterr()
            time.sleep(0.05)
        os.killpg(run.pid, signal.SIGKILL)   # the machine is lost: worker and nanny
        tool.join(120)
        assert not tool.is_alive(), 'still waiting for a worker'
        assert result == [1]
        err = capsys.readouterr().err
        assert re.fullmatch(rf'error: the Dask cluster at {bare["address"]} \(1 worker\): no '
                            r'worker left for 3 s with [12] tasks to run; the run stops',
                            err.splitlines()[-1]), err
        assert 'Traceback' not in err
        assert not list(out.glob('.*.partial'))
    finally:
        stop_worker(processes, bare, run)
