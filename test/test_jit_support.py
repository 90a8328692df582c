"""Tests of the one compiled/numpy switch (pipeline.jit) and its background compilation gate.

The gate matters for the node's cold start: while the kernels compile on one thread, every
other thread runs the numpy path.
"""

from __future__ import annotations

import threading

import pytest

from obstacle_detection.pipeline import jit as jit_support

needs_compiled = pytest.mark.skipif(not jit_support.enabled(),
                                    reason='numba is not installed or switched off')


@pytest.mark.parametrize('value, on', [(None, True), ('', True), ('0', True), ('1', False),
                                       ('yes', False)])
def test_the_switch_follows_the_environment(value, on, monkeypatch) -> None:
    """OBSTACLE_DETECTION_NO_JIT set to anything but '' or '0' turns the kernels off."""
    if value is None:
        monkeypatch.delenv(jit_support.NO_JIT_ENV, raising=False)
    else:
        monkeypatch.setenv(jit_support.NO_JIT_ENV, value)
    assert jit_support.enabled() is (on and jit_support.AVAILABLE)
    assert jit_support.switched_off() is not on


@pytest.fixture
def fresh_gate(monkeypatch: pytest.MonkeyPatch) -> threading.Event:
    """Give this test a gate of its own, so a failed compilation cannot leak out."""
    gate = threading.Event()
    gate.set()
    monkeypatch.setattr(jit_support, '_kernels_ready', gate)
    return gate


@needs_compiled
def test_other_threads_take_the_numpy_path_while_compiling(fresh_gate: threading.Event) -> None:
    release = threading.Event()
    seen_inside: list[bool] = []

    def warm_up() -> None:
        seen_inside.append(jit_support.enabled())
        assert release.wait(10.0)

    job = jit_support.compile_in_background(warm_up)
    assert job is not None
    try:
        while not seen_inside:
            threading.Event().wait(0.01)
        assert seen_inside == [True]          # the compiling thread uses the kernels
        assert not jit_support.enabled()      # everybody else: numpy, no waiting on a lock
        assert jit_support.compiling()
        assert not job.done()
    finally:
        release.set()
    assert job.wait(10.0)
    assert job.error is None and job.seconds is not None and job.seconds >= 0.0
    assert jit_support.enabled()
    assert not jit_support.compiling()


@needs_compiled
def test_a_failed_compilation_keeps_the_numpy_path_and_says_why(
        fresh_gate: threading.Event) -> None:
    finished: list[jit_support.BackgroundCompile] = []

    def warm_up() -> None:
        raise RuntimeError('no LLVM today')

    job = jit_support.compile_in_background(warm_up, on_done=finished.append)
    assert job is not None and job.wait(10.0)
    assert finished == [job]
    assert isinstance(job.error, RuntimeError) and 'no LLVM today' in str(job.error)
    assert not jit_support.enabled()


@needs_compiled
def test_nothing_starts_when_the_compiled_path_is_switched_off(
        fresh_gate: threading.Event, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(jit_support.NO_JIT_ENV, '1')
    ran: list[int] = []
    assert jit_support.compile_in_background(lambda: ran.append(1)) is None
    assert ran == [] and fresh_gate.is_set()
