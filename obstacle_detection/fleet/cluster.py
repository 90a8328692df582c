"""Open a Dask cluster (or none) and run a list of tasks on it, in order (docs/fleet.md)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib.util
import io
import logging
import os
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.progress import Progress

#: Whether dask.distributed can be imported (the optional ``fleet`` extra).
DASK_AVAILABLE = importlib.util.find_spec('distributed') is not None
#: The environment variable Dask itself reads for the scheduler's address.
SCHEDULER_ENV = 'DASK_SCHEDULER_ADDRESS'
#: Retries of a task that raised (a worker that died is restarted by Dask, see the module).
DEFAULT_RETRIES = 2
#: How often the scheduler restarts a task whose worker died before giving up on it.
ALLOWED_FAILURES = 3
#: The environment of a local cluster's worker processes: one thread per worker.
ONE_THREAD_ENV = {'NUMBA_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1',
                  'OPENBLAS_NUM_THREADS': '1'}
INSTALL_HINT = "pip install 'dask[distributed]' (or pip install .[fleet])"


class FleetError(ValueError):
    """The cluster asked for cannot be used (Dask missing, no scheduler at the address)."""


@dataclasses.dataclass
class Fleet:
    """Where tasks run: a Dask client, or None for this process; ``description`` says which."""

    client: Any
    description: str
    workers: int
    retries: int = DEFAULT_RETRIES

    @property
    def distributed(self) -> bool:
        """True when tasks run on a Dask cluster."""
        return self.client is not None


def usable_cores() -> int:
    """CPUs this process may run on."""
    if hasattr(os, 'sched_getaffinity'):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def add_fleet_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--workers``, ``--scheduler`` and ``--retries``."""
    group = parser.add_argument_group(
        'where the work runs (Dask, optional: README, Offline work at scale)')
    group.add_argument('--workers', type=tool_support.int_in(0), metavar='N',
                       help='a local Dask cluster of N worker processes (one thread each); '
                            '0 = this process, no Dask [default: one per core when Dask is '
                            'installed and there is more than one task]')
    group.add_argument('--scheduler', metavar='ADDRESS',
                       help=f'run on the Dask cluster of this scheduler, e.g. '
                            f'tcp://host:8786 [default: ${SCHEDULER_ENV} if set]')
    group.add_argument('--retries', type=tool_support.int_in(0), default=DEFAULT_RETRIES,
                       metavar='N',
                       help='retries of a task that raised [default: %(default)s]; a task '
                            'whose worker died is restarted by Dask')


def fleet_options(args: argparse.Namespace) -> dict[str, Any]:
    """Return the keyword arguments of :func:`open_fleet` from the parsed fleet options."""
    return {'workers': args.workers, 'scheduler': args.scheduler, 'retries': args.retries}


@contextlib.contextmanager
def open_fleet(*, workers: int | None = None, scheduler: str | None = None,
               retries: int = DEFAULT_RETRIES, tasks: int = 2) -> Iterator[Fleet]:
    """Yield where to run ``tasks`` tasks; close it afterwards.

    Raises FleetError when Dask is missing or the scheduler cannot be reached for a cluster asked
    for, or for ``workers`` and ``scheduler`` together.
    """
    if scheduler is not None and workers is not None:
        raise FleetError('--workers starts a local cluster, --scheduler uses another one: '
                         'give one of them')
    if scheduler is None and workers is None:
        scheduler = os.environ.get(SCHEDULER_ENV) or None
    wanted = scheduler is not None or (workers is not None and workers > 0)
    if wanted and not DASK_AVAILABLE:
        what = f'--scheduler {scheduler}' if scheduler else f'--workers {workers}'
        raise FleetError(f'{what} needs dask.distributed, which is not installed: '
                         f'{INSTALL_HINT}, or leave out --workers/--scheduler (and unset '
                         f'{SCHEDULER_ENV}) to run in this process')
    if not wanted and (workers == 0 or not DASK_AVAILABLE or tasks < 2
                       or usable_cores() < 2):
        yield Fleet(None, 'this process', 1, retries)
        return
    import dask
    from distributed import Client, LocalCluster

    # Dask's default MALLOC_TRIM_THRESHOLD_ for its workers fixes glibc's mmap threshold at
    # 128 kB: every frame-sized array is then mapped and unmapped anew, and its page faults
    # made a worker's frames ~50 % slower than one process's here. Workers keep glibc's default.
    # The workers' statistical profiler samples the running task's stack every 10 ms and the
    # event loops tick every 20 ms: CPU taken from the frames, for nothing a batch run reads.
    with dask.config.set({'distributed.scheduler.allowed-failures': ALLOWED_FAILURES,
                          'distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_': None,
                          'distributed.worker.profile.enabled': False,
                          'distributed.admin.tick.interval': '500ms'}):
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout='10s')
            except (OSError, TimeoutError) as err:
                raise FleetError(f'{scheduler}: no Dask scheduler answers ({err})') from err
            with client:
                count = len(client.scheduler_info().get('workers', {}))
                yield Fleet(client, f'the Dask cluster at {scheduler} ({count} workers)',
                            count, retries)
            return
        count = workers if workers is not None else usable_cores()
        # the workers ignore Ctrl-C (worker_setup): this process alone stops the run
        with _quiet_dask_logs(), LocalCluster(
                n_workers=count, threads_per_worker=1, processes=True, host='127.0.0.1',
                dashboard_address='127.0.0.1:0', env=dict(ONE_THREAD_ENV),
                silence_logs=logging.CRITICAL,
                preload=['obstacle_detection.fleet.worker_setup']) as cluster, \
                Client(cluster) as client:
                yield Fleet(client, f'a local Dask cluster of {count} worker process'
                            f'{"es" if count != 1 else ""} (1 thread each)', count, retries)


@contextlib.contextmanager
def _quiet_dask_logs() -> Iterator[None]:
    """Keep Dask's own log lines (a worker restarted, a cluster closing) off the terminal."""
    loggers = [logging.getLogger(name) for name in ('distributed', 'distributed.nanny',
                                                    'distributed.scheduler',
                                                    'distributed.worker', 'distributed.core')]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)


def limit_threads() -> None:
    """Run this task on one thread: numba's parallel kernels and OpenCV (see the module)."""
    import cv2

    cv2.setNumThreads(1)
    if importlib.util.find_spec('numba') is not None:
        import numba

        numba.set_num_threads(1)


@dataclasses.dataclass
class TaskError:
    """A task that failed for good: its exception's text (``errors='return'``)."""

    reason: str


def run_tasks(fleet: Fleet, function: Callable[..., Any], items: Sequence[tuple[Any, ...]],
              *, label: str, progress: bool = True, errors: str = 'raise',
              on_result: Callable[[int, Any], None] | None = None) -> list[Any]:
    """Return ``[function(*item) for item in items]``, computed where ``fleet`` says.

    errors: 'raise' the first failure, or 'return' a :class:`TaskError` in its place;
    on_result(index, result) as each task finishes.
    """
    if errors not in ('raise', 'return'):
        raise ValueError(f"errors={errors!r}: 'raise' or 'return'")
    results: list[Any] = [None] * len(items)
    bar = Progress(len(items), label, stream=None if progress else io.StringIO())
    with bar:
        if not fleet.distributed:
            for index, item in enumerate(items):
                try:
                    results[index] = function(*item)
                except Exception as err:   # noqa: BLE001 - reported as the task's failure
                    if errors == 'raise':
                        raise
                    results[index] = TaskError(f'{type(err).__name__}: {err}')
                if on_result is not None:
                    on_result(index, results[index])
                bar.update()
            return results
        from distributed import as_completed

        run = uuid.uuid4().hex[:8]
        name = getattr(function, '__name__', 'task')
        futures = [fleet.client.submit(function, *item, key=f'{name}-{run}-{index}',
                                       retries=fleet.retries, pure=False)
                   for index, item in enumerate(items)]
        position = {future.key: index for index, future in enumerate(futures)}
        try:
            for future in as_completed(futures):
                index = position[future.key]
                try:
                    results[index] = future.result()
                except Exception as err:   # noqa: BLE001 - as in one process, or returned
                    if errors == 'raise':
                        raise
                    results[index] = TaskError(_task_reason(err))
                if on_result is not None:
                    on_result(index, results[index])
                bar.update()
        except BaseException:
            fleet.client.cancel(futures)
            raise
    return results


def _task_reason(err: BaseException) -> str:
    """One line on why a task failed on the cluster."""
    kind = type(err).__name__
    if kind == 'KilledWorker':
        return (f'its worker died {ALLOWED_FAILURES} times while running it (out of memory, '
                'a crash in native code?)')
    return f'{kind}: {err}'
