"""The bridge's command delay line (``command_delay_steps`` = D).

The command of step k is written at tick k + D.
"""

import numpy as np
import pytest

from rths_actuator_bridge.bridge import Bridge, DelayLine


def test_delay_line_returns_each_command_d_ticks_later():
    line = DelayLine(3)
    for k in range(10):
        line.receive(k, f'c{k}')
        got = line.due(k)
        # ticks 0..2 come before command 0 is due: they write command 0 (position at rest)
        assert got == ('c0' if k < 3 else f'c{k - 3}'), k


def test_delay_line_reports_a_missing_command_and_forgets_stale_ones():
    line = DelayLine(2)
    for k in (0, 1, 2):
        line.receive(k, k)
    assert [line.due(t) for t in range(5)] == [0, 0, 0, 1, 2]
    assert line.due(5) is None          # command 3 never arrived: a deadline miss
    line.receive(3, 3)                  # ... and arrives after its tick
    line.receive(4, 4)
    assert line.due(6) == 4
    assert line.pending == {}           # the late command 3 is dropped, not written later


def test_zero_delay_is_the_plain_loop():
    line = DelayLine(0)
    line.receive(0, 'a')
    assert line.due(0) == 'a'
    assert line.due(1) is None


@pytest.mark.parametrize('bad', [-1, 1.5, 'three', True, 10**6])
def test_bad_delay_is_named(bad):
    with pytest.raises(ValueError, match='command_delay_steps'):
        DelayLine(bad)


def _run(delay_steps, commands):
    bridge = Bridge()
    bridge.configure({'backend': 'simulated', 'fs_hz': 1024.0, 'seed': 1,
                      'command_delay_steps': delay_steps})
    bridge.activate()
    applied, measured = [], []
    for k, c in enumerate(commands):
        bridge.receive(k, np.array([c]))
        result = bridge.step(k, bridge.due(k))
        applied.append(result.applied[0])
        measured.append(result.displacement[0])
    return np.array(applied), np.array(measured)


def test_bridge_with_delay_is_the_plant_delayed_by_d_steps():
    """Measured displacement with D = 4 is that with D = 0, four steps later (P(z) z^-4)."""
    t = np.arange(600) / 1024.0
    u = 0.004 * np.sin(2 * np.pi * 2.0 * t) * np.minimum(t / 0.2, 1.0)
    applied0, measured0 = _run(0, u)
    applied4, measured4 = _run(4, u)
    np.testing.assert_array_equal(applied4[4:], applied0[:-4])
    np.testing.assert_allclose(measured4[4:], measured0[:-4], rtol=0, atol=1e-12)
    assert np.all(applied4[:4] == u[0])
