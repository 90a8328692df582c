"""Cutting a kernel's work into parts that other threads may run (no numba needed).

A kernel module that can split its work takes ``parts`` and a ``run_parts`` callable from its
stage module (``pipeline.parallel`` provides one); these two helpers are what every such
kernel module does with them.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ['edges', 'run']


def edges(count: int, parts: int) -> list[int]:
    """Return the parts + 1 boundaries cutting ``range(count)`` into near-equal ranges."""
    return [count * p // parts for p in range(parts + 1)]


def run(calls: list[Callable[[], None]],
        run_parts: Callable[[list[Callable[[], None]]], None] | None) -> None:
    """Run ``calls`` through ``run_parts`` (e.g. on several threads), or here, in order."""
    if run_parts is None:
        for call in calls:
            call()
    else:
        run_parts(calls)
