"""The hardware path end to end: Bridge + SafetySupervisor + UDP backend + controller emulator.

The emulator runs the simulated plant behind the UDP protocol (``rths controller-emulator``);
the bridge must behave as with the simulated backend: commands inside the limits pass
unchanged, an over-limit command never reaches the plant (hold, ramp to the safe position,
stop, deactivate), and every reply is used exactly once.
"""

import numpy as np
import pytest

from rths_actuator_bridge import safety
from rths_actuator_bridge.bridge import Bridge
from rths_actuator_bridge.emulator import ControllerEmulator
from rths_actuator_bridge.simulated import SimulatedPlant
from rths_actuator_bridge.udp import STAT_KEYS

FS = 1024.0
SAFE = -0.002          # [m] safe position != 0, so ending there is no coincidence
LIMITS = {'hold_time_s': 0.01, 'ramp_time_s': 0.2, 'acceleration_m_s2': 8.0,
          'safe_position_m': SAFE}


def _commands(n, amp=0.003, f=2.0):
    """``amp (1 - cos 2 pi f t)``: starts at rest, inside every limit of :data:`LIMITS`."""
    t = np.arange(n) / FS
    return amp * (1.0 - np.cos(2 * np.pi * f * t))


def _within_limits(applied, lim):
    p = np.concatenate([[0.0, 0.0], applied])
    v = np.diff(p) * lim.fs_hz
    a = np.diff(v) * lim.fs_hz
    assert np.all(np.isfinite(p)) and np.max(np.abs(p)) <= lim.stroke_m
    assert np.max(np.abs(v)) <= lim.velocity_m_s * (1 + 1e-9)
    assert np.max(np.abs(a)) <= lim.acceleration_m_s2 * (1 + 1e-9)


def _phases(states):
    return [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]


def _run_to_stop(bridge, commands):
    results = []
    for k, u in enumerate(commands):
        results.append(bridge.step(k, u))
        if bridge.state == safety.STOPPED:
            break
    return results


def test_bridge_over_udp_passes_good_commands_and_stops_safely_on_an_over_limit_one(
        emulator_process):
    port, stop_emulator = emulator_process
    bad_step, bad = 300, 0.3                       # beyond the 0.254 m stroke (seed 4.3.1)
    u = _commands(3000)
    u[bad_step] = bad
    b = Bridge()
    b.configure(dict(LIMITS, backend='udp', port=port, timeout_s=2.0))
    b.activate()
    lim = b.supervisor.limits
    results = _run_to_stop(b, u)
    states = [r.state for r in results]
    applied = np.array([r.applied[0] for r in results])
    assert len(applied) == len(results)

    # the good commands pass unchanged; the bad one is refused in its own step, with its value
    assert all(s == safety.ACTIVE for s in states[:bad_step])
    np.testing.assert_array_equal(applied[:bad_step], u[:bad_step])
    assert b.supervisor.fault == f'stroke limit: command {bad:g} m > 0.254 m at step {bad_step}'
    assert states[bad_step] == safety.HOLD and results[bad_step].fault == b.supervisor.fault
    assert _phases(states[bad_step:]) == [safety.HOLD, safety.RAMP, safety.STOPPED]
    assert not np.any(applied[bad_step:] == u[bad_step:len(applied)])
    _within_limits(applied, lim)
    assert applied[-1] == pytest.approx(SAFE, abs=1e-12)
    assert b.backend.lifecycle == 'inactive'
    stats = dict(b.backend.stats)
    assert b.step(len(results), u[len(results)]).applied.size == 0     # nothing after STOP
    assert b.backend.stats == stats

    # the controller measured exactly what the plant does under the applied commands: the
    # over-limit command never reached it, and every reply belongs to its own step
    plant = SimulatedPlant(dtm='valve2')
    ref = [plant.step(x) for x in applied]
    np.testing.assert_array_equal([r.displacement[0] for r in results],
                                  [m['table_disp'] for m in ref])
    np.testing.assert_array_equal([r.force[0] for r in results], [m['force'] for m in ref])
    np.testing.assert_array_equal([r.channels['rel_disp'] for r in results],
                                  [m['rel_disp'] for m in ref])
    assert np.max(np.abs([m['table_disp'] for m in ref])) > 1e-3     # the plant did move

    # datagram counts: one reply used per step, nothing lost, late, duplicated or malformed
    assert stats == dict.fromkeys(STAT_KEYS, 0) | {'received': len(applied)}
    emu = stop_emulator()
    assert emu == {'commands': len(applied), 'lost': 0, 'late': 0, 'duplicate': 0,
                   'malformed': 0, 'inactive': 0}


def test_lost_replies_over_udp_trip_the_bridge_which_stops_safely():
    """Three replies in a row are dropped on the wire: 'measurement lost', then a safe stop."""
    drop = {200, 201, 202}
    emu = ControllerEmulator({'dtm': 'valve4'}, faults={'drop': drop}).start()
    try:
        b = Bridge()
        b.configure(dict(LIMITS, backend='udp', port=emu.address[1], timeout_s=0.05,
                         max_invalid_measurements=3))
        b.activate()
        u = _commands(3000)
        results = _run_to_stop(b, u)
        assert b.backend.lifecycle == 'inactive'      # deactivated by the bridge at STOPPED
        b.close()
    finally:
        emu.stop()
    states = [r.state for r in results]
    applied = np.array([r.applied[0] for r in results])
    assert b.supervisor.fault == 'measurement lost: 3 non-finite readings in a row (limit 3)'
    assert states.index(safety.HOLD) == max(drop)
    assert all(np.isnan(results[k].displacement[0]) for k in drop)
    assert all(np.isfinite(r.displacement[0]) for k, r in enumerate(results) if k not in drop)
    assert _phases(states) == [safety.ACTIVE, safety.HOLD, safety.RAMP, safety.STOPPED]
    np.testing.assert_array_equal(applied[:max(drop) + 1], u[:max(drop) + 1])
    _within_limits(applied, b.supervisor.limits)
    assert applied[-1] == pytest.approx(SAFE, abs=1e-12)
    assert b.backend.stats['lost'] == len(drop)
    assert b.backend.stats['received'] == len(applied) - len(drop)
    assert emu.stats['commands'] == len(applied) and emu.stats['lost'] == 0
