"""What the command lines share (obstacle_detection/cli/support.py): the domain option, pinning."""

import argparse
import subprocess
import sys

import pytest

from obstacle_detection.cli import support


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='tool')
    support.add_domain_id_option(parser, 'ROS_DOMAIN_ID')
    return parser


@pytest.mark.parametrize('value', ['0', '57', '232'])
def test_domain_ids_in_range_are_taken(value: str) -> None:
    assert _parser().parse_args(['--domain-id', value]).domain_id == int(value)


def test_the_default_domain_is_one_of_the_runs_own(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv('ROS_DOMAIN_ID', raising=False)
    assert 100 <= _parser().parse_args([]).domain_id <= 200


@pytest.mark.parametrize('tool', ['demo', 'latency_bench'])
def test_an_exported_domain_is_the_default(tool: str, monkeypatch: pytest.MonkeyPatch) -> None:
    # a user working in their own domain sees the demo's topics there
    import importlib

    module = importlib.import_module(f'obstacle_detection.tools.{tool}')
    monkeypatch.setenv('ROS_DOMAIN_ID', '37')
    assert module.build_parser().parse_args([]).domain_id == 37
    assert module.build_parser().parse_args(['--domain-id', '12']).domain_id == 12


def test_a_bad_exported_domain_is_named(monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv('ROS_DOMAIN_ID', '300')
    with pytest.raises(SystemExit) as exit_info:
        _parser().parse_args([])
    assert exit_info.value.code == 2
    assert "ROS_DOMAIN_ID='300' (from the environment) must be in 0..232" in \
        capsys.readouterr().err


@pytest.mark.parametrize('value, message', [('233', 'must be in 0..232, got 233'),
                                            ('-1', 'must be in 0..232, got -1'),
                                            ('seven', "integer in 0..232, got 'seven'")])
def test_domain_ids_out_of_range_are_refused_with_the_reason(
        value: str, message: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        _parser().parse_args(['--domain-id', value])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_pin_one_cpu_leaves_the_process_on_one_cpu() -> None:
    # in a child process: pinning the test process would slow every later test
    code = ('import os; from obstacle_detection.cli import support; '
            'print(support.pin_one_cpu()); print(len(os.sched_getaffinity(0)))')
    run = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    said, cpus = run.stdout.splitlines()
    assert said.startswith('pinned to CPU ') and 'OpenCV threads = 1' in said
    assert cpus == '1'


def test_int_in_parses_integers_in_range_and_names_the_bound() -> None:
    at_least_one = support.int_in(1)
    assert at_least_one('3') == 3
    for text, words in (('0', 'must be >= 1, got 0'), ('x', "must be an integer >= 1, got 'x'")):
        with pytest.raises(argparse.ArgumentTypeError, match=words):
            at_least_one(text)
    with pytest.raises(argparse.ArgumentTypeError, match=r'must be in 0\.\.232, got 233'):
        support.domain_id('233')


#: Words of the code, not of a user: reST markup, exception class names, issue numbers.
INTERNAL = (':func:', ':class:', '``', 'Error)', 'issue ', 'FusionParams(')


@pytest.mark.parametrize('tool', ['bag_convert', 'bag_play', 'bag_process', 'demo',
                                  'estimate_mount', 'evaluate', 'latency_bench', 'sweep'])
def test_help_holds_no_internal_words(tool: str) -> None:
    import importlib

    parser = importlib.import_module(f'obstacle_detection.tools.{tool}').build_parser()
    texts = [parser.format_help()]
    for action in parser._actions:   # sub-commands (bag_convert SOURCE -h)
        if isinstance(action, argparse._SubParsersAction):
            texts += [sub.format_help() for sub in action.choices.values()]
    for text in texts:
        assert not [word for word in INTERNAL if word in text], text
