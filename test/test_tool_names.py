"""Every command line names itself as installed: ``usage: bag_convert``, not ``bag_convert.py``.

setup.py installs ``tools/<name>.py`` as the command ``<name>`` (``.venv/bin/<name>``,
``ros2 run obstacle_detection <name>``), so its ``--help`` and its error lines say ``<name>``.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

TOOLS_DIR = Path(__file__).resolve().parents[1] / 'tools'
TOOLS = sorted(p.stem for p in TOOLS_DIR.glob('*.py') if not p.name.startswith('_'))


@pytest.mark.parametrize('name', TOOLS)
def test_help_names_the_installed_command(name: str,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    module = importlib.import_module(f'obstacle_detection.tools.{name}')
    with pytest.raises(SystemExit) as done:
        module.main(['--help'])
    assert done.value.code == 0
    assert capsys.readouterr().out.startswith(f'usage: {name} ')
