"""Fixtures shared by several test modules."""

from __future__ import annotations

import inspect
import re
import subprocess
import sys
import threading
from pathlib import Path

import pytest

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


# -- the integration mark, set by what a test does -------------------------------------------
#: Words in a test's code (or in a fixture or module function it uses) that start a process or
#: a DDS graph.
_STARTS_PROCESS = re.compile(r'\b(subprocess|Popen|rclpy\.init|rclpy_context|multiprocessing'
                             r'|LocalCluster)\b')
_CALLED = re.compile(r'\b([A-Za-z_]\w*)\b')


def _source(obj: object) -> str:
    try:
        return inspect.getsource(obj)
    except (OSError, TypeError):
        return ''


def _starts_process(item: pytest.Item) -> bool:
    """Whether the test, its fixtures or the module functions they use start a process/DDS."""
    module = getattr(item, 'module', None)
    infos = getattr(item, '_fixtureinfo', None)   # pytest has no public name for this
    todo = [getattr(item, 'function', None)]
    for name in getattr(item, 'fixturenames', ()):
        if name == '_processes_need_the_mark':   # the guard below names what it refuses
            continue
        for definition in (infos.name2fixturedefs.get(name, ()) if infos else ()):
            todo.append(definition.func)
    seen: set[int] = set()
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
