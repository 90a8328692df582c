"""The ``integration`` mark comes from what a test does (test/conftest.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

CONFTEST = Path(__file__).resolve().parent / 'conftest.py'

TESTS = '''
import subprocess
import sys

import helper


def _start():
    return subprocess.run([sys.executable, '-c', 'pass'], check=True)


def test_pure():
    assert 1 + 1 == 2


def test_starts_a_process_through_a_module_function():
    _start()


def test_starts_a_process_elsewhere():
    helper.start()
'''

HELPER = '''
import subprocess
import sys


def start():
    subprocess.run([sys.executable, '-c', 'pass'], check=True)
'''


@pytest.fixture
def suite(pytester: pytest.Pytester) -> pytest.Pytester:
    """Return a small test folder with this project's conftest."""
    pytester.makeconftest(CONFTEST.read_text(encoding='utf-8'))
    pytester.makeini('[pytest]\nmarkers =\n    integration: starts processes\n')
    pytester.makepyfile(test_small=TESTS, helper=HELPER)
    pytester.syspathinsert()
    return pytester


def test_a_test_that_starts_a_process_in_its_module_is_marked(suite: pytest.Pytester) -> None:
    marked = suite.runpytest('-m', 'integration', '--collect-only', '-q')
    marked.stdout.fnmatch_lines(['*test_starts_a_process_through_a_module_function*'])
    assert 'test_pure' not in marked.stdout.str()


def test_a_process_started_elsewhere_fails_the_fast_run_with_the_fix(
        suite: pytest.Pytester) -> None:
    fast = suite.runpytest('-m', 'not integration')
    fast.assert_outcomes(passed=1, failed=1, deselected=1)
    fast.stdout.fnmatch_lines(['*test_starts_a_process_elsewhere starts a process*'
                               'mark it @pytest.mark.integration*'])
