"""The one switch between the compiled kernels and the numpy path, and the background compile.

Each stage's ``_reference_<name>`` and compiled twin (same signature and result): :func:`choose`.
"""

from __future__ import annotations

import functools
import os
import threading
import time
from collections.abc import Callable
from typing import Any

from ._compiled._numba import AVAILABLE, CACHED_KERNELS

#: Environment variable that, set to anything but '' or '0', turns the compiled path off (for
#: tests and comparisons); it is read on every call.
NO_JIT_ENV = 'OBSTACLE_DETECTION_NO_JIT'


#: Open unless a background compilation (:func:`compile_in_background`) is under way: while it
#: is closed, every caller but the compiling thread takes the numpy path (same results).
_kernels_ready = threading.Event()
_kernels_ready.set()
_compiling = threading.local()


def switched_off() -> bool:
    """Return True when ``OBSTACLE_DETECTION_NO_JIT`` asks for the numpy path."""
    return os.environ.get(NO_JIT_ENV, '').strip() not in ('', '0')


def compiling() -> bool:
    """Return True while a background compilation keeps the other threads on numpy."""
    return not _kernels_ready.is_set()


def cache_filled() -> bool:
    """Return True when numba's cache holds an index for every cached kernel defined so far.

    Then a warm-up loads the kernels (about a second) rather than compiling them (about a
    minute on two cores). False when one lacks it, or numba's cache layout is not the one known.
    """
    try:
        return bool(CACHED_KERNELS) and all(os.path.exists(kernel._cache._cache_file._index_path)
                                            for kernel in CACHED_KERNELS)
    except AttributeError:   # numba's internal layout changed: not known to be filled
        return False


def enabled() -> bool:
    """Return True when the compiled kernels run (on the compiling thread only while one runs)."""
    if not AVAILABLE or switched_off():
        return False
    return _kernels_ready.is_set() or getattr(_compiling, 'active', False)


def choose(reference: Callable[..., Any], compiled: Callable[..., Any]) -> Callable[..., Any]:
    """Return a dispatcher: ``compiled`` when :func:`enabled`, else ``reference``.

    The result keeps both as ``.reference`` and ``.compiled`` (tests compare them).
    """
    @functools.wraps(reference)
    def dispatch(*args: Any, **kwargs: Any) -> Any:
        if enabled():
            return compiled(*args, **kwargs)
        return reference(*args, **kwargs)

    dispatch.__name__ = dispatch.__qualname__ = compiled.__name__
    dispatch.reference = reference
    dispatch.compiled = compiled
    return dispatch


class BackgroundCompile(threading.Thread):
    """A compilation on a daemon thread (:func:`compile_in_background`); error: what it raised."""

    def __init__(self, warm_up: Callable[[], Any],
                 on_done: Callable[['BackgroundCompile'], None] | None) -> None:
        super().__init__(name='numba_compile', daemon=True)
        self.seconds: float | None = None   #: wall time of the compilation, once done
        self.error: BaseException | None = None
        self._warm_up = warm_up
        self._on_done = on_done

    def run(self) -> None:
        """Compile on this thread; the numpy path stays open after a failure."""
        _compiling.active = True
        start = time.perf_counter()
        try:
            self._warm_up()
        except BaseException as error:  # noqa: BLE001 - reported through self.error
            self.error = error
        finally:
            _compiling.active = False
            self.seconds = time.perf_counter() - start
            if self.error is None:
                _kernels_ready.set()
            if self._on_done is not None:
                self._on_done(self)


def compile_in_background(warm_up: Callable[[], Any], *,
                          on_done: Callable[[BackgroundCompile], None] | None = None
                          ) -> BackgroundCompile | None:
    """Run ``warm_up`` on a daemon thread; meanwhile the other threads run the numpy path.

    ``on_done`` is called on that thread at the end. Returns None when the compiled path is off.
    """
    if not enabled():
        return None
    job = BackgroundCompile(warm_up, on_done)
    _kernels_ready.clear()
    job.start()
    return job
