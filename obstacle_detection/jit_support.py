"""What the optional numba kernels share: the import, the compile decorator and the switch.

numba is an optional accelerator (README, Dependencies). When it imports, the kernels of
:mod:`.jit_median`, :mod:`.jit_knn` and :mod:`.jit_voxel` run compiled; when it does not (a ROS
system without python3-numba), or the environment variable ``OBSTACLE_DETECTION_NO_JIT`` is set
to anything but '' or '0', the numpy/scipy code runs with the same results.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

try:
    import numba
except (ImportError, OSError):  # not installed, or built for another numpy / llvm
    numba = None

#: True when numba imported and the compiled kernels can run.
AVAILABLE: bool = numba is not None

#: Environment variable that, set to anything but '' or '0', turns the compiled path off (for
#: tests and comparisons); it is read on every call.
NO_JIT_ENV = 'OBSTACLE_DETECTION_NO_JIT'


def enabled() -> bool:
    """Return True when the compiled kernels run: numba is there and not switched off."""
    return AVAILABLE and os.environ.get(NO_JIT_ENV, '').strip() in ('', '0')


def jit(func: Callable[..., Any]) -> Callable[..., Any]:
    """Compile ``func`` with numba (cached on disk) when numba is there; else leave it as is.

    Single-threaded (no ``parallel``), releasing the GIL; without a writable cache directory
    the kernel is compiled in memory at each start.
    """
    if numba is None:
        return func
    try:
        return numba.njit(cache=True, nogil=True, boundscheck=False)(func)
    except RuntimeError:
        return numba.njit(cache=False, nogil=True, boundscheck=False)(func)
