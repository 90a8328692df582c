"""The numba import, the compile decorators and the scratch buffers the kernels share.

numba is optional: without it :data:`AVAILABLE` is False, the decorators leave the functions
as plain Python and the stage modules run their numpy path.
"""

from __future__ import annotations

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
#: numba's parallel range in :func:`jit_parallel` kernels (``range`` without numba).
prange = numba.prange if numba is not None else range

_SCRATCH = threading.local()


def _compile(func: Callable[..., Any], **options: Any) -> Callable[..., Any]:
    """numba.njit ``func`` releasing the GIL, cached on disk if it can be; ``options`` added."""
    if numba is None:
        return func
    try:
        return numba.njit(cache=True, nogil=True, boundscheck=False, **options)(func)
    except RuntimeError:   # no writable cache directory: compiled in memory at each start
        return numba.njit(cache=False, nogil=True, boundscheck=False, **options)(func)


def jit(func: Callable[..., Any]) -> Callable[..., Any]:
    """Compile ``func`` with numba (single-threaded, cached on disk) when numba is there."""
    return _compile(func)


def jit_parallel(func: Callable[..., Any]) -> Callable[..., Any]:
    """:func:`jit` with ``parallel=True``: ``prange`` loops on :func:`set_threads` threads."""
    return _compile(func, parallel=True)


def set_threads(threads: int) -> None:
    """Let this thread's next :func:`jit_parallel` kernels use ``threads`` (clipped) threads."""
    if numba is not None:
        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))


def jit_inline(func: Callable[..., Any]) -> Callable[..., Any]:
    """:func:`jit`, inlined into every compiled caller (spares the array reference counts)."""
    return _compile(func, inline='always')


def scratch(name: str, size: int, dtype: Any, zero: bool = False) -> np.ndarray:
    """Return this thread's flat buffer ``name`` of at least ``size`` elements, kept for reuse.

    Reuse spares the page faults of fresh large arrays. ``zero``: it starts all zero, and its
    users leave it so.
    """
    buf = getattr(_SCRATCH, name, None)
    if buf is None or buf.size < size or buf.dtype != dtype:
        buf = np.zeros(size, dtype) if zero else np.empty(size, dtype)
        setattr(_SCRATCH, name, buf)
    return buf
