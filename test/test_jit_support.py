"""Tests of the one compiled/numpy switch (pipeline.jit) and its background compilation gate.

The gate matters for the node's cold start: while the kernels compile on one thread, every
other thread runs the numpy path.
"""

from __future__ import annotations

import threading

import pytest

from obstacle_detection.pipeline import jit as jit_support

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


@pytest.mark.skipif(not jit_support.AVAILABLE, reason='numba is not installed')
def test_cache_filled_tells_a_load_from_a_compilation(tmp_path) -> None:
    """The node says "load" or "compile" by it: the venv's cache is filled by setup_venv.sh."""
    import os
    import subprocess
    import sys

    code = ('from obstacle_detection.pipeline import detector, jit; '
            'print(jit.cache_filled(), len(jit.CACHED_KERNELS) > 5)')
    env = {**os.environ, 'NUMBA_CACHE_DIR': str(tmp_path / 'empty')}
    empty = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                           text=True, check=True).stdout.split()
    assert empty == ['False', 'True']
    from obstacle_detection.pipeline import detector  # noqa: F401 - defines the kernels
    assert jit_support.cache_filled(), 'run tools/setup_venv.sh: it fills numba\'s cache'


@pytest.fixture
def fresh_gate(monkeypatch: pytest.MonkeyPatch) -> threading.Event:
    """Give this test a gate of its own, so a failed compilation cannot leak out.

    The compiled path is on (not switched off by the environment).
    """
    monkeypatch.delenv(jit_support.NO_JIT_ENV, raising=False)
    gate = threading.Event()
    gate.set()
    monkeypatch.setattr(jit_support, '_kernels_ready', gate)
    return gate


@pytest.mark.numba
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
        assert job.seconds is None            # not done
    finally:
        release.set()
    job.join(10.0)
    assert job.error is None and job.seconds is not None and job.seconds >= 0.0
    assert jit_support.enabled()
    assert not jit_support.compiling()


@pytest.mark.numba
def test_a_failed_compilation_keeps_the_numpy_path_and_says_why(
        fresh_gate: threading.Event) -> None:
    finished: list[jit_support.BackgroundCompile] = []

    def warm_up() -> None:
        raise RuntimeError('no LLVM today')

    job = jit_support.compile_in_background(warm_up, on_done=finished.append)
    assert job is not None
    job.join(10.0)
    assert finished == [job]
    assert isinstance(job.error, RuntimeError) and 'no LLVM today' in str(job.error)
    assert not jit_support.enabled()


@pytest.mark.numba
def test_nothing_starts_when_the_compiled_path_is_switched_off(
        fresh_gate: threading.Event, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(jit_support.NO_JIT_ENV, '1')
    ran: list[int] = []
    assert jit_support.compile_in_background(lambda: ran.append(1)) is None
    assert ran == [] and fresh_gate.is_set()


def _twice(x: int) -> int:
    """Return 2 x."""
    return 2 * x


def _twice_compiled(x: int) -> int:
    return x + x + 1000   # marks which twin ran


def test_choose_runs_the_compiled_twin_only_when_the_switch_is_on(monkeypatch) -> None:
    both = jit_support.choose(_twice, _twice_compiled)
    assert (both.reference, both.compiled) == (_twice, _twice_compiled)
    assert both.__name__ == '_twice_compiled' and both.__doc__ == _twice.__doc__
    monkeypatch.setenv(jit_support.NO_JIT_ENV, '1')
    assert both(3) == 6
    monkeypatch.setenv(jit_support.NO_JIT_ENV, '0')
    assert both(3) == (1006 if jit_support.AVAILABLE else 6)
