"""The shared progress line: redrawn in place on a terminal, a few plain lines in CI logs."""

import io
import os
import pty
import select

import pytest

from rths_common import progress


class _Tty(io.StringIO):
    def isatty(self):
        return True


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@pytest.fixture(autouse=True)
def _no_forced_mode(monkeypatch):
    monkeypatch.delenv('RTHS_PROGRESS', raising=False)


def _run(stream, steps=100, dt=0.05, **kwargs):
    clock = _Clock()
    with progress.Progress(steps, 'replay', 'msgs', stream=stream, clock=clock, **kwargs) as bar:
        for k in range(1, steps + 1):
            clock.t = k * dt
            bar.update(k)
    return bar


def test_terminal_line_shows_steps_rate_and_eta():
    out = _Tty()
    _run(out)                                     # 20 steps/s for 5 s
    text = out.getvalue()
    assert text.startswith('\rreplay: 1/100 msgs (  1 %)') and text.endswith('\n')
    assert 'ETA 0:04' in text                     # 80 steps left at 20/s, at step 20
    assert text.count('\r') <= 100 * 0.05 / 0.2 + 2   # at most one redraw per 0.2 s
    assert text.rstrip('\n').split('\r')[-1].startswith('replay: 100/100 msgs (100 %), 20/s')
    assert text.count('\n') == 1                  # one line, redrawn


def test_a_real_pseudo_terminal_gets_the_redrawn_line():
    master, slave = pty.openpty()
    try:
        with os.fdopen(slave, 'w', closefd=False) as tty:
            assert progress.mode(tty) == 'tty'
            _run(tty, steps=10, dt=0.3)
        chunks = []
        while select.select([master], [], [], 0.5)[0]:   # everything the terminal got
            chunks.append(os.read(master, 65536))
        text = b''.join(chunks).decode()
    finally:
        os.close(master)
        os.close(slave)
    assert text.startswith('\rreplay: 1/10 msgs') and '10/10 msgs (100 %)' in text


def test_a_log_gets_a_plain_line_every_10_percent_and_the_end():
    out = io.StringIO()                           # not a TTY: CI logs, pipes
    _run(out, steps=100, dt=0.05)                 # 5 s: 10 % = 0.5 s, lines >= 1 s apart
    lines = out.getvalue().splitlines()
    assert '\r' not in out.getvalue()
    assert 4 <= len(lines) <= 6, lines            # at 1, 2, 3, 4 s and the end
    assert lines[0].startswith('replay: 20/100 msgs ( 20 %), 20/s, ETA 0:04')
    assert lines[-1].startswith('replay: 100/100 msgs (100 %)')


def test_a_slow_log_gets_a_line_every_10_percent_or_10_seconds():
    out = io.StringIO()
    _run(out, steps=1000, dt=0.1)                 # 100 s: a line per 10 % (10 s)
    assert len(out.getvalue().splitlines()) == 10
    out = io.StringIO()
    _run(out, steps=10000, dt=0.1, log_pct=50.0)  # 1000 s: the 10 s heartbeat rules
    assert 95 <= len(out.getvalue().splitlines()) <= 101


def test_a_quick_job_writes_nothing_to_a_log():
    out = io.StringIO()
    _run(out, steps=1000, dt=0.0009)              # under a second
    assert out.getvalue() == ''


def test_quiet_and_rths_progress_force_the_mode(monkeypatch):
    monkeypatch.setenv('RTHS_PROGRESS', '')          # restored after the test
    parser = __import__('argparse').ArgumentParser()
    progress.add_quiet_argument(parser)
    progress.apply_quiet(parser.parse_args(['--quiet']))
    assert os.environ['RTHS_PROGRESS'] == '0'
    out = _Tty()
    bar = _run(out)
    assert out.getvalue() == '' and bar.done == 100
    monkeypatch.setenv('RTHS_PROGRESS', '1')
    assert progress.enabled(io.StringIO())
    monkeypatch.setenv('RTHS_PROGRESS', 'log')
    assert progress.mode(_Tty()) == 'log'


def test_other_output_goes_around_the_terminal_line():
    out, clock = _Tty(), _Clock()
    bar = progress.Progress(10, 'run', stream=out, clock=clock)
    bar.update(3)
    bar.write('[launch] node started')
    drawn = 'run: 3/10 ( 30 %), 0/s, ETA --:--'
    assert out.getvalue() == ('\r' + drawn + '\r' + ' ' * len(drawn) + '\r'
                              '[launch] node started\n\r' + drawn)


def test_step_notes_are_silenced_with_progress(monkeypatch):
    out = io.StringIO()
    progress.Progress(0, 'io', stream=out).note('linear baseline: decimation 4')
    assert out.getvalue() == 'linear baseline: decimation 4\n'
    monkeypatch.setenv('RTHS_PROGRESS', '0')           # --quiet
    out = io.StringIO()
    bar = progress.Progress(0, 'io', stream=out)
    bar.note('linear baseline: decimation 4')
    bar.write('a result line')
    assert out.getvalue() == 'a result line\n'


def test_track_counts_the_items():
    out = io.StringIO()
    clock = _Clock()

    def tick():
        clock.t += 1.5
        return clock.t

    assert list(progress.track(range(4), 'runs', stream=out, clock=tick)) == [0, 1, 2, 3]
    assert out.getvalue().splitlines()[-1] == 'runs: 4/4 (100 %), 1.5 s each, done in 0:06'


def test_eta_and_unknown_totals():
    assert progress.format_eta(3725) == '1:02:05' and progress.format_eta(None) == '--:--'
    assert progress.line('run', 50, 0, 2.0, 'steps') == 'run: 50 steps, 25/s, 0:02 elapsed'
    assert progress.line('run', 0, 10, 0.0).endswith('ETA --:--')
