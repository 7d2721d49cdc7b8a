"""Every safety rule is violated once; nothing unsafe may reach the plant."""

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from rths_actuator_bridge import safety
from rths_actuator_bridge.bridge import Bridge
from rths_actuator_bridge.safety import SafetyLimits, SafetySupervisor

FS = 1024.0
LIM = SafetyLimits(fs_hz=FS, stroke_m=0.254, velocity_m_s=0.5, acceleration_m_s2=20.0,
                   hold_time_s=0.01, ramp_time_s=0.5, watchdog_steps=5)


class RecordingBackend:
    """Stands in for the plant: records every command the supervisor lets through."""

    def __init__(self):
        self.sent = []


def _assert_within_limits(sent, lim, start=0.0):
    """Positions, velocities and accelerations of a sent command sequence respect ``lim``."""
    p = np.concatenate([[start, start], np.ravel(sent)])
    assert np.all(np.isfinite(p))
    assert np.max(np.abs(p)) <= lim.stroke_m * (1 + 1e-9)
    v = np.diff(p) * lim.fs_hz
    a = np.diff(v) * lim.fs_hz
    assert np.max(np.abs(v)) <= lim.velocity_m_s * (1 + 1e-9)
    assert np.max(np.abs(a)) <= lim.acceleration_m_s2 * (1 + 1e-9)


def _run(commands, lim=LIM, extra_steps=2000):
    sup = SafetySupervisor(lim)
    sup.configure()
    sup.activate(0.0)
    sent, states, faults = [], [], []
    for k, c in enumerate(list(commands) + [None] * extra_steps):
        out, state, fault = sup.filter(k, c)
        if out is not None:
            sent.append(out[0])
        states.append(state)
        faults.append(fault)
        if state == safety.STOPPED:
            break
    return np.array(sent), states, faults, sup


def _smooth(n, amp=0.02, f=1.0):
    t = np.arange(n) / FS
    return amp * np.sin(2 * np.pi * f * t) ** 2


def test_state_numbers_match_loopstatus_msg():
    # rths_msgs/LoopStatus: SAFETY_OK 0, HOLD 1, RAMP 2, STOPPED 3, INACTIVE 4
    assert (safety.OK, safety.ACTIVE, safety.HOLD, safety.RAMP, safety.STOPPED,
            safety.INACTIVE) == (0, 0, 1, 2, 3, 4)


def test_inactive_supervisor_sends_nothing():
    sup = SafetySupervisor(LIM)
    out, state, _ = sup.filter(0, np.array([0.01]))
    assert out is None and state == safety.INACTIVE


def test_valid_commands_pass_unchanged():
    u = _smooth(500)
    sent, states, faults, _ = _run(u, extra_steps=0)
    np.testing.assert_array_equal(sent, u)
    assert set(states) == {safety.ACTIVE} and not any(faults)


@pytest.mark.parametrize('bad, limit_text', [
    (0.31, 'stroke limit: command 0.31 m > 0.254 m'),
    (np.nan, 'non-finite command'),
    (np.inf, 'non-finite command'),
    (-1e300, 'stroke limit'),
])
def test_out_of_range_command_is_never_sent(bad, limit_text):
    u = list(_smooth(300))
    u[200] = bad
    sent, states, faults, sup = _run(u)
    assert bad not in sent
    assert limit_text in sup.fault and 'step 200' in sup.fault
    assert states[200] == safety.HOLD
    assert safety.RAMP in states and states[-1] == safety.STOPPED
    assert sent[-1] == pytest.approx(LIM.safe_position_m, abs=1e-12)
    _assert_within_limits(sent, LIM)


def test_velocity_limit():
    u = list(_smooth(300))
    u[150] = u[149] + 0.6 / FS + 0.0      # 0.6 m/s > 0.5 m/s
    sent, states, faults, sup = _run(u)
    assert sup.fault.startswith('velocity limit: command velocity')
    assert '> 0.5 m/s' in sup.fault
    _assert_within_limits(sent, LIM)


def test_acceleration_limit():
    u = list(_smooth(300))
    v = (u[149] - u[148])
    u[150] = u[149] + v + 25.0 / FS ** 2   # 25 m/s^2 > 20 m/s^2
    sent, states, faults, sup = _run(u)
    assert sup.fault.startswith('acceleration limit')
    _assert_within_limits(sent, LIM)


def test_braking_room_inside_the_stroke():
    """Near the stroke end at speed, a command that cannot stop in time is refused."""
    lim = SafetyLimits(fs_hz=FS, velocity_m_s=0.5, acceleration_m_s2=2.0, hold_time_s=0.01)
    n = int(0.5 * FS)
    speed_up = np.cumsum(np.minimum(np.arange(1, n) * 2.0 / FS, 0.4)) / FS   # to 0.4 m/s
    u = np.concatenate([speed_up, speed_up[-1] + np.cumsum(np.full(2000, 0.4 / FS))])
    sent, states, faults, sup = _run(u, lim)
    # 0.4 m/s needs 0.04 m to stop at 2 m/s^2: refused from ~0.214 m on, not at 0.254 m
    assert 'cannot brake' in sup.fault
    assert np.max(np.abs(sent)) <= 0.254
    assert np.max(np.abs(sent)) > 0.2
    _assert_within_limits(sent, lim)


def test_watchdog_holds_ramps_then_stops_and_deactivates():
    b = Bridge()
    b.configure({'dtm': 'valve4', 'watchdog_steps': 5, 'hold_time_s': 0.01,
                 'ramp_time_s': 0.2})
    b.activate()
    u = _smooth(400, amp=0.01)
    results = [b.step(k, uk) for k, uk in enumerate(u)]
    k = len(u)
    # three missing steps are bridged by extrapolation, the fifth trips the watchdog
    results += [b.step(k + i, None) for i in range(4)]
    assert results[-1].state == safety.ACTIVE
    results.append(b.step(k + 4, None))
    assert results[-1].state == safety.HOLD and 'watchdog' in results[-1].fault
    i = k + 5
    while b.state != safety.STOPPED and i < k + 5000:
        results.append(b.step(i, u[-1]))      # late commands no longer pass
        i += 1
    assert b.state == safety.STOPPED
    assert b.backend.lifecycle == 'inactive'
    applied = np.array([r.applied[0] for r in results if r.applied.size])
    _assert_within_limits(applied, b.supervisor.limits)
    assert applied[-1] == pytest.approx(0.0, abs=1e-12)
    after = b.step(i, 0.0)
    assert after.applied.size == 0      # deactivated backend: nothing written


def test_a_cold_start_is_held_then_rejoined_and_a_start_that_never_catches_up_trips():
    """Misses in the first start_grace_steps do not trip yet; afterwards the watchdog does."""
    lim = SafetyLimits(fs_hz=FS, stroke_m=0.254, velocity_m_s=0.5, acceleration_m_s2=20.0,
                       hold_time_s=0.01, ramp_time_s=0.5, watchdog_steps=5,
                       start_grace_steps=64)
    ramp = list(0.5e-3 * np.arange(1, 301) / 300)          # commands once the loop runs
    # step 0's command, then 40 steps without one (the chain's cold start), then commands
    sent, states, faults, sup = _run([0.0] + [None] * 40 + ramp, lim=lim, extra_steps=0)
    assert all(s == safety.ACTIVE for s in states) and not any(faults), faults[-1]
    assert np.all(sent[:41] == 0.0)                       # at rest: held where it was
    assert sent[-1] == ramp[-1] and sup.rejoins <= 1
    _assert_within_limits(sent, lim)
    # the same misses after the grace trip at the fifth, as before
    sent, states, faults, sup = _run([0.0] * 100 + [None] * 40 + ramp, lim=lim, extra_steps=0)
    assert states[104] == safety.HOLD and 'no command for 5 steps' in faults[104]
    # a start that never catches up trips at the end of the grace
    sent, states, faults, sup = _run([0.0] + [None] * 200, lim=lim, extra_steps=0)
    tripped = states.index(safety.HOLD)
    assert tripped == 64 and 'no command for 64 steps' in faults[tripped]
    _assert_within_limits(sent, lim)
    # start_grace_steps 0: the first misses count at once
    sent, states, faults, sup = _run([0.0] + [None] * 40, lim=SafetyLimits(
        fs_hz=FS, watchdog_steps=5, start_grace_steps=0), extra_steps=0)
    assert states.index(safety.HOLD) == 5


LIM_REJOIN = SafetyLimits(fs_hz=FS, stroke_m=0.254, velocity_m_s=0.5, acceleration_m_s2=20.0,
                          hold_time_s=0.01, ramp_time_s=0.5, watchdog_steps=51)


def _rest_gap_then(target_commands, gap=4, rest=100):
    """At rest, ``gap`` missing commands (a stall), then ``target_commands``."""
    return [0.0] * rest + [None] * gap + list(target_commands)


def test_after_missing_commands_the_supervisor_rejoins_them_within_the_limits():
    # A 2 mm step after a 4-step stall: 2.05 m/s in one step, four times the velocity limit.
    sent, states, faults, sup = _run(_rest_gap_then([0.002] * 300), lim=LIM_REJOIN,
                                     extra_steps=0)
    assert all(s == safety.ACTIVE for s in states) and not any(faults), faults[-1]
    assert sup.rejoins == 1
    _assert_within_limits(sent, LIM_REJOIN)
    off = np.flatnonzero(sent != 0.002)
    caught = int(off[-1]) + 1                 # from here on every command passes unchanged
    assert 104 < caught < 104 + LIM_REJOIN.watchdog_steps
    assert caught < len(sent) - 100


def test_the_same_jump_without_missing_commands_is_a_fault():
    sent, states, faults, sup = _run([0.0] * 100 + [0.002] * 300, lim=LIM_REJOIN)
    assert 'velocity limit' in faults[-1] and sup.rejoins == 0
    assert not np.any(np.isclose(sent, 0.002))


def test_commands_running_away_faster_than_the_rejoin_speed_trip():
    # after the stall the commands move at 0.45 m/s (inside the 0.5 m/s limit, beyond the
    # 0.4 m/s = 80 % the rejoin may use), starting 5 mm away: never caught
    run_away = 0.005 + 0.45 * np.arange(200) / FS
    sent, states, faults, sup = _run(_rest_gap_then(run_away), lim=LIM_REJOIN)
    assert faults[-1].startswith('rejoin:'), faults[-1]
    _assert_within_limits(sent, LIM_REJOIN)


def test_a_non_finite_command_after_a_stall_still_trips_at_once():
    sent, states, faults, sup = _run(_rest_gap_then([float('nan')] + [0.0] * 10),
                                     lim=LIM_REJOIN)
    assert 'non-finite' in faults[-1] and sup.rejoins == 0


def test_emergency_stop():
    sup = SafetySupervisor(LIM)
    sup.activate(0.0)
    u = _smooth(200)
    for k, uk in enumerate(u):
        sup.filter(k, uk)
    sup.emergency_stop('operator pressed the button')
    out, state, fault = sup.filter(200, u[-1] + 1e-5)
    assert state == safety.HOLD and fault == 'emergency stop: operator pressed the button'


@pytest.mark.parametrize('within_s', [None, 0.4])
def test_a_stop_within_a_time_budget_still_ends_at_the_safe_position_within_limits(within_s):
    # the launcher died: hold and ramp shortened to launcher_loss_stop_s (0.4 s here), against
    # the configured 0.25 s hold and 2 s ramp of an ordinary stop
    lim = SafetyLimits(fs_hz=FS, velocity_m_s=1.0, acceleration_m_s2=400.0, hold_time_s=0.25,
                       ramp_time_s=2.0)
    sup = SafetySupervisor(lim)
    sup.activate(0.0)
    u = _smooth(300, amp=0.01)
    sent = [sup.filter(k, uk)[0][0] for k, uk in enumerate(u)]
    sup.emergency_stop('the launcher (pid 1) died', within_s=within_s)
    states = []
    for k in range(300, 300 + int(5 * FS)):
        out, state, _ = sup.filter(k, None)
        sent.append(out[0])
        states.append(state)
        if state == safety.STOPPED:
            break
    assert states[-1] == safety.STOPPED and sent[-1] == lim.safe_position_m
    _assert_within_limits(sent, lim)
    took_s = len(states) / FS
    if within_s is None:
        assert took_s > 2.25
    else:
        assert within_s * 0.9 < took_s <= within_s + 0.01


def test_force_limit_and_dtm_range():
    sup = SafetySupervisor(LIM)
    sup.activate(0.0)
    sup.filter(0, 0.0)
    assert sup.check_measurement([0.0], [7999.0], [0.05]) == ''
    text = sup.check_measurement([0.0], [-8100.0], [0.0])
    assert text == 'force limit: measured force -8100 N > 8000 N'
    assert sup.state == safety.HOLD
    sup2 = SafetySupervisor(LIM)
    sup2.activate(0.0)
    sup2.filter(0, 0.0)
    assert 'DTM relative displacement limit: 0.12 m > 0.1 m' == \
        sup2.check_measurement([0.0], [0.0], [0.12])


def test_lost_measurements_trip_after_the_configured_count():
    sup = SafetySupervisor(LIM)
    sup.activate(0.0)
    sup.filter(0, 0.0)
    for _ in range(LIM.max_invalid_measurements):     # up to the limit: filled, no trip
        assert sup.check_measurement([np.nan], [np.nan]) == ''
    assert sup.state == safety.ACTIVE
    assert 'measurement lost' in sup.check_measurement([np.nan], [np.nan])   # one more


def test_instability_detector_growing_force_oscillation():
    lim = SafetyLimits(fs_hz=FS, instability_window_steps=128, instability_force_n=5000.0,
                       instability_growth=1.3, instability_growth_windows=3)
    sup = SafetySupervisor(lim)
    sup.activate(0.0)
    t = np.arange(4000) / FS
    force = 50.0 * np.exp(1.5 * t) * np.sin(2 * np.pi * 5 * t)   # grows x1.2 per 0.125 s
    tripped = None
    for k in range(len(t)):
        sup.filter(k, 0.0)
        if sup.check_measurement([0.0], [force[k]]):
            tripped = k
            break
    assert tripped is not None and 'instability' in sup.fault and 'force' in sup.fault
    assert abs(force[:tripped]).max() < lim.force_n     # caught before the force limit


def test_instability_detector_ignores_steady_oscillation():
    lim = SafetyLimits(fs_hz=FS, instability_window_steps=128)
    sup = SafetySupervisor(lim)
    sup.activate(0.0)
    t = np.arange(6000) / FS
    for k in range(len(t)):
        sup.filter(k, 0.0)
        sup.check_measurement([1e-3 * np.sin(2 * np.pi * 3 * t[k])],
                              [1000 * np.sin(2 * np.pi * 3 * t[k])])
    assert sup.state == safety.ACTIVE


@pytest.mark.parametrize('gain, unstable', [(0.5, False), (2.5, True)])
def test_unstable_feedback_loop_is_caught(gain, unstable):
    """An RTHS-like loop with too much delayed feedback goes unstable; the bridge aborts it."""
    b = Bridge()
    b.configure({'dtm': 'valve4', 'instability_window_steps': 128,
                 'acceleration_m_s2': 1000.0, 'velocity_m_s': 2.0})
    b.activate()
    rng = np.random.default_rng(0)
    y = np.zeros(1)
    u = 0.0
    max_sent = 0.0
    for k in range(4000):
        # command = kick + negative feedback of the measured displacement with gain 2.5:
        # the actuator's phase lag (Table 1) makes this loop unstable
        u = (1e-4 * rng.standard_normal() if k < 50 else 0.0) - gain * y[0]
        r = b.step(k, u)
        if r.applied.size:
            max_sent = max(max_sent, abs(r.applied[0]))
            y = r.displacement
        if b.state != safety.ACTIVE:
            break
    if not unstable:
        assert b.state == safety.ACTIVE and b.supervisor.fault == ''
        return
    assert b.state != safety.ACTIVE
    assert b.supervisor.fault.startswith('instability')
    assert max_sent < 0.02          # caught long before the stroke


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-0.3, max_value=0.3),
    st.none()), min_size=1, max_size=300),
    st.booleans())
def test_property_nothing_beyond_limits_reaches_the_plant(commands, estop):
    """Arbitrary command sequences (NaN, inf, huge, gaps): sent commands respect every limit."""
    sup = SafetySupervisor(LIM)
    sup.activate(0.0)
    sent = []
    seq = list(commands) + [None] * 1500
    for k, c in enumerate(seq):
        if estop and k == len(commands) // 2:
            sup.emergency_stop('test')
        out, state, _ = sup.filter(k, c)
        if out is not None:
            sent.append(out[0])
        if state == safety.STOPPED:
            break
    assert sent
    _assert_within_limits(sent, LIM)


def test_limits_validation_names_the_key():
    with pytest.raises(ValueError, match="'velocity_m_s'"):
        SafetyLimits.from_params({'velocity_m_s': 0})
    with pytest.raises(ValueError, match="'watchdog_steps'"):
        SafetyLimits.from_params({'watchdog_steps': 2.5})
    with pytest.raises(ValueError, match="'safe_position_m'"):
        SafetyLimits.from_params({'safe_position_m': 0.3})
    lim = SafetyLimits.from_params({'stroke_m': '0.2'})
    assert lim.stroke_m == 0.2 and lim.force_n == 8000.0


# ---------------------------------------------------------------------------------------------
# Measurement faults through the whole Bridge (simulated backend): nothing unsafe reaches the
# plant after the fault, the actuator is brought to the safe position and the backend stops.

SAFE = -0.002                      # [m] a safe position != 0, so reaching it is not a coincidence
#: a low acceleration limit makes the HOLD phase brake over several steps
BRIDGE_PARAMS = {'dtm': 'valve4', 'hold_time_s': 0.01, 'ramp_time_s': 0.2,
                 'acceleration_m_s2': 8.0, 'safe_position_m': SAFE}


def _offset_sine(n, amp, f):
    """``amp (1 - cos 2 pi f t)``: starts at rest (zero velocity), oscillates about ``amp``."""
    t = np.arange(n) / FS
    return amp * (1.0 - np.cos(2 * np.pi * f * t))


def _reference(commands, **params):
    """Channels the simulated plant measures for ``commands`` (same parameters as the bridge)."""
    from rths_actuator_bridge.simulated import SimulatedPlant
    return SimulatedPlant(**dict(BRIDGE_PARAMS, **params)).simulate(commands)


def _bridge_to_stop(params, commands, patch=None):
    """Step a simulated-backend Bridge until it is STOPPED.

    Step a simulated-backend Bridge with ``commands`` (the sender keeps sending them after a
    fault) until it is STOPPED; return ``(bridge, results)``.
    """
    b = Bridge()
    b.configure(dict(BRIDGE_PARAMS, **params))
    if patch is not None:
        patch(b)
    b.activate()
    results = []
    for k, u in enumerate(commands):
        results.append(b.step(k, u))
        if b.state == safety.STOPPED:
            break
    return b, results


def _check_safe_stop(b, results, commands, fault_step):
    """Return the common checks of a measurement fault detected in the reading of ``fault_step``."""
    lim = b.supervisor.limits
    states = [r.state for r in results]
    applied = np.array([r.applied[0] for r in results])
    assert len(applied) == len(results)          # one command written per step until STOPPED
    # up to the fault the commands pass unchanged, and the fault is seen in its own step
    assert all(s == safety.ACTIVE for s in states[:fault_step])
    np.testing.assert_array_equal(applied[:fault_step + 1], commands[:fault_step + 1])
    assert states[fault_step] == safety.HOLD
    # then exactly HOLD -> RAMP -> STOPPED, STOPPED once, in the last step
    phases = [s for i, s in enumerate(states[fault_step:]) if i == 0
              or s != states[fault_step + i - 1]]
    assert phases == [safety.HOLD, safety.RAMP, safety.STOPPED]
    assert states.count(safety.STOPPED) == 1
    # every command written respects the stroke, velocity and acceleration limits
    _assert_within_limits(applied, lim)
    # HOLD: brake (speed never grows), then keep the position for hold_time_s (the step that
    # ends the hold is already labelled RAMP)
    hold = applied[fault_step:fault_step + states.count(safety.HOLD) + 1]
    speed = np.abs(np.diff(hold))
    assert np.all(np.diff(speed) <= 1e-15)
    moving = np.flatnonzero(speed > 0)
    held = len(speed) - (moving[-1] + 1 if moving.size else 0)
    assert held == int(round(lim.hold_time_s * lim.fs_hz)) + 1
    # RAMP: monotonically to the safe position, which is reached exactly; the sender's commands
    # (still arriving) no longer reach the plant
    ramp = applied[fault_step + states.count(safety.HOLD):]
    assert np.all(np.diff(ramp) * np.sign(SAFE - ramp[0]) >= -1e-12)
    assert applied[-1] == pytest.approx(SAFE, abs=1e-12)
    assert not np.any(applied[fault_step + 1:] == commands[fault_step + 1:len(applied)])
    # the backend is deactivated: the next step writes nothing and the plant does not advance
    assert b.backend.lifecycle == 'inactive'
    written = b.backend.step
    after = b.step(len(results), commands[len(results)])
    assert after.applied.size == 0 and after.state == safety.STOPPED
    assert b.backend.step == written


@pytest.mark.parametrize('acc', [100.0, 8.0])
@pytest.mark.parametrize('safe', [0.254, -0.254, 0.0])
def test_the_ramp_never_passes_the_safe_position_even_at_the_stroke_end(safe, acc):
    """A safe position at the stroke end (allowed) must not be overshot out of the stroke."""
    lim = SafetyLimits(fs_hz=FS, acceleration_m_s2=acc, hold_time_s=0.01, ramp_time_s=0.2,
                       safe_position_m=safe)
    for start in np.linspace(-0.25, 0.25, 21):
        sup = SafetySupervisor(lim)
        sup.activate(start)
        sup.emergency_stop('test')
        sent = []
        for k in range(5000):
            out, state, _ = sup.filter(k, None)
            sent.append(out[0])
            if state == safety.STOPPED:
                break
        assert state == safety.STOPPED
        _assert_within_limits(sent, lim, start)
        # monotone, never beyond the safe position (1 pm of rounding)
        assert np.all(np.diff(sent) * np.sign(safe - start) >= -1e-12)
        assert np.max(np.abs(np.array(sent) - start)) <= abs(safe - start) + 1e-12
        assert sent[-1] == safe


def test_force_limit_through_the_bridge_holds_ramps_stops_and_deactivates():
    u = _offset_sine(4000, 0.004, 5.0)
    ref = _reference(u)['force']
    force_n = 0.6 * np.max(np.abs(ref))        # well inside the record's force range
    first = int(np.argmax(np.abs(ref) > force_n))
    b, results = _bridge_to_stop({'force_n': force_n}, u)
    assert b.supervisor.fault == (f'force limit: measured force {ref[first]:.6g} N > '
                                  f'{force_n:.6g} N')
    assert all(abs(r.force[0]) <= force_n for r in results[:first])
    _check_safe_stop(b, results, u, first)


def test_dtm_range_through_the_bridge_holds_ramps_stops_and_deactivates():
    from rths_numerical.dtm import TABLE4
    dtm = TABLE4['valve4']
    f_n = np.sqrt(dtm.k_d / dtm.m_d) / (2 * np.pi)    # drive the DTM at resonance (eq. 47)
    u = _offset_sine(6000, 0.002, f_n)
    ref = _reference(u)
    limit = 0.5 * np.max(np.abs(ref['rel_disp']))
    first = int(np.argmax(np.abs(ref['rel_disp']) > limit))
    assert np.max(np.abs(ref['force'][:first + 1])) < 8000.0    # not the force limit first
    b, results = _bridge_to_stop({'dtm_rel_disp_m': limit}, u)
    assert b.supervisor.fault == (f'DTM relative displacement limit: '
                                  f"{ref['rel_disp'][first]:.6g} m > {limit:.6g} m")
    _check_safe_stop(b, results, u, first)


def test_lost_measurements_through_the_bridge_hold_ramp_stop_and_deactivate():
    """The sensors go dead (non-finite readings) and never come back."""
    u = _offset_sine(4000, 0.004, 2.0)
    first = int(round(FS * 3 / 8 / 2.0))    # the trip falls on a velocity peak: HOLD must brake
    dead_from = first - 4          # 4 invalid readings are filled, the 5th trips

    def kill_sensors(bridge):
        plant = bridge.backend.plant
        measure = plant.measure

        def dead_after(true=None):
            out = measure(true)
            if plant.k >= dead_from:
                out = dict(out, table_disp=float('nan'), force=float('nan'))
            return out
        plant.measure = dead_after

    b, results = _bridge_to_stop({'max_invalid_measurements': 4}, u, kill_sensors)
    assert b.supervisor.fault == ('measurement lost: non-finite readings: 5 in a row (more '
                                  'than max_invalid_measurements 4)')
    assert all(np.isfinite(r.displacement[0]) and not r.filled for r in results[:dead_from])
    # the gap policy holds the last valid reading in every dead step (the published values)
    held = results[dead_from - 1]
    assert all(r.filled == 1 and r.displacement[0] == held.displacement[0]
               and r.force[0] == held.force[0] for r in results[dead_from:])
    _check_safe_stop(b, results, u, first)
    # the trip came at full speed: the hold braked at the acceleration limit over many steps
    v = np.diff([r.applied[0] for r in results[first - 1:]]) * FS
    a_lim = b.supervisor.limits.acceleration_m_s2
    assert abs(v[0]) > 4 * a_lim / FS
    assert abs(v[1]) == pytest.approx(abs(v[0]) - a_lim / FS, rel=1e-9)
