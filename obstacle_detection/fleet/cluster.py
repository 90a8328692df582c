"""Open a Dask cluster (or none) and run a list of tasks on it, in order (docs/fleet.md)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import importlib.util
import io
import logging
import os
import socket
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.progress import Progress
from . import probe

#: Whether dask.distributed can be imported (the optional ``fleet`` extra).
DASK_AVAILABLE = importlib.util.find_spec('distributed') is not None
#: The environment of a local cluster's worker processes: one thread per worker. Not
#: NUMBA_NUM_THREADS: a worker's environment is not yet set when numba reads it, and numba
#: refuses to compile once the two differ; limit_threads sets numba's count instead.
ONE_THREAD_ENV = {'OMP_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1'}


@dataclasses.dataclass
class Fleet:
    """Where tasks run: a Dask client, or None for this process; ``description`` says which."""

    client: Any
    description: str
    workers: int
    remote: bool = False   # a cluster of --scheduler (not this machine's)

    @property
    def distributed(self) -> bool:
        """True when tasks run on a Dask cluster."""
        return self.client is not None

    def submit(self, function: Callable[..., Any], *args: Any) -> Any:
        """Start ``function(*args)`` on the cluster; return its future."""
        return self.client.submit(function, *args, pure=False)


def add_fleet_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--workers`` and ``--scheduler``."""
    group = parser.add_argument_group(
        'where the work runs (Dask, optional: README, Offline work at scale)')
    group.add_argument('--workers', type=tool_support.int_in(0), metavar='N',
                       help='a local Dask cluster of N worker processes (one thread each); '
                            '0 = this process, no Dask [default: one per core when Dask is '
                            'installed and the work pays for starting them, else this '
                            'process; the first line says which]')
    group.add_argument('--scheduler', metavar='ADDRESS',
                       help='run on the Dask cluster of this scheduler, e.g. tcp://host:8786 '
                            '(its workers must see the files at the same paths)')


def fleet_options(args: argparse.Namespace) -> dict[str, Any]:
    """Return the keyword arguments of :func:`open_fleet` from the parsed fleet options."""
    return {'workers': args.workers, 'scheduler': args.scheduler}


#: ``--scheduler``: seconds for the scheduler's first answer, then for a first worker to join.
CONNECT_TIMEOUT_S = 10.0
WORKERS_TIMEOUT_S = 30.0
#: Seconds a worker may take to warm up: a cold numba cache compiles for about a minute.
WARM_TIMEOUT_S = 600.0
#: A warm-up longer than this compiled the kernels (a cold cache), rather than loading them.
COLD_WARM_UP_S = 5.0
#: Seconds a local cluster of 2 workers takes to start and warm up, beyond one process
#: (measured on the 2-core machine: docs/fleet.md, One process or a cluster).
LOCAL_CLUSTER_START_S = 4.0


def local_cluster_pays(work_s: float, workers: int) -> bool:
    """Whether ``workers`` local workers finish ``work_s`` seconds of one-process work first.

    One process takes ``work_s``; the cluster about its start plus ``work_s / workers``.
    """
    return workers >= 2 and work_s * (1.0 - 1.0 / workers) > LOCAL_CLUSTER_START_S


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


@contextlib.contextmanager
def open_fleet(*, workers: int | None = None, scheduler: str | None = None,
               tasks: int = 2, work_s: float | None = None,
               log: Callable[[str], None] = _stderr) -> Iterator[Fleet]:
    """Yield where to run ``tasks`` tasks; close it afterwards.

    Without ``workers`` or ``scheduler``: a local cluster when it pays for ``work_s`` seconds of
    one-process work (:func:`local_cluster_pays`; None: it pays), else this process. A cluster's
    workers are checked (the same obstacle_detection) and warmed up, each step said by ``log``.
    Raises ToolError for a cluster that cannot be used, or ``workers`` and ``scheduler`` both.
    """
    if scheduler is not None and workers is not None:
        raise tool_support.ToolError('--workers starts a local cluster, --scheduler uses '
                                     'another one: give one of them')
    wanted = scheduler is not None or (workers is not None and workers > 0)
    if wanted and not DASK_AVAILABLE:
        what = f'--scheduler {scheduler}' if scheduler else f'--workers {workers}'
        raise tool_support.ToolError(
            f"{what} needs dask.distributed, which is not installed: pip install "
            f"'dask[distributed]' (or pip install .[fleet]), or leave out --workers/--scheduler "
            'to run in this process')
    cores = len(os.sched_getaffinity(0))
    if not wanted and (reason := _why_this_process(workers, tasks, cores, work_s)) is not None:
        yield Fleet(None, f'this process ({reason})' if reason else 'this process', 1)
        return
    import dask
    from distributed import Client, LocalCluster

    # glibc's own mmap threshold, no profiler, slower ticks: docs/fleet.md, Speed
    with dask.config.set({'distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_': None,
                          'distributed.worker.profile.enabled': False,
                          'distributed.admin.tick.interval': '500ms'}):
        if scheduler is not None:
            with _connect(scheduler) as client:
                count = len(client.scheduler_info().get('workers', {}))
                fleet = Fleet(client, f'the Dask cluster at {scheduler} ({count} worker'
                                      f'{"s" if count != 1 else ""})', count, remote=True)
                prepare_workers(fleet, log)
                yield fleet
            return
        count = workers if workers is not None else cores
        why = '' if workers is not None or work_s is None else f'; about {work_s:.0f} s of work'
        # the workers ignore Ctrl-C (worker_setup): this process alone stops the run
        with LocalCluster(
                n_workers=count, threads_per_worker=1, processes=True, host='127.0.0.1',
                dashboard_address='127.0.0.1:0', env=dict(ONE_THREAD_ENV),
                silence_logs=logging.CRITICAL,
                preload=['obstacle_detection.fleet.worker_setup']) as cluster, \
                Client(cluster) as client:
            fleet = Fleet(client, f'a local Dask cluster of {count} worker process'
                          f'{"es" if count != 1 else ""} (1 thread each{why})', count)
            prepare_workers(fleet, log)
            yield fleet


def _why_this_process(workers: int | None, tasks: int, cores: int, work_s: float | None
                      ) -> str | None:
    """Say why the tasks run in this process ('' for --workers 0), or None: a local cluster."""
    if workers == 0:
        return ''
    if not DASK_AVAILABLE:
        return 'dask.distributed is not installed'
    if tasks < 2:
        return 'one task'
    if cores < 2:
        return 'one core'
    if work_s is not None and not local_cluster_pays(work_s, cores):
        return (f'about {work_s:.0f} s of work: a local cluster of {cores} workers would not '
                f'pay its start-up of about {LOCAL_CLUSTER_START_S:.0f} s')
    return None


def probe_scheduler(address: str, timeout: float | None = None) -> None:
    """Check that a Dask scheduler answers at ``address`` (``tcp://`` or ``tls://``).

    Dask's client waits for ever for the first message of a listener that accepts and never
    speaks (a dashboard's HTTP port, a stuck process): a scheduler sends its handshake at once,
    so this waits ``timeout`` s (CONNECT_TIMEOUT_S) for it. Raises ToolError saying what
    answers instead.
    """
    timeout = CONNECT_TIMEOUT_S if timeout is None else timeout
    scheme, sep, rest = address.rpartition('://')
    scheme = scheme if sep else 'tcp'
    host, _, port = rest.rpartition(':')
    host = host.strip('[]')
    if scheme not in ('tcp', 'tls'):
        raise tool_support.ToolError(address, f'{scheme}:// is not supported: give the '
                                              "scheduler's tcp:// (or tls://) address")
    if not host or not port.isdigit():
        raise tool_support.ToolError(address, 'not a scheduler address: expected tcp://HOST:PORT, '
                                              'e.g. tcp://head:8786')
    try:
        sock = socket.create_connection((host, int(port)), timeout=timeout)
    except OSError as err:
        raise tool_support.ToolError(address, f'no Dask scheduler answers ({err})') from err
    with sock:
        if scheme == 'tls':
            return   # the TLS handshake needs Dask's certificates: the client checks it
        sock.settimeout(timeout)
        try:
            head = sock.recv(8)
        except OSError:
            head = None
    if head and len(head) == 8 and 0 < int.from_bytes(head, 'little') < 2**32:
        return   # the length of Dask's first message
    if _speaks_http(host, int(port), timeout):
        what = ("is a web server (HTTP), not a Dask scheduler: 8787 is usually the Dask "
                "dashboard, the scheduler's address is the one 'dask scheduler' prints, "
                'tcp://HOST:8786 by default')
    elif head is None:
        what = (f'accepts connections but says nothing in {timeout:.0f} s: not a Dask '
                'scheduler (a scheduler greets at once)')
    else:
        what = f'answers, but not as a Dask scheduler (it sent {head!r})'
    raise tool_support.ToolError(address, what)


def _speaks_http(host: str, port: int, timeout: float) -> bool:
    """Whether ``host:port`` answers an HTTP request."""
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            sock.settimeout(timeout)
            sock.sendall(b'HEAD / HTTP/1.0\r\n\r\n')
            return sock.recv(5) == b'HTTP/'
    except OSError:
        return False


@contextlib.contextmanager
def _connect(scheduler: str) -> Iterator[Any]:
    """Yield a client of the scheduler at ``scheduler`` with at least one worker (ToolError)."""
    import dask
    from distributed import Client

    probe_scheduler(scheduler)
    if scheduler.startswith('tls://') and not dask.config.get('distributed.comm.tls.ca-file',
                                                              None):
        raise tool_support.ToolError(
            scheduler, "tls:// needs Dask's TLS settings: distributed.comm.tls.ca-file, "
                       'distributed.comm.tls.client.cert and .key in its configuration '
                       '(~/.config/dask/*.yaml or DASK_DISTRIBUTED__COMM__TLS__CA_FILE, ...)')
    try:
        client = Client(scheduler, timeout=f'{CONNECT_TIMEOUT_S}s')
    except (OSError, TimeoutError, TypeError, ValueError) as err:
        raise tool_support.ToolError(scheduler, f'no Dask scheduler answers ({err})') from err
    with client:
        try:
            client.wait_for_workers(1, timeout=WORKERS_TIMEOUT_S)
        except TimeoutError:
            raise tool_support.ToolError(
                scheduler, f'the scheduler has no workers (none joined in '
                           f'{WORKERS_TIMEOUT_S:.0f} s): start some with dask worker '
                           f'{scheduler}') from None
        yield client


def prepare_workers(fleet: Fleet, log: Callable[[str], None] = _stderr) -> None:
    """Check that every worker runs this obstacle_detection, then warm each up once.

    A worker without the package would die unpickling its first task while the client waits;
    a worker with other code would give other results; a cold numba cache compiles for about
    a minute in the first task. ToolError names the workers that differ.
    """
    from distributed import wait

    client = fleet.client   # probe's functions travel by value: they run without the package
    facts = client.run(probe.package_facts, on_error='return')
    mine = probe.package_facts()
    wrong = []
    if fleet.remote:   # Dask's scheduler unpickles the tasks too
        facts['the scheduler'] = client.run_on_scheduler(probe.package_facts)
    for address, theirs in sorted(facts.items()):
        if isinstance(theirs, BaseException):
            wrong.append(f'{address} does not answer ({type(theirs).__name__}: {theirs})')
        elif 'error' in theirs:
            wrong.append(f'{address} cannot import obstacle_detection ({theirs["error"]})')
        elif (theirs['version'], theirs['digest']) != (mine['version'], mine['digest']):
            wrong.append(f'{address} has obstacle_detection {theirs["version"]} '
                         f'(source {theirs["digest"]}, in {theirs["where"]})')
    if wrong:
        raise tool_support.ToolError(
            f'the workers must run the obstacle_detection of this machine, '
            f'{mine["version"]} (source {mine["digest"]}): ' + '; '.join(wrong) +
            '. Install it in the workers\' environment (pip install <this checkout>) and '
            'restart them')
    addresses = sorted(set(facts) - {'the scheduler'})
    log(f'warming up {len(addresses)} worker{"s" if len(addresses) != 1 else ""} (numba '
        'kernels: loaded from their cache, or compiled once where it is cold, about a '
        'minute)...')
    futures = {address: client.submit(warm_worker, workers=[address], allow_other_workers=True,
                                      pure=False) for address in addresses}
    try:
        wait(list(futures.values()), timeout=WARM_TIMEOUT_S)
    except TimeoutError:
        raise tool_support.ToolError(f'the workers did not warm up in {WARM_TIMEOUT_S:.0f} s') \
            from None
    seconds = {address: future.result() for address, future in futures.items()}
    cold = [f'{address} compiled them ({s:.0f} s: its cache was cold; kept for next time)'
            for address, s in seconds.items() if s > COLD_WARM_UP_S]
    log(f'workers warm in {max(seconds.values()):.1f} s' + ('; ' + '; '.join(cold) if cold
                                                             else ''))


def warm_worker() -> float:
    """Load or compile this worker's numba kernels (a task); return the seconds."""
    from obstacle_detection.pipeline.detector import Detector

    limit_threads()
    return Detector().warm_up()


def limit_threads() -> None:
    """Run this task on one thread: numba's parallel kernels and OpenCV (see the module)."""
    import cv2

    cv2.setNumThreads(1)
    if importlib.util.find_spec('numba') is not None:
        import numba

        numba.set_num_threads(1)


@dataclasses.dataclass
class TaskError:
    """A task that failed for good (``return_errors``): why, and its exception."""

    reason: str
    error: BaseException | None = dataclasses.field(default=None, compare=False)


#: Seconds between two looks at a cluster's workers while its tasks run.
WATCH_S = 2.0


def _as_completed(fleet: Fleet, futures: Sequence[Any]) -> Iterator[Any]:
    """Yield ``futures`` as they complete; ToolError when the cluster keeps no worker.

    Dask keeps the tasks of a cluster whose every worker left waiting for a new one, for ever;
    after WORKERS_TIMEOUT_S without a worker this stops the run instead.
    """
    from distributed import wait

    order = {future.key: index for index, future in enumerate(futures)}
    pending, alone_since = set(futures), None
    while pending:
        try:
            done, pending = wait(pending, timeout=WATCH_S, return_when='FIRST_COMPLETED')
        except TimeoutError:
            if fleet.client.scheduler_info().get('workers'):
                alone_since = None
            elif alone_since is None:
                alone_since = time.monotonic()
            elif time.monotonic() - alone_since > WORKERS_TIMEOUT_S:
                raise tool_support.ToolError(
                    f'{fleet.description}: no worker left for {WORKERS_TIMEOUT_S:.0f} s with '
                    f'{len(pending)} tasks to run; the run stops') from None
            continue
        yield from sorted(done, key=lambda future: order[future.key])


def run_tasks(fleet: Fleet, function: Callable[..., Any], items: Sequence[tuple[Any, ...]],
              *, label: str, progress: bool = True, return_errors: bool = False) -> list[Any]:
    """Return ``[function(*item) for item in items]``, computed where ``fleet`` says.

    A task that fails raises, or with ``return_errors`` gives a :class:`TaskError` instead.
    """
    results: list[Any] = [None] * len(items)
    futures: list[Any] = []
    if fleet.distributed:
        futures = [fleet.submit(function, *item) for item in items]
        position = {future.key: index for index, future in enumerate(futures)}
        done = ((position[future.key], future.result)
                for future in _as_completed(fleet, futures))
    else:
        done = ((index, functools.partial(function, *item)) for index, item in enumerate(items))
    with Progress(len(items), label, stream=None if progress else io.StringIO()) as bar:
        try:
            for index, result in done:
                try:
                    results[index] = result()
                except Exception as err:   # noqa: BLE001 - the task's failure
                    if not return_errors:
                        raise
                    results[index] = TaskError(f'{type(err).__name__}: {err}', err)
                bar.update()
        except BaseException:
            if futures:
                fleet.client.cancel(futures)
            raise
    return results

