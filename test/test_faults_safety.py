"""Property test over the whole bridge (issue 8): whatever arrives, no output beyond a limit.

``src/rths_actuator_bridge/test/test_safety.py`` checks the supervisor alone;
this one drives :class:`rths_actuator_bridge.bridge.Bridge` (supervisor +
simulated actuator, table and DTM + measurement checks) with arbitrary step
sequences: finite commands of any size, NaN, +-inf, missing steps (None),
wrong channel counts and emergency stops at any time.  For every sequence:

* every value written to the plant is finite, inside the stroke, and its
  first/second differences respect the velocity/acceleration limits;
* once a fault is raised the bridge never returns to ACTIVE, and after
  STOPPED nothing more is written;
* the plant ends at rest at the safe position when the sequence ends in a stop.
"""

import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
import numpy as np

from rths_actuator_bridge import safety
from rths_actuator_bridge.bridge import Bridge

LIMITS = {'stroke_m': 0.05, 'velocity_m_s': 0.2, 'acceleration_m_s2': 20.0,
          'hold_time_s': 0.01, 'ramp_time_s': 0.1, 'watchdog_steps': 5,
          'fs_hz': 1024.0, 'dtm': 'valve4', 'force_n': 8000.0}
DT = 1.0 / LIMITS['fs_hz']

command = st.one_of(
    st.none(),
    st.floats(min_value=-0.2, max_value=0.2, allow_nan=False),
    st.floats(min_value=-1e-4, max_value=1e-4, allow_nan=False),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e300]),
    st.lists(st.floats(-0.01, 0.01), min_size=2, max_size=3),   # wrong channel count
    st.just('estop'),
)


def run(sequence):
    bridge = Bridge()
    bridge.configure(dict(LIMITS, backend='simulated'))
    bridge.activate()
    written, states = [], []
    for k, item in enumerate(sequence):
        if isinstance(item, str):
            bridge.emergency_stop('property test')
            item = None
        cmd = None if item is None else (item if isinstance(item, list) else [item])
        result = bridge.step(k, cmd)
        states.append(result.state)
        if result.applied.size:
            written.append(float(result.applied[0]))
    bridge.close()
    return np.array(written), states


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(command, min_size=1, max_size=300))
def test_no_output_of_the_bridge_ever_exceeds_a_limit(sequence):
    written, states = run(sequence)
    tol = 1e-9
    assert np.all(np.isfinite(written))
    assert np.all(np.abs(written) <= LIMITS['stroke_m'] + tol)
    path = np.concatenate([[0.0], written])   # the actuator starts at rest at 0
    vel = np.diff(path) / DT
    assert np.all(np.abs(vel) <= LIMITS['velocity_m_s'] * (1 + 1e-6) + tol)
    acc = np.diff(np.concatenate([[0.0], vel])) / DT
    assert np.all(np.abs(acc) <= LIMITS['acceleration_m_s2'] * (1 + 1e-6) + 1e-6)
    faulted = False
    for state in states:
        if faulted:
            assert state != safety.ACTIVE   # a fault is never forgotten
        faulted = faulted or state in (safety.HOLD, safety.RAMP, safety.STOPPED)


def test_nan_command_never_reaches_the_plant_and_the_bridge_stops_safely():
    """A NaN command: hold, ramp to the safe position, STOPPED, at rest."""
    seq = [0.0001 * k for k in range(50)] + [math.nan] + [None] * 400
    written, states = run(seq)
    assert np.all(np.isfinite(written))
    assert safety.STOPPED in states
    assert abs(written[-1]) < 1e-12     # the ramp ended at the safe position 0
