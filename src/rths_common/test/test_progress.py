"""The shared progress line: redrawn in place on a terminal, silent in CI logs."""

import io

from rths_common import progress


class _Tty(io.StringIO):
    def isatty(self):
        return True


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_terminal_line_shows_steps_rate_and_eta(monkeypatch):
    monkeypatch.delenv('RTHS_PROGRESS', raising=False)
    out, clock = _Tty(), _Clock()
    with progress.Progress(100, 'replay', 'msgs', stream=out, clock=clock) as bar:
        for k in range(1, 101):
            clock.t = k * 0.05                    # 20 steps/s
            bar.update(k)
    text = out.getvalue()
    assert text.startswith('\rreplay: 1/100 msgs (  1 %)') and text.endswith('\n')
    assert 'ETA 0:04' in text                     # 80 steps left at 20/s, at step 20
    assert text.count('\r') <= 100 * 0.05 / 0.2 + 2   # at most one redraw per 0.2 s
    assert text.rstrip('\n').split('\r')[-1].startswith('replay: 100/100 msgs (100 %), 20/s')


def test_not_a_tty_writes_nothing(monkeypatch):
    monkeypatch.delenv('RTHS_PROGRESS', raising=False)
    out = io.StringIO()
    with progress.Progress(10, 'x', stream=out) as bar:
        for _ in range(10):
            bar.advance()
    bar.report(5, 20)
    assert out.getvalue() == '' and bar.total == 20


def test_rths_progress_forces_it_on_or_off(monkeypatch):
    monkeypatch.setenv('RTHS_PROGRESS', '1')
    assert progress.enabled(io.StringIO())
    monkeypatch.setenv('RTHS_PROGRESS', '0')
    assert not progress.enabled(_Tty())


def test_eta_and_unknown_totals():
    assert progress.format_eta(3725) == '1:02:05' and progress.format_eta(None) == '--:--'
    assert progress.line('run', 50, 0, 2.0, 'steps') == 'run: 50 steps, 25/s'
    assert progress.line('run', 0, 10, 0.0).endswith('ETA --:--')
