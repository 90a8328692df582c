"""How the node process runs: its executor and its frozen start-up heap (in-process, loopback).

The figures behind these choices (CPU per thread, the length of a full collection) are
measured by tools/latency_bench.py and described in the README; these tests check the
behaviour the node relies on.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator

import pytest
import rclpy
import ros_env

from obstacle_detection.ros.node import DetectorNode, freeze_heap_when_ready, make_executor



@pytest.fixture(scope='module')
def context() -> Iterator[rclpy.Context]:
    with ros_env.rclpy_context(__name__) as ctx:
        yield ctx


def test_executor_raises_a_callback_error_and_goes_on_dispatching(context) -> None:
    """spin_forever survives a raising callback only if spin_once raises it and goes on."""
    node = rclpy.create_node('executor_probe', context=context)
    executor = make_executor(context)
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


def test_start_up_heap_is_frozen_once_the_kernels_are_ready(context) -> None:
    node = DetectorNode(context=context)
    before = [object()]          # a list: tracked by the collector
    try:
        assert id(before) in {id(o) for o in gc.get_objects()}
        freeze_heap_when_ready(node).join(timeout=300.0)
        assert node._compile is None or node._compile.done()
        assert gc.get_freeze_count() > 0
        assert id(before) not in {id(o) for o in gc.get_objects()}   # out of every collection
        after = [object()]
        assert id(after) in {id(o) for o in gc.get_objects()}        # new objects are collected
    finally:
        gc.unfreeze()
        node.close()
        node.destroy_node()
