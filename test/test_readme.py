"""The README stays true to the code; the parameter table of docs/ is the generated one."""

import re
from pathlib import Path

import pytest

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


def test_param_table_doc_with_a_missing_file_is_one_line(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]):
    assert param_table.main(['--doc', str(tmp_path / 'none.md')]) == 1
    out, err = capsys.readouterr()
    assert out == '' and err == f'error: {tmp_path / "none.md"}: No such file or directory\n'


def test_param_table_doc_says_what_it_wrote(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    doc = tmp_path / 'parameters.md'
    doc.write_text(f'intro\n{param_table.DOC_BEGIN}\nold\n{param_table.DOC_END}\n')
    assert param_table.main(['--doc', str(doc)]) == 0
    rows = len(param_table.parameter_table().splitlines()) - 2
    assert capsys.readouterr().out == f'{doc}: wrote the table of {rows} parameters\n'
    assert param_table.main(['--doc', str(doc)]) == 0
    assert capsys.readouterr().out == f'{doc}: the table of {rows} parameters is current\n'


def test_param_table_doc_outside_the_repository_is_the_repositorys(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]):
    monkeypatch.chdir(tmp_path)   # (the table is current: test_parameter_table_is_...)
    assert param_table.main(['--doc']) == 0
    assert capsys.readouterr().out.startswith(f'{REPO / "docs" / "parameters.md"}: ')


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


#: Where a path written in the README may start: the repository's top level, or a subpackage
#: of obstacle_detection (``pipeline/parallel.py``). Generated folders (.venv, out) are not here.
_TOP = ('obstacle_detection', 'tools', 'test', 'params', 'launch', 'resource', 'docs', '.ci')
_SUBPACKAGES = ('pipeline', 'ros', 'sim', 'viz', 'cli', 'evaluation')


def readme_paths(text: str) -> list[str]:
    """Return the words in backticks (inline and fenced code) that look like repository paths.

    A word looks like one when it contains '/' and starts with a top-level folder of the
    repository or a subpackage of obstacle_detection; patterns with ``<`` or ``{`` are left out.
    """
    fenced = re.findall(r'^```[^\n]*\n(.*?)^```', text, flags=re.M | re.S)
    prose = re.sub(r'^```.*?^```', '', text, flags=re.M | re.S)
    # a code span opens and closes with runs of as many backticks (an unmatched run is text)
    inline = [m.group(2) for m in re.finditer(r'(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)', prose,
                                              flags=re.S)]
    paths = []
    for span in [*fenced, *inline]:
        for word in span.split():
            word = word.strip('.,;:()[]\'"')
            first = word.split('/')[0]
            if '/' in word and '://' not in word and not set('<{$') & set(word) and \
                    first in (*_TOP, *_SUBPACKAGES):
                paths.append(word)
    return paths


def test_readme_paths_finds_inline_and_fenced_paths() -> None:
    text = ('see `obstacle_detection/x.py` and `.venv/bin/python tools/y.py --out a/b`\n'
            '```bash\nbash tools/z.sh params/*.yaml\n```\n`out/demo/` `` | `pipeline/w.py`\n')
    assert readme_paths(text) == ['tools/z.sh', 'params/*.yaml', 'obstacle_detection/x.py',
                                  'tools/y.py', 'pipeline/w.py']


#: (document, path): files a history names that are gone on purpose.
_GONE = {('docs/threads.md', 'pipeline/parallel.py'), ('docs/speed.md', 'pipeline/parallel.py')}


@pytest.mark.parametrize('document', ['README.md', *sorted(
    str(p.relative_to(REPO)) for p in (REPO / 'docs').glob('*.md'))])
def test_every_repository_path_in_the_manual_exists(document: str) -> None:
    text = (REPO / document).read_text(encoding='utf-8')
    missing = []
    for path in readme_paths(text):
        root = REPO / 'obstacle_detection' if path.split('/')[0] in _SUBPACKAGES else REPO
        if not list(root.glob(path.rstrip('/'))) and (document, path) not in _GONE:
            missing.append(path)
    assert missing == []
