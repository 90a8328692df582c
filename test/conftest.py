"""Fixtures shared by several test modules."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


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
