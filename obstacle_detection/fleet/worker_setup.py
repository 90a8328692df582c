"""Dask preload of a local cluster's workers: they ignore Ctrl-C (the tool stops the run)."""

from __future__ import annotations

import signal


def dask_setup(worker: object) -> None:
    """Ignore SIGINT in this worker process (called by Dask in its main thread)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
