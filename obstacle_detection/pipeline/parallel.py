"""Run the parts of one stage on more than one thread, with the one-thread result.

``DetectorParams.compute_threads`` = n > 1 cuts the heaviest stages into parts whose results do
not depend on who computes them or in which order: the K x K median into bands of output rows
(:func:`.median.median_filter`), the k-nearest-neighbour search and the normals into ranges of
query points (:mod:`.normals`). Each part writes its own rows of an output array that the
caller made, so the result equals the one-thread result bit for bit.

The compiled kernels release the GIL, so the parts run at the same time on a multi-core
machine. :func:`run_parts` hands them to a small persistent pool of daemon threads and takes a
share itself: every thread takes the next part nobody has taken yet, so a pool thread that is
slow to wake (waking an idle virtual CPU costs 0.1-0.3 ms here) or kept off the CPU by another
process delays the stage by at most the part it holds.
"""

from __future__ import annotations

import ctypes
import itertools
import operator
import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import jit
from ._compiled import _numba, _parts

__all__ = ['MAX_THREADS', 'check_threads', 'part_bounds', 'run_parts', 'usable_cpus', 'wake',
           'warm_up']

#: Most threads a stage may use (the range of ``compute_threads``).
MAX_THREADS = 8
#: How long the calling thread polls, once its parts are done, for the last part of another
#: thread before it blocks [s]; blocking costs a wake-up (0.1-0.3 ms on a virtual machine).
_POLL_S = 0.004
#: How long a helper stays awake after its parts, for the next stage's [s] (yielding its CPU
#: to any other thread that wants it); 0 = block at once.
LINGER_S = 0.002
#: A wake-up this soon after the last hand-over is skipped [s]: the helpers are still awake
#: (the node wakes them when it takes a frame, the detector again when it starts).
_REWAKE_S = LINGER_S / 4


class _Batch:
    """The parts of one stage; each thread takes the next part nobody has taken (see run_parts)."""

    def __init__(self, parts: list[Callable[[], Any]]) -> None:
        self.parts = parts
        self.errors: list[BaseException | None] = [None] * len(parts)
        self._next = itertools.count()     # next() on a count is atomic under the GIL
        self._left = len(parts)
        self._lock = threading.Lock()
        self.done = threading.Event()

    def work(self) -> None:
        """Run parts nobody has taken until none is left."""
        while True:
            index = next(self._next)
            if index >= len(self.parts):
                return
            try:
                self.parts[index]()
            except BaseException as error:  # noqa: BLE001 - raised again by run_parts
                self.errors[index] = error
            with self._lock:
                self._left -= 1
                if self._left == 0:
                    self.done.set()


def _current_cpu_function() -> Callable[[], int] | None:
    """Return glibc's ``sched_getcpu`` (the CPU the calling thread runs on), or None."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        function = libc.sched_getcpu
    except (OSError, AttributeError):
        return None
    function.restype = ctypes.c_int
    function.argtypes = []
    return function if function() >= 0 else None


def _make_spin() -> Callable[[np.ndarray, int, int], bool] | None:
    """Return the compiled wait of :meth:`_Pool._next_soon`, or None without numba / libc.

    ``spin(generation, seen, rounds)`` returns True as soon as ``generation[0] != seen``, or
    False after ``rounds`` yields of the CPU (``sched_yield``: another thread that wants this
    CPU gets it at once). It holds no GIL. The call to libc also keeps the compiler from
    reading ``generation[0]`` once for the whole loop.
    """
    if _numba.numba is None:
        return None
    try:
        yield_cpu = ctypes.CDLL(None).sched_yield
    except (OSError, AttributeError):
        return None
    yield_cpu.restype = ctypes.c_int
    yield_cpu.argtypes = []

    def spin(generation: np.ndarray, seen: int, rounds: int) -> bool:  # pragma: no cover
        for _ in range(rounds):
            if generation[0] != seen:
                return True
            yield_cpu()
        return generation[0] != seen

    # not cached on disk: numba cannot cache a call through a ctypes pointer (tiny compile)
    return _numba.numba.njit(nogil=True, cache=False)(spin)


class _Pool:
    """Daemon threads that each take batches from one queue and work on them.

    Linux wakes a sleeping thread on the CPU of the thread that woke it when that CPU looks
    idle, as it does at the start of a frame after the gap between frames: the helper then
    shares the caller's CPU until the load balancer moves it, milliseconds later, and the
    stage takes as long as on one thread (measured: a 30 Hz median on two threads was no
    faster than on one). So, on machines with more CPUs than the helpers need, the helpers
    may run anywhere but on the caller's CPU, updated when the caller moves.
    """

    def __init__(self) -> None:
        self._tasks: queue.SimpleQueue[_Batch] = queue.SimpleQueue()
        self._threads: list[threading.Thread] = []
        self._native_ids: list[int] = []
        self._lock = threading.Lock()
        self._current_cpu = _current_cpu_function()
        self._kept_off: int | None = None    # the CPU the helpers are kept off
        self._generation = np.zeros(1, np.int64)   # moves at every submit
        self._spin: Callable[[np.ndarray, int, int], bool] | None = None
        self._spin_rounds = 0                # yields in LINGER_S, measured when compiled
        self.handed_at = -1.0                # perf_counter of the last submit

    def lingers(self) -> bool:
        """Whether the helpers stay awake a while after a hand-over (the compiled wait)."""
        return self._spin is not None

    def prepare_spin(self) -> None:
        """Compile the helpers' wait (:func:`_make_spin`) and time its yields, once."""
        with self._lock:
            if self._spin is not None or LINGER_S <= 0.0:
                return
            spin = _make_spin()
            if spin is None:
                return
            spin(self._generation, -1, 1)           # compiles
            probe = 2000
            start = time.perf_counter()
            spin(self._generation, int(self._generation[0]), probe)
            per_round = max((time.perf_counter() - start) / probe, 1e-8)
            self._spin_rounds = max(1, int(LINGER_S / per_round))
            self._spin = spin

    def _serve(self) -> None:
        _local.in_pool = True
        while True:
            batch: _Batch | None = self._tasks.get()
            while batch is not None:
                batch.work()
                batch = self._next_soon()

    def _next_soon(self) -> _Batch | None:
        """Return the next batch if it comes within LINGER_S, else None (then block).

        Waking a blocked thread costs 0.1-0.3 ms on this virtual machine, more than some
        stages save on two threads; a helper that stays awake between the stages of a frame
        starts the next one within microseconds.
        """
        spin = self._spin
        seen = int(self._generation[0])    # read before looking: a submit after it moves it
        try:
            return self._tasks.get_nowait()
        except queue.Empty:
            pass
        if spin is None or not spin(self._generation, seen, self._spin_rounds):
            return None
        try:
            return self._tasks.get_nowait()    # submit puts the batch before it moves it
        except queue.Empty:
            return None

    def _keep_off_caller_cpu(self) -> None:
        if self._current_cpu is None:
            return
        cpu = self._current_cpu()
        if cpu == self._kept_off or cpu < 0:
            return
        try:
            allowed = os.sched_getaffinity(0) - {cpu}
            if not allowed:
                return
            for native_id in self._native_ids:
                os.sched_setaffinity(native_id, allowed)
        except OSError:      # a thread that is gone, or affinity not permitted: best effort
            return
        self._kept_off = cpu

    def submit(self, batch: _Batch, helpers: int) -> None:
        """Let ``helpers`` pool threads work on ``batch`` (started when first needed)."""
        with self._lock:
            while len(self._threads) < helpers:
                started = threading.Event()
                thread = threading.Thread(target=self._start, args=(started,), daemon=True,
                                          name=f'obstacle_detection_part{len(self._threads)}')
                thread.start()
                started.wait()
                self._threads.append(thread)
                self._native_ids.append(thread.native_id)
                self._kept_off = None
            self._keep_off_caller_cpu()
        for _ in range(helpers):
            self._tasks.put(batch)
        self._generation[0] += 1
        self.handed_at = time.perf_counter()

    def _start(self, started: threading.Event) -> None:
        started.set()
        self._serve()


_pool = _Pool()
_local = threading.local()


def wake(threads: int) -> None:
    """Wake the pool's helpers ahead of the parts ``threads`` threads will run soon.

    A frame's first parallel stage then finds its helpers awake (see :meth:`_Pool._next_soon`)
    instead of paying their wake-up. Does nothing for one thread or from a pool thread.
    """
    if time.perf_counter() - _pool.handed_at < _REWAKE_S and _pool.lingers():
        return            # woken a moment ago (or given parts): still awake
    helpers = min(check_threads(threads), usable_cpus()) - 1
    if helpers > 0 and not getattr(_local, 'in_pool', False):
        if jit.enabled():   # not while a background compile holds numba (the node's start)
            _pool.prepare_spin()
        _pool.submit(_Batch([]), helpers)


def warm_up() -> None:
    """Compile the helpers' wait ahead of the first frame (a fraction of a second)."""
    _pool.prepare_spin()


def usable_cpus() -> int:
    """Return the number of CPUs this process may run on (its affinity, e.g. ``taskset``).

    A stage never runs on more threads than that: a second thread on one CPU only waits.
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def check_threads(threads: Any) -> int:
    """Return ``threads`` as an int in [1, MAX_THREADS]; TypeError / ValueError otherwise."""
    if isinstance(threads, (bool, np.bool_)):
        raise TypeError(f'compute_threads must be an integer, got {threads!r}')
    threads = operator.index(threads)
    if not 1 <= threads <= MAX_THREADS:
        raise ValueError(f'compute_threads={threads} out of range: must be in [1, {MAX_THREADS}]')
    return threads


def part_bounds(count: int, parts: int) -> list[tuple[int, int]]:
    """Cut ``range(count)`` into at most ``parts`` contiguous, non-empty, near-equal ranges."""
    cuts = _parts.edges(count, max(1, min(int(parts), int(count))))
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def run_parts(parts: Sequence[Callable[[], Any]], threads: int) -> None:
    """Call every function of ``parts`` on up to ``threads`` threads; return when all returned.

    The calling thread and ``threads - 1`` pool threads take the parts in list order, each the
    next one not yet taken, never more threads than :func:`usable_cpus`. The first exception
    (in list order) is raised again once every part has returned. One thread, one part, one
    usable CPU, or a call from a pool thread (a pool never waits on itself) runs the parts one
    after the other on the calling thread.
    """
    parts = list(parts)
    helpers = min(check_threads(threads), len(parts), usable_cpus()) - 1
    if helpers <= 0 or getattr(_local, 'in_pool', False):
        for part in parts:
            part()
        return
    batch = _Batch(parts)
    _pool.submit(batch, helpers)
    batch.work()
    if not batch.done.is_set():
        # the last part is another thread's: poll a little (GIL released by the sleep), then
        # block; a blocked thread costs a wake-up on a virtual machine
        deadline = time.perf_counter() + _POLL_S
        while not batch.done.is_set() and time.perf_counter() < deadline:
            time.sleep(0)
        batch.done.wait()
    for error in batch.errors:
        if error is not None:
            raise error
