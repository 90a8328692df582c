"""Run the parts of the median's bands on up to ``compute_threads`` threads (concurrent.futures).

Only the median (:func:`.median.median_filter` and its variants) cuts its work into parts
for several threads: each part writes its own rows of an output array that the caller made,
so the result equals the one-thread result bit for bit. The other stages run on the calling
thread: on this project's 2-core machine their split did not pay (docs/threads.md).
"""

from __future__ import annotations

import operator
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from typing import Any

import numpy as np

__all__ = ['MAX_THREADS', 'check_threads', 'run_parts']

#: Most threads a stage may use (the range of ``compute_threads``).
MAX_THREADS = 8

_helpers = ThreadPoolExecutor(max_workers=MAX_THREADS - 1,
                              thread_name_prefix='obstacle_detection_part')


def check_threads(threads: Any) -> int:
    """Return ``threads`` as an int in [1, MAX_THREADS]; TypeError / ValueError otherwise."""
    if isinstance(threads, (bool, np.bool_)):
        raise TypeError(f'compute_threads must be an integer, got {threads!r}')
    threads = operator.index(threads)
    if not 1 <= threads <= MAX_THREADS:
        raise ValueError(f'compute_threads={threads} out of range: must be in [1, {MAX_THREADS}]')
    return threads


def run_parts(parts: Sequence[Callable[[], Any]], threads: int) -> None:
    """Call every function of ``parts`` on up to ``threads`` threads; return when all returned.

    The calling thread and up to ``threads - 1`` pool threads each take the next part not yet
    taken, never more threads than the CPUs the process may use. A pool thread that has not
    started when the calling thread runs out of parts is not waited for (the calling thread
    did its share), so a busy machine delays the stage by at most the part a late thread
    holds. The first exception (in list order) is raised again once every part has returned.
    """
    parts = list(parts)
    threads = min(check_threads(threads), len(parts), len(os.sched_getaffinity(0)))
    errors: list[BaseException | None] = [None] * len(parts)
    taken = iter(range(len(parts)))      # next() on it is atomic under the GIL

    def work() -> None:
        for index in taken:
            try:
                parts[index]()
            except BaseException as error:  # noqa: BLE001 - raised again below
                errors[index] = error

    helpers = [_helpers.submit(work) for _ in range(threads - 1)]
    work()
    wait([helper for helper in helpers if not helper.cancel()])
    for error in errors:
        if error is not None:
            raise error
