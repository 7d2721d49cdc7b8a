"""The composed container's end of a run: the actuator is parked before the bookkeeping.

After the last step the bridge ramps an external actuator to its safe position
(``BridgeNode.finish_run`` -> ``park``).  The numerical node's finish publishes the whole
response through the recording tee and writes its history and timing files.  Done
first, it left the servo controller without a command between the record's last step and
the ramp's first: 18.7 and 20.7 ms in two 10 s runs at 1024 Hz with the lab controller of
the system tests (2026-11-29, from the bag's stamps), 0.9 and 2.1 ms with the bridge first.
A controller whose command watchdog is shorter would trip.
"""

import pytest

from rths_bringup import container as ct


class Shell:
    def __init__(self, name, calls, **attrs):
        self.name, self.calls = name, calls
        self.__dict__.update(attrs)

    def finish_run(self, *args):
        self.calls.append(self.name)
        return 0


class Bridge(Shell):
    own = {'executor': 'events'}
    stopped = False

    def spin(self, executor, nodes, done):
        self.calls.append('spin')
        return True


def _container(calls):
    c = object.__new__(ct.Container)
    c.shells = {}
    c.bridge = Bridge('bridge', calls, lockstep=True)
    c.numerical = Shell('numerical', calls, finished=True, failed=False, node=None)
    c.compensator = Shell('compensator', calls, node=None)
    c.shells = {'numerical': c.numerical, 'bridge': c.bridge, 'compensator': c.compensator}
    c.bridge.node = None
    c.tee = None

    class Log:
        def info(self, text):
            calls.append('log')
    c.log = Log()
    return c


def test_the_bridge_finishes_and_parks_before_the_other_nodes(monkeypatch):
    calls = []
    monkeypatch.setattr(ct.ns, 'make_executor', lambda kind: None)
    assert _container(calls).run() == 0
    assert [c for c in calls if c != 'log'] == ['spin', 'bridge', 'numerical', 'compensator']


def test_the_other_nodes_still_finish_when_the_bridge_s_finish_fails(monkeypatch):
    calls = []
    monkeypatch.setattr(ct.ns, 'make_executor', lambda kind: None)
    c = _container(calls)

    def fails(*args):
        calls.append('bridge')
        raise OSError('timing file: disk full')
    c.bridge.finish_run = fails
    with pytest.raises(OSError, match='disk full'):       # the error still reaches the caller
        c.run()
    assert [c for c in calls if c != 'log'] == ['spin', 'bridge', 'numerical', 'compensator']
