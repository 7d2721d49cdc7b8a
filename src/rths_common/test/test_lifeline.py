"""A launcher's children learn of its death, however it died (rths_common.lifeline)."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

CHILD = textwrap.dedent('''
    import signal, sys, time
    from rths_common import lifeline
    stop = sys.argv[1] == 'stop'
    signal.signal(signal.SIGTERM, lambda *_: open(sys.argv[2], 'w').write('SIGTERM'))
    print(lifeline.bind(stop=stop), flush=True)
    t_end = time.monotonic() + 20
    while time.monotonic() < t_end and not lifeline.lost():
        time.sleep(0.005)
    if lifeline.lost() and not stop:
        print('stdout is /dev/null now: no BrokenPipeError', flush=True)
        open(sys.argv[2], 'w').write('lost')
    time.sleep(0.2)
''')

LAUNCHER = textwrap.dedent('''
    import os, subprocess, sys, time
    from rths_common import lifeline
    child = subprocess.Popen([sys.executable, '-c', sys.argv[1], sys.argv[2], sys.argv[3]],
                             env=dict(os.environ, **lifeline.launcher_env()),
                             stdout=subprocess.PIPE, text=True, start_new_session=True)
    print(child.pid, child.stdout.readline().strip(), flush=True)
    time.sleep(60)
''')


@pytest.mark.parametrize('stop, expected', [(False, 'lost'), (True, 'SIGTERM')])
def test_sigkill_of_the_launcher_reaches_its_child(tmp_path, stop, expected):
    marker = tmp_path / 'marker'
    launcher = subprocess.Popen(
        [sys.executable, '-c', LAUNCHER, CHILD, 'stop' if stop else 'flag', str(marker)],
        stdout=subprocess.PIPE, text=True)
    pid, bound = launcher.stdout.readline().split()
    assert bound == 'True'
    os.kill(launcher.pid, signal.SIGKILL)          # nothing of the launcher runs after this
    launcher.wait()
    t_end = time.monotonic() + 1.0
    while not marker.exists() and time.monotonic() < t_end:
        time.sleep(0.01)
    assert marker.read_text() == expected
    for _ in range(200):                            # the child ends by itself
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            break
        if open(f'/proc/{pid}/stat').read().split(') ')[1][0] == 'Z':
            break
        time.sleep(0.01)
    else:
        os.kill(int(pid), signal.SIGKILL)
        raise AssertionError('the child outlived its launcher by 2 s')


def test_without_a_launcher_nothing_is_bound(monkeypatch):
    from rths_common import lifeline

    monkeypatch.delenv(lifeline.ENV, raising=False)
    assert lifeline.bind() is False and lifeline.lost() is False
