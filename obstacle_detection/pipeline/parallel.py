"""Run the parts of the median's bands on up to ``compute_threads`` threads (concurrent.futures).

Only the median (:mod:`.median`) still hands Python-level parts to threads; the other stages
cut their work inside compiled ``prange`` loops (:func:`.jit.use_threads`). Each part writes
its own rows of an output array that the caller made, so the result equals the one-thread
result bit for bit.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from typing import Any

from .jit import MAX_THREADS, check_threads

__all__ = ['check_threads', 'run_parts']

_helpers = ThreadPoolExecutor(max_workers=MAX_THREADS - 1,
                              thread_name_prefix='obstacle_detection_part')


def run_parts(parts: Sequence[Callable[[], Any]], threads: int) -> None:
    """Call every function of ``parts`` on up to ``threads`` threads; return when all returned.

    The calling thread and up to ``threads - 1`` pool threads each take the next part not
    yet taken, never more threads than the CPUs the process may use. The first exception (in
    list order) is raised again once every part has returned.
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
    wait(helpers)
    for error in errors:
        if error is not None:
            raise error
