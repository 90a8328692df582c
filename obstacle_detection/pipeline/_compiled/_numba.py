"""The numba import and the compile decorator the kernels of this package share.

numba is an optional accelerator (README, Dependencies): when it does not import (a ROS system
without python3-numba, or one built for another numpy / llvm), :data:`AVAILABLE` is False,
:func:`jit` leaves the functions as plain Python and the stage modules run their numpy path
(the switch is :func:`obstacle_detection.pipeline.jit.enabled`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

try:
    import numba
except (ImportError, OSError):  # not installed, or built for another numpy / llvm
    numba = None

#: True when numba imported and the compiled kernels can run.
AVAILABLE: bool = numba is not None
#: numba's parallel range in :func:`jit_parallel` kernels (``range`` without numba).
prange = numba.prange if numba is not None else range


def _compile(func: Callable[..., Any], **options: Any) -> Callable[..., Any]:
    """numba.njit ``func`` releasing the GIL, cached on disk if it can be; ``options`` added."""
    if numba is None:
        return func
    try:
        return numba.njit(cache=True, nogil=True, boundscheck=False, **options)(func)
    except RuntimeError:   # no writable cache directory: compiled in memory at each start
        return numba.njit(cache=False, nogil=True, boundscheck=False, **options)(func)


def jit(func: Callable[..., Any]) -> Callable[..., Any]:
    """Compile ``func`` with numba (cached on disk) when numba is there; else leave it as is.

    Single-threaded (no ``parallel``), releasing the GIL; without a writable cache directory
    the kernel is compiled in memory at each start.
    """
    return _compile(func)


def jit_parallel(func: Callable[..., Any]) -> Callable[..., Any]:
    """:func:`jit` with numba's ``parallel=True``: its ``prange`` loops run on numba's threads.

    The caller chooses how many with :func:`set_threads`.
    """
    return _compile(func, parallel=True)


def set_threads(threads: int) -> None:
    """Let the next :func:`jit_parallel` kernels of this thread use ``threads`` threads.

    Clipped to 1 .. numba's thread count (``NUMBA_NUM_THREADS``, the CPUs by default). A no-op
    without numba.
    """
    if numba is not None:
        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))


def jit_inline(func: Callable[..., Any]) -> Callable[..., Any]:
    """:func:`jit`, and inlined into every compiled caller (numba's ``inline='always'``).

    For the small helpers of a hot kernel: an ordinary call passing arrays costs two atomic
    reference-count updates per array, more than the work of the helper; inlined, the
    caller compiles as if the helper's body were written in it.
    """
    return _compile(func, inline='always')
