"""The rths command line: every package's commands are registered, errors are clean."""

import argparse
import os

import pytest

from rths_bringup import cli

EXPECTED = {'launch', 'bag', 'run', 'review', 'bench', 'identify', 'design', 'compensate',
            'simulate', 'study', 'characterise-dtm', 'controller-emulator', 'discrepancy'}
BENCHES = {'compensators', 'dtm', 'numerical', 'loop', 'discrepancy'}


def _choices(parser):
    action = next(a for a in parser._actions if a.dest in ('command', 'bench'))
    return action.choices


def test_every_command_and_benchmark_is_registered():
    parser = cli.build_parser()
    commands = _choices(parser)
    assert EXPECTED <= set(commands)
    assert BENCHES <= set(_choices(commands['bench']))


def test_user_error_exits_2_with_a_message(tmp_path, capsys):
    code = cli.main(['bag', 'info', str(tmp_path / 'nope')])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith('rths bag: error:') and 'does not exist' in err


def test_help_exits_cleanly():
    with pytest.raises(SystemExit) as exc:
        cli.main(['--help'])
    assert exc.value.code == 0


def _all_parsers(parser, path=()):
    """(command path, parser) of ``parser`` and of every sub-command below it."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _all_parsers(sub, path + (name,))


def test_every_command_help_formats(capsys):
    """``rths ... --help`` works for every (sub-)command.

    ``rths ... --help`` works for every (sub-)command (a stray '%' in a help text broke
    ``rths study --help``: argparse %-formats help strings).
    """
    paths = []
    for path, parser in _all_parsers(cli.build_parser()):
        assert parser.format_help().startswith('usage:'), path   # what --help prints
        paths.append(path)
    assert ('study',) in paths and ('bench', 'distributed') in paths


def test_long_commands_and_every_bench_take_quiet(monkeypatch):
    """Issue 17: --quiet on the commands that show progress turns it off (here and in children)."""
    parser = cli.build_parser()
    for argv in (['run'], ['launch'], ['review', 'BAG'], ['study', 'dtm-tuning'],
                 ['discrepancy', '--scenario', 'specimen', '--measured', 'M', '--out', 'O'],
                 ['bench', 'loop'], ['bench', 'adaptive', '--out', 'D'],
                 ['bench', 'discrepancy', '--out', 'F']):
        assert parser.parse_args(argv + ['--quiet']).quiet, argv
    with pytest.raises(SystemExit):            # a quick command has no progress to silence
        parser.parse_args(['bag', 'info', 'BAG', '--quiet'])
    monkeypatch.setenv('RTHS_PROGRESS', 'log')
    assert cli.main(['review', '/nonexistent/bag']) == 2
    assert os.environ['RTHS_PROGRESS'] == 'log'           # without --quiet: left alone
    assert cli.main(['review', '/nonexistent/bag', '--quiet']) == 2
    assert os.environ['RTHS_PROGRESS'] == '0'             # inherited by the nodes too
