"""The hardware path end to end: Bridge + SafetySupervisor + UDP backend + controller emulator.

The emulator runs the simulated plant behind the UDP protocol (``rths controller-emulator``);
the bridge must behave as with the simulated backend: commands inside the limits pass
unchanged, an over-limit command never reaches the plant (hold, ramp to the safe position,
stop, deactivate), and every reply is used exactly once.
"""

import time

import numpy as np
import pytest

from rths_actuator_bridge import safety
from rths_actuator_bridge.bridge import Bridge
from rths_actuator_bridge.emulator import ControllerEmulator
from rths_actuator_bridge.simulated import SimulatedPlant

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
    assert stats['replies'] == len(applied)
    assert all(v == 0 for k, v in stats.items() if k not in ('replies', 'worst_reply_ms'))
    emu = stop_emulator()
    assert emu['commands'] == len(applied)
    assert all(v == 0 for k, v in emu.items() if k != 'commands')


@pytest.mark.parametrize('version', [1, 2])
def test_up_to_max_invalid_bad_replies_are_filled_and_the_loop_runs_on(version):
    """A lost, a malformed and a late reply, and max_invalid_measurements (3) lost in a row.

    The numerical substructure closes the loop on the published force: every step gets a
    finite force (the gap policy holds the last valid reading), the run completes, and the
    counts name what happened.  (Before the gap policy, the first lost reply published a NaN
    force and the numerical core refused it: "measured force [nan] ... stopping the run".)
    """
    from rths_numerical.stepping import NumericalCore
    from rths_numerical.substructure import make_substructure

    faults = {'drop': {100, 300, 301, 302}, 'corrupt': {200}, 'delay_s': {400: 0.06}}  # > timeout_s
    emu = ControllerEmulator({'specimen': 'valve4'}, faults=faults).start()
    core = NumericalCore(make_substructure({'model': 'sdof', 'record': 'harmonic', 'scale': 0.05,
                                            'duration_s': 0.6, 'fs_hz': FS}))
    b = Bridge()
    b.configure(dict(LIMITS, backend='udp', port=emu.address[1], timeout_s=0.05,
                     protocol_version=version))
    b.activate()
    try:
        x = core.first_displacement()
        results = []
        for k in range(core.sub.n_steps):
            r = b.step(k, x)
            results.append(r)
            out = core.step(k, r.force)          # raises on a non-finite force
            if out.done:
                break
            x = out.arrays[0]
        counts = b.backend.counts()
        seen = []          # each step as it happens (the node publishes it then)
        parked = b.park(on_step=lambda r: seen.append((r.step, b.backend.lifecycle)))
    finally:
        b.close()
        emu.stop()
    assert core.done() and len(results) == core.sub.n_steps
    assert all(r.state == safety.ACTIVE for r in results)
    assert [k for k, r in enumerate(results) if r.filled] == [100, 200, 300, 301, 302, 400]
    assert results[301].force[0] == results[299].force[0]        # held
    assert counts['replies_lost'] == 5 and counts['replies_late'] == 1
    assert counts['replies_malformed'] == 1 and counts['protocol_version'] == version
    # the end of the run: brake, ramp to the safe position, then DEACTIVATE
    assert [r.state for r in parked][-1] == safety.STOPPED
    assert parked[-1].applied[0] == pytest.approx(SAFE, abs=1e-12)
    _within_limits(np.array([r.applied[0] for r in results + parked]), b.supervisor.limits)
    assert b.backend.lifecycle == 'inactive' and not b.supervisor.fault
    assert [k for k, _ in seen] == [r.step for r in parked] == list(
        range(len(results), len(results) + len(parked)))
    assert all(state == 'active' for _, state in seen[:-1])      # before the deactivation


def test_realtime_steps_never_wait_for_a_reply_past_the_tick():
    """Realtime: a reply 50 ms late does not stretch the step; it is counted late."""
    emu = ControllerEmulator({'specimen': 'valve4'}, faults={'delay_s': {20: 0.05}},
                             rt_priority=50).start()
    b = Bridge()
    # (a loaded machine may delay a few replies in a row: this test is not about the stall)
    b.configure(dict(LIMITS, backend='udp', port=emu.address[1], timeout_s=1.0,
                     max_invalid_measurements=100))
    b.activate()
    try:
        took, results = [], []
        for k, u in enumerate(_commands(200)):
            t0 = time.monotonic()
            results.append(b.step(k, u, realtime=True))
            took.append(time.monotonic() - t0)
            time.sleep(1.0 / FS)
        assert results_state(b) == safety.ACTIVE
        assert took[20] < 0.035                      # waited about half a period, not 50 ms
        assert results[20].filled == 1
        # (a loaded machine may make other replies late too: each is counted the same way)
        assert b.backend.stats['replies_late'] >= 1
        assert b.backend.stats['replies_late'] + b.backend.stats['replies_lost'] == sum(
            r.filled for r in results)
    finally:
        b.close()
        emu.stop()


def results_state(bridge):
    """Return the supervisor's state."""
    return bridge.supervisor.state


def test_more_than_max_invalid_lost_replies_are_a_controller_stall_and_a_safe_stop():
    """Four replies in a row are dropped on the wire (limit 3): controller stall, safe stop."""
    drop = {200, 201, 202, 203}
    emu = ControllerEmulator({'specimen': 'valve4'}, faults={'drop': drop}).start()
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
    assert b.supervisor.fault == ('controller stall: no usable reply: 4 in a row (more than '
                                  'max_invalid_measurements 3)')
    assert states.index(safety.HOLD) == max(drop)
    assert all(results[k].filled for k in drop)
    assert all(np.isfinite(r.displacement[0]) for r in results)
    assert _phases(states) == [safety.ACTIVE, safety.HOLD, safety.RAMP, safety.STOPPED]
    np.testing.assert_array_equal(applied[:max(drop) + 1], u[:max(drop) + 1])
    _within_limits(applied, b.supervisor.limits)
    assert applied[-1] == pytest.approx(SAFE, abs=1e-12)
    assert b.backend.stats['replies_lost'] == len(drop)
    assert b.backend.stats['replies'] == len(applied) - len(drop)
    assert emu.stats['commands'] == len(applied) and emu.stats['lost'] == 0
