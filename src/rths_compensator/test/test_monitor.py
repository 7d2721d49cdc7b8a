"""The online stability monitor: its estimates, a stop on injected faults, no alarm when nominal."""

import numpy as np
import pytest

from rths_compensator.monitor import OK, STOP, WARN, MonitorSettings, StabilityMonitor

FS = 4096.0


def record(seconds, seed=0):
    """Return a target [m]: three modes of a building (1.1, 2.7, 4.9 Hz), random phases."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * FS)) / FS
    phases = rng.uniform(0, 2 * np.pi, 3)
    return (4e-3 * np.sin(2 * np.pi * 1.1 * t + phases[0])
            + 2e-3 * np.sin(2 * np.pi * 2.7 * t + phases[1])
            + 1e-3 * np.sin(2 * np.pi * 4.9 * t + phases[2]))


def delayed(x, delay_ms, gain=1.0, change_at=None, extra_ms=0.0, extra_gain=1.0, seed=1):
    """Measured = gain x(t - delay) + 4 um noise; from ``change_at`` the change applies."""
    rng = np.random.default_rng(seed)
    k = np.arange(x.size)
    d = np.full(x.size, delay_ms * 1e-3 * FS)
    g = np.full(x.size, gain)
    if change_at is not None:
        d[change_at:] += extra_ms * 1e-3 * FS
        g[change_at:] *= extra_gain
    return g * np.interp(k - d, k, x, left=0.0) + 4e-6 * rng.standard_normal(x.size)


def run(x, y, settings=None):
    mon = StabilityMonitor(FS, settings)
    levels = np.array([mon.step(a, b).level for a, b in zip(x, y, strict=True)])
    return mon, levels


def test_estimates_the_delay_gain_and_error_of_a_known_lag():
    x = record(4.0)
    mon, levels = run(x, delayed(x, 2.0, gain=0.9))
    assert mon.state.delay_ms == pytest.approx(2.0, abs=0.3)
    assert mon.state.gain == pytest.approx(0.9, abs=0.02)
    assert 5.0 < mon.state.error_pct < 20.0
    assert mon.state.ti > 0          # the actuator lags: the x-y loop encloses area
    assert not np.any(levels == STOP)


@pytest.mark.parametrize('seed', range(5))
def test_no_alarm_on_a_nominal_compensated_actuator(seed):
    x = record(20.0, seed)
    _, levels = run(x, delayed(x, 0.6, gain=1.01, seed=seed))   # the FIR's residual delay
    assert np.all(levels == OK)


@pytest.mark.parametrize('seed', range(5))
def test_a_delay_step_of_8_ms_stops_within_half_a_second(seed):
    x = record(12.0, seed)
    change = int(6.0 * FS)
    _, levels = run(x, delayed(x, 0.6, change_at=change, extra_ms=8.0, seed=seed))
    assert np.all(levels[:change] == OK)
    stop = int(np.argmax(levels == STOP))
    assert levels[stop] == STOP and (stop - change) / FS <= 0.5
    assert np.any(levels[change:stop] == WARN)          # warned before it stopped
    assert np.all(levels[stop:] == STOP)                # latched


def test_a_gain_jump_of_40_percent_stops():
    x = record(8.0)
    change = int(4.0 * FS)
    _, levels = run(x, delayed(x, 0.6, change_at=change, extra_gain=1.6))
    stop = int(np.argmax(levels == STOP))
    assert levels[stop] == STOP and (stop - change) / FS <= 0.5


def test_a_non_finite_measurement_stops_and_quiet_input_never_alarms():
    x = record(3.0)
    mon = StabilityMonitor(FS)
    assert mon.step(x[0], float('nan')).level == STOP
    _, levels = run(1e-6 * x / np.max(np.abs(x)), np.zeros(x.size))   # 1 um: not excited
    assert np.all(levels == OK)


def test_settings_are_checked():
    with pytest.raises(ValueError, match='stop threshold below'):
        StabilityMonitor(FS, MonitorSettings(warn_delay_ms=6.0, stop_delay_ms=5.0))
    with pytest.raises(ValueError, match='window_s'):
        StabilityMonitor(FS, MonitorSettings(window_s=0.0))
