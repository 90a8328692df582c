"""The README stays true to the code; the parameter table of docs/ is the generated one."""

import re
from pathlib import Path

from obstacle_detection.tools import param_table

REPO = Path(__file__).resolve().parents[1]


def test_parameter_table_is_the_generated_one():
    doc = (REPO / 'docs' / 'parameters.md').read_text(encoding='utf-8')
    expected = param_table.with_table(doc, param_table.parameter_table())
    assert doc == expected, 'run: .venv/bin/python tools/param_table.py --doc'


def test_with_table_replaces_only_between_the_markers():
    text = f'intro\n{param_table.DOC_BEGIN}\nold\n{param_table.DOC_END}\nrest\n'
    out = param_table.with_table(text, '| new |\n')
    assert out == f'intro\n{param_table.DOC_BEGIN}\n| new |\n{param_table.DOC_END}\nrest\n'


def test_ci_runs_the_readme_test_command():
    readme = (REPO / 'README.md').read_text(encoding='utf-8')
    ci = (REPO / '.ci' / 'run').read_text(encoding='utf-8')
    command = 'bash tools/setup_venv.sh && .venv/bin/python -m pytest -v'
    assert command in readme and command in ci


def test_readme_commands_use_the_venv_and_nothing_outside_the_clone():
    # the system's bare `python` lacks OpenCV and the ROS wheels; ../shared is not in a clone
    readme = (REPO / 'README.md').read_text(encoding='utf-8')
    bare = [line for line in readme.splitlines()
            if re.search(r'(^|[\s`(])python (tools/|-m )', line)]
    assert bare == []
    assert '../shared' not in readme
    for link in re.findall(r'\]\(([^)#]+)\)', readme):
        if '://' not in link:
            assert (REPO / link).exists(), link
