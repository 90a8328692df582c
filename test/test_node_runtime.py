"""How the node process runs: its executor (in-process, loopback).

The figures behind this choice (CPU per thread) are measured by tools/latency_bench.py and
described in the README; this test checks the behaviour the node relies on.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest
import rclpy
import ros_env

from rclpy.experimental import EventsExecutor



@pytest.fixture(scope='module')
def context() -> Iterator[rclpy.Context]:
    with ros_env.rclpy_context(__name__) as ctx:
        yield ctx


def test_executor_raises_a_callback_error_and_goes_on_dispatching(context) -> None:
    """spin_forever survives a raising callback only if spin_once raises it and goes on."""
    node = rclpy.create_node('executor_probe', context=context)
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    calls = []
    second = threading.Event()

    def tick() -> None:
        calls.append(len(calls))
        if len(calls) == 1:
            raise RuntimeError('first tick fails')
        second.set()

    node.create_timer(0.01, tick)
    raised = []
    try:
        for _ in range(200):
            try:
                executor.spin_once(timeout_sec=0.05)
            except RuntimeError as error:
                raised.append(str(error))
            if second.is_set():
                break
    finally:
        executor.shutdown()
        node.destroy_node()
    assert raised == ['first tick fails']
    assert second.is_set() and len(calls) >= 2
