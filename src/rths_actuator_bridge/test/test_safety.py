"""Every safety rule is violated once; nothing unsafe may reach the plant."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

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
    for _ in range(LIM.max_invalid_measurements - 1):
        assert sup.check_measurement([np.nan], [np.nan]) == ''
    assert 'measurement lost' in sup.check_measurement([np.nan], [np.nan])


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
