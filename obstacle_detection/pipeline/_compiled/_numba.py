"""The numba import, the compile decorators and the scratch buffers the kernels share.

numba is optional: without it :data:`AVAILABLE` is False, the decorators leave the functions
as plain Python and the stage modules run their numpy path.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

try:
    import numba
except (ImportError, OSError):  # not installed, or built for another numpy / llvm
    numba = None

#: True when numba imported and the compiled kernels can run.
AVAILABLE: bool = numba is not None
#: numba's parallel range in ``jit(parallel=True)`` kernels (``range`` without numba).
prange = numba.prange if numba is not None else range

_SCRATCH = threading.local()
#: The kernels cached on disk, in definition order (jit.cache_filled looks for their files).
CACHED_KERNELS: list[Any] = []


def jit(func: Callable[..., Any] | None = None, **options: Any) -> Any:
    """numba.njit ``func`` releasing the GIL, cached on disk if it can be; ``options`` added.

    ``@jit(inline='always')``: inlined into every compiled caller (spares the array reference
    counts); ``@jit(parallel=True)``: ``prange`` loops on :func:`set_threads` threads.
    """
    if func is None:
        return functools.partial(jit, **options)
    if numba is None:
        return func
    try:
        kernel = numba.njit(cache=True, nogil=True, boundscheck=False, **options)(func)
    except RuntimeError:   # no writable cache directory: compiled in memory at each start
        return numba.njit(cache=False, nogil=True, boundscheck=False, **options)(func)
    if options.get('inline') != 'always':   # an inlined one lives in its callers' files
        CACHED_KERNELS.append(kernel)
    return kernel


def set_threads(threads: int) -> None:
    """Let this thread's next parallel kernels use ``threads`` (clipped) threads."""
    if numba is not None:
        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))


def scratch(name: str, size: int, dtype: Any, zero: bool = False) -> np.ndarray:
    """Return this thread's flat buffer ``name`` (>= ``size``), reused: no fresh page faults.

    ``zero``: it starts all zero, and its users leave it so.
    """
    buf = getattr(_SCRATCH, name, None)
    if buf is None or buf.size < size or buf.dtype != dtype:
        buf = np.zeros(size, dtype) if zero else np.empty(size, dtype)
        setattr(_SCRATCH, name, buf)
    return buf
