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
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.progress import Progress

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
                            'installed and there is more than one task]')
    group.add_argument('--scheduler', metavar='ADDRESS',
                       help='run on the Dask cluster of this scheduler, e.g. tcp://host:8786')


def fleet_options(args: argparse.Namespace) -> dict[str, Any]:
    """Return the keyword arguments of :func:`open_fleet` from the parsed fleet options."""
    return {'workers': args.workers, 'scheduler': args.scheduler}


@contextlib.contextmanager
def open_fleet(*, workers: int | None = None, scheduler: str | None = None,
               tasks: int = 2) -> Iterator[Fleet]:
    """Yield where to run ``tasks`` tasks; close it afterwards.

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
    if not wanted and (workers == 0 or not DASK_AVAILABLE or tasks < 2 or cores < 2):
        yield Fleet(None, 'this process', 1)
        return
    import dask
    from distributed import Client, LocalCluster

    # glibc's own mmap threshold, no profiler, slower ticks: docs/fleet.md, Speed
    with dask.config.set({'distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_': None,
                          'distributed.worker.profile.enabled': False,
                          'distributed.admin.tick.interval': '500ms'}):
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout='10s')
            except (OSError, TimeoutError) as err:
                raise tool_support.ToolError(scheduler, f'no Dask scheduler answers ({err})') \
                    from err
            with client:
                count = len(client.scheduler_info().get('workers', {}))
                yield Fleet(client, f'the Dask cluster at {scheduler} ({count} workers)',
                            count)
            return
        count = workers if workers is not None else cores
        # the workers ignore Ctrl-C (worker_setup): this process alone stops the run
        with LocalCluster(
                n_workers=count, threads_per_worker=1, processes=True, host='127.0.0.1',
                dashboard_address='127.0.0.1:0', env=dict(ONE_THREAD_ENV),
                silence_logs=logging.CRITICAL,
                preload=['obstacle_detection.fleet.worker_setup']) as cluster, \
                Client(cluster) as client:
                yield Fleet(client, f'a local Dask cluster of {count} worker process'
                            f'{"es" if count != 1 else ""} (1 thread each)', count)


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


def run_tasks(fleet: Fleet, function: Callable[..., Any], items: Sequence[tuple[Any, ...]],
              *, label: str, progress: bool = True, return_errors: bool = False) -> list[Any]:
    """Return ``[function(*item) for item in items]``, computed where ``fleet`` says.

    A task that fails raises, or with ``return_errors`` gives a :class:`TaskError` instead.
    """
    results: list[Any] = [None] * len(items)
    futures: list[Any] = []
    if fleet.distributed:
        from distributed import as_completed

        futures = [fleet.submit(function, *item) for item in items]
        position = {future.key: index for index, future in enumerate(futures)}
        done = ((position[future.key], future.result) for future in as_completed(futures))
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

