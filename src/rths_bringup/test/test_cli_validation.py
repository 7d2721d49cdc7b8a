"""Validation before work: every numeric option of every ``rths`` command is checked while parsing.

A value outside the option's range (``rths_common.params.OPTION_RANGES``; the loop
rate's is ``LOOP_RATE_RANGE_HZ``) or not finite ends the command with one error
line naming the option and the range, exit code 2, before anything starts.
"""

import argparse

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
import pytest

from rths_bringup import cli
from rths_common.params import LOOP_RATE_RANGE_HZ, OPTION_RANGES

PARSER = cli.build_parser()


def _numeric_options(parser, path=()):
    """(command path, action) of every int/float option below ``parser``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _numeric_options(sub, path + (name,))
        elif getattr(action.type, '__name__', '') in ('int', 'float'):
            yield path, action


OPTIONS = list(_numeric_options(PARSER))


def _run(argv, capsys):
    """Return (exit code, stderr) of ``rths ARGV`` (argparse exits, commands return)."""
    try:
        code = cli.main(argv)
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err


def test_every_numeric_option_has_a_checked_type():
    assert len(OPTIONS) > 50
    for path, action in OPTIONS:
        assert hasattr(action.type, 'option_range'), (path, action.option_strings)
    ranged = {o for _, a in OPTIONS for o in a.option_strings if a.type.option_range}
    assert {'--rate', '--duration', '--taps', '--port'} <= ranged


@pytest.mark.parametrize('argv, needle', [
    (['bench', 'loop', '--rate', '1e9', '--duration', '1'],
     f'[{LOOP_RATE_RANGE_HZ[0]:g}, {LOOP_RATE_RANGE_HZ[1]:g}] Hz'),
    (['run', '--duration', '-1'], 'argument --duration: -1 is outside'),
    (['run', '--fc', 'nan'], 'not a finite number'),
    (['launch', '--timeout', 'inf'], 'not a finite number'),
    (['run', '--taps', '0'], 'argument --taps'),
    (['run', '--taps', '4.5'], 'invalid int value'),
])
def test_bad_option_is_refused_in_one_line_before_work(argv, needle, capsys, tmp_path,
                                                       monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = _run(argv, capsys)
    assert code == 2
    assert needle in err and err.count('\n') == 1 and 'Traceback' not in err, err
    assert err.startswith(f'rths {" ".join(argv[:2 if argv[0] == "bench" else 1])}: error:')
    assert list(tmp_path.iterdir()) == []   # nothing started, nothing written


@settings(max_examples=300, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(index=st.integers(0, len(OPTIONS) - 1),
       text=st.one_of(st.text(max_size=12), st.floats().map(repr), st.integers().map(str),
                      st.sampled_from(['nan', '-inf', '1e999', '0x10', '', ' 1', '1_000'])))
def test_any_text_for_any_numeric_option_is_parsed_or_refused_cleanly(index, text):
    """Fuzz: a value is either finite and in range, or refused with ArgumentTypeError."""
    _, action = OPTIONS[index]
    try:
        value = action.type(text)
    except argparse.ArgumentTypeError as err:
        assert '\n' not in str(err)
        return
    assert value == value and abs(value) != float('inf')
    spec = action.type.option_range
    if spec is not None:
        assert spec.range[0] <= value <= spec.range[1]


def test_option_ranges_use_the_loop_rate_range():
    assert OPTION_RANGES['--rate'].range == LOOP_RATE_RANGE_HZ


def test_review_of_a_bag_whose_metadata_is_not_a_mapping(tmp_path, capsys):
    """Without a data file to rebuild it from: one line naming the bag, nothing written."""
    bag = tmp_path / 'bag'
    bag.mkdir()
    for text in ('- a\n- b\n', 'just text\n', '{rosbag2_bagfile_information: 3}\n', ': : :\n'):
        (bag / 'metadata.yaml').write_text(text)
        code, err = _run(['review', str(bag), '--out', str(tmp_path / 'rev')], capsys)
        assert code == 2, err
        assert str(bag) in err and err.count('\n') == 1 and 'Traceback' not in err, err
        assert not (tmp_path / 'rev').exists()
        assert (bag / 'metadata.yaml').read_text() == text   # the damaged file is kept
