"""Style checks run with the tests (STYLE.md): pyflakes/pycodestyle and pep257 docstrings.

ruff does both in one tool, with the settings of pyproject.toml (the ROS conventions).
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
RUFF_ARGS = ['check', '--no-cache', 'obstacle_detection', 'tools', 'test', 'setup.py', 'launch']


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
