"""Style checks run with the tests (STYLE.md): pyflakes/pycodestyle and pep257 docstrings.

ruff does both in one tool. The rules follow the ROS conventions: ament_flake8's line length
of 99, and ament_pep257's pep257 convention with the missing-docstring checks (D100-D107) off.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
RUFF_ARGS = ['check', '--no-cache', '--line-length', '99', '--select', 'E,F,W,D',
             '--ignore', 'D100,D101,D102,D103,D104,D105,D106,D107',
             '--config', "lint.pydocstyle.convention='pep257'",
             'obstacle_detection', 'tools', 'test', 'setup.py']


def _ruff() -> list[str] | None:
    exe = shutil.which('ruff', path=str(Path(sys.executable).parent)) or shutil.which('ruff')
    if exe:
        return [exe]
    try:
        import ruff  # noqa: F401
    except ImportError:
        return None
    return [sys.executable, '-m', 'ruff']


def test_code_passes_flake8_and_pep257_rules():
    ruff = _ruff()
    if ruff is None:
        pytest.skip('ruff is not installed (pip install -r requirements.txt)')
    run = subprocess.run([*ruff, *RUFF_ARGS], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
