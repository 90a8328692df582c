"""Set up a local cluster's worker process (a Dask preload, run as the worker starts).

A Ctrl-C at the terminal reaches every process of its group. The worker processes ignore it:
the tool's process alone stops the run and closes the cluster (the running tasks finish, or
stop when their worker is ended, no new ones start), instead of each worker dying with a
traceback.
"""

from __future__ import annotations

import signal
from typing import Any


def dask_setup(worker: Any) -> None:
    """Ignore SIGINT in this worker process (called by Dask in its main thread)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
