"""Fixtures shared by several test modules."""

from __future__ import annotations

import copy
import dataclasses
import functools
import inspect
import re
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from obstacle_detection.pipeline import jit

REPO = Path(__file__).resolve().parents[1]
pytest_plugins = ['pytester']   # test_conftest_marks runs pytest on small test files


@pytest.fixture(scope='session')
def prefix(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Install the package once the way colcon's ament_python build does; its prefix."""
    tmp = tmp_path_factory.mktemp('colcon')
    build, install = tmp / 'build', tmp / 'install'
    build.mkdir()
    command = [sys.executable, 'setup.py', '--quiet',
               'egg_info', '--egg-base', str(build),
               'build', '--build-base', str(build / 'build'),
               'install', '--prefix', str(install), '--record', str(build / 'install.log'),
               '--single-version-externally-managed']
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300,
                          check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    return install


# -- the small bags of test_bag_process and test_fleet ----------------------------------------
@pytest.fixture(scope='session')
def depths() -> list[np.ndarray]:
    """Return the frames of the small test bags (``test_bag_process.frames``), rendered once."""
    from test_bag_process import frames

    return frames()


@pytest.fixture(scope='module')
def params_file(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Write the test module's ``PARAMS_YAML`` to a params file; return its path."""
    path = tmp_path_factory.mktemp('params') / 'params.yaml'
    path.write_text(request.module.PARAMS_YAML)
    return path


@pytest.fixture(scope='module')
def local_context(request: pytest.FixtureRequest) -> Iterator[Any]:
    """Yield an rclpy context for in-process nodes: loopback DDS, the test module's domain."""
    import ros_env

    with ros_env.rclpy_context(request.module.__name__ + ':in-process') as context:
        yield context


# -- the numpy/scipy reference and the compiled (numba) path -----------------------------------
def pytest_configure(config: pytest.Config) -> None:
    """Declare the ``numba`` mark: the test needs the compiled kernels (skipped without)."""
    config.addinivalue_line('markers', 'numba: needs numba; skipped where it is not installed')


@pytest.fixture(autouse=True)
def _needs_numba(request: pytest.FixtureRequest) -> None:
    """Skip the tests marked ``numba`` where numba is not installed."""
    if request.node.get_closest_marker('numba') is not None and not jit.AVAILABLE:
        pytest.skip('numba is not installed')


def _use_path(monkeypatch: pytest.MonkeyPatch, path: str) -> None:
    """Switch the pipeline to 'reference' (numpy/scipy) or 'compiled' (skipped without numba)."""
    if path == 'compiled' and not jit.AVAILABLE:
        pytest.skip('numba is not installed')
    monkeypatch.setenv(jit.NO_JIT_ENV, '1' if path == 'reference' else '0')
    assert jit.enabled() == (path == 'compiled')


@pytest.fixture(params=['reference', 'compiled'])
def kernel_path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Run the test once on each path: 'reference' (numpy/scipy) and 'compiled' (numba)."""
    _use_path(monkeypatch, request.param)
    return request.param


def assert_same(got: Any, want: Any, where: str = 'result') -> None:
    """Assert two results equal bit for bit: arrays (dtype, shape, bytes), dataclasses, tuples."""
    if isinstance(want, np.ndarray):
        assert isinstance(got, np.ndarray), f'{where}: {type(got)} is not an array'
        assert (got.dtype, got.shape) == (want.dtype, want.shape), where
        assert np.ascontiguousarray(got).tobytes() == np.ascontiguousarray(want).tobytes(), \
            f'{where} differs'
    elif dataclasses.is_dataclass(want):
        assert type(got) is type(want), where
        for f in dataclasses.fields(want):
            assert_same(getattr(got, f.name), getattr(want, f.name), f'{where}.{f.name}')
    elif isinstance(want, (tuple, list)):
        assert type(got) is type(want) and len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want)):
            assert_same(g, w, f'{where}[{i}]')
    elif isinstance(want, dict):
        assert got.keys() == want.keys(), where
        for key in want:
            assert_same(got[key], want[key], f'{where}[{key!r}]')
    else:
        assert type(got) is type(want) and (got == want or got != got and want != want), \
            f'{where}: {got!r} != {want!r}'


@pytest.fixture
def both_paths(monkeypatch: pytest.MonkeyPatch) -> Callable[..., Any]:
    """Return ``compare(call, *args, **kwargs)``: run on both paths, assert the same result.

    ``call`` runs on a deep copy of the arguments with the numpy/scipy reference, then with
    the compiled kernels (the test is skipped without numba); the two results must be equal
    bit for bit (:func:`assert_same`). Returns the reference's result.
    """
    def compare(call: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        results = []
        for path in ('reference', 'compiled'):
            _use_path(monkeypatch, path)
            results.append(call(*copy.deepcopy(args), **copy.deepcopy(kwargs)))
        assert_same(results[1], results[0])
        return results[0]

    return compare


# -- the integration mark, set by what a test does -------------------------------------------
#: Words in a test's code (or in a fixture or module function it uses) that start a process or
#: a DDS graph (NodeProcess, rclpy_context, run_detector: test/ros_env.py).
_STARTS_PROCESS = re.compile(r'\b(subprocess|Popen|rclpy\.init|rclpy_context|multiprocessing'
                             r'|LocalCluster|NodeProcess|run_detector)\b')
_CALLED = re.compile(r'\b([A-Za-z_]\w*)\b')


def _source(obj: object) -> str:
    try:
        return inspect.getsource(obj)
    except (OSError, TypeError):
        return ''


@functools.cache
def _reaches_process(module: object, root: object) -> bool:
    """Whether ``root`` or the functions of ``module`` its code names start a process/DDS.

    Cached: a parametrised test and a shared fixture are read once, not once per test.
    """
    todo, seen = [root], set()
    while todo:
        func = todo.pop()
        if func is None or id(func) in seen:
            continue
        seen.add(id(func))
        text = _source(func)
        if _STARTS_PROCESS.search(text):
            return True
        for name in set(_CALLED.findall(text)):   # this module's own helpers it calls
            obj = getattr(module, name, None)
            if inspect.isfunction(obj) or inspect.isclass(obj):
                if getattr(obj, '__module__', None) == getattr(module, '__name__', ''):
                    todo.append(obj)
    return False


def _starts_process(item: pytest.Item) -> bool:
    """Whether the test, its fixtures or the module functions they use start a process/DDS."""
    module = getattr(item, 'module', None)
    infos = getattr(item, '_fixtureinfo', None)   # pytest has no public name for this
    roots = [getattr(item, 'function', None)]
    for name in getattr(item, 'fixturenames', ()):
        if name == '_processes_need_the_mark':   # the guard below names what it refuses
            continue
        for definition in (infos.name2fixturedefs.get(name, ()) if infos else ()):
            roots.append(definition.func)
    return any(_reaches_process(module, root) for root in roots if root is not None)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark ``integration`` every test that starts a process or a DDS graph."""
    for item in items:
        if item.get_closest_marker('integration') is None and _starts_process(item):
            item.add_marker(pytest.mark.integration)


@pytest.fixture(autouse=True)
def _processes_need_the_mark(request: pytest.FixtureRequest,
                             monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail a test that starts a process or rclpy without the ``integration`` mark.

    The mark is set from the test's code above; this catches what that reading missed (a
    process started through another module), so ``pytest -m "not integration"`` stays fast.
    """
    if request.node.get_closest_marker('integration') is not None:
        return
    message = (f'{request.node.nodeid} starts a process or a DDS graph: mark it '
               '@pytest.mark.integration (test/conftest.py did not see it in its code)')

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError(message)

    monkeypatch.setattr(subprocess.Popen, '__init__', refuse)
    try:
        import rclpy
    except ImportError:
        return
    monkeypatch.setattr(rclpy, 'init', refuse)


def _join_compilations() -> None:
    """Wait for background compilations (``jit.BackgroundCompile``, thread 'numba_compile')."""
    for thread in threading.enumerate():
        if thread.name == 'numba_compile':
            thread.join(timeout=120.0)


# A node compiles its kernels on a thread of its own and logs an [INFO] line when done. Ending
# between two phases of a test, while pytest's capture is paused to report, that line would
# land in `pytest -q`'s output: each phase (setup, call, teardown) waits for the compilations
# it started before its capture ends (trylast: inside the capture plugin's own wrapper).
@pytest.hookimpl(wrapper=True, trylast=True)
def pytest_runtest_setup(item: pytest.Item) -> object:
    """Run the setup phase, then wait for the compilations it started."""
    try:
        return (yield)
    finally:
        _join_compilations()


@pytest.hookimpl(wrapper=True, trylast=True)
def pytest_runtest_call(item: pytest.Item) -> object:
    """Run the test, then wait for the compilations it started."""
    try:
        return (yield)
    finally:
        _join_compilations()


@pytest.hookimpl(wrapper=True, trylast=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> object:
    """Run the teardown phase, then wait for the compilations it started."""
    try:
        return (yield)
    finally:
        _join_compilations()
