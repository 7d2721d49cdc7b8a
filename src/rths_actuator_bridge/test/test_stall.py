"""Host stalls of 20, 50 and 200 ms never drive the actuator outside its limits (issue 12).

The bridge (simulated plant, 1024 Hz) follows the commands of the designed
compensator (config/compensator.yaml: WLS, fc = 10 Hz, 400 taps, high-pass in
the stopband: 647, -1791, 1806, ...) for a
1.5 Hz, 20 mm interface displacement, and a stall hits the loop in one of
two ways:

* ``clock``: the bridge's own clock stops (its process or the whole host;
  in the composed layout every node stops with it): the skipped ticks go to
  :meth:`SafetySupervisor.stalled`, then the commands continue in step order;
* ``inputs``: the numerical node and the compensator stop while the bridge
  ticks on (processes layout): the bridge extrapolates, then the compensator
  fills the lost displacements (rths_common.gaps, as its node does) and its
  high-pass taps put the fill error into the commands that come back.

Every command written must respect the stroke, velocity and acceleration
limits.  A stall of the clock shorter than ``stall_limit_s`` (default 0.5 s)
resumes, a longer one aborts safely (HOLD, RAMP to the safe position,
STOPPED); stalled inputs are extrapolated until the watchdog (10 steps by
default) aborts the same way, or, with a longer watchdog, rejoined.
"""

import functools
import os
from pathlib import Path

import numpy as np
import pytest

from rths_actuator_bridge.bridge import Bridge
from rths_actuator_bridge.safety import ACTIVE, STOPPED

FS = 1024.0
STALL_MS = (20, 50, 200)
N_STEPS = int(4.5 * FS)
STALL_AT = int(1.0 * FS) + 37


def repo_root() -> Path:
    """Return the checkout (RTHS_ROOT from env.sh, else the parent holding config/, Makefile)."""
    if os.environ.get('RTHS_ROOT'):
        return Path(os.environ['RTHS_ROOT'])
    for parent in Path(__file__).resolve().parents:
        if (parent / 'config').is_dir() and (parent / 'Makefile').is_file():
            return parent
    raise RuntimeError('cannot find the rths checkout; source env.sh first')


@functools.lru_cache(maxsize=1)
def designed_taps() -> tuple:
    """Return the committed design of config/compensator.yaml (WLS, 400 taps, 1024 Hz)."""
    from rths_compensator.params import load_compensator_params

    comp = load_compensator_params(repo_root() / 'config' / 'compensator.yaml')
    assert float(comp['fs_hz']) == FS
    return np.asarray(comp['taps'], float), np.asarray(comp['denominator'], float)


def displacement(k):
    """Return the interface displacement of steps k [m]: 20 mm at 1.5 Hz, faded in from rest."""
    t = np.asarray(k) / FS
    fade = 0.5 * (1.0 - np.cos(np.pi * np.minimum(t / 0.8, 1.0)))
    return 0.02 * np.sin(2 * np.pi * 1.5 * t) * fade


def commands(kind: str, stall: int) -> np.ndarray:
    """Return the compensator's command of every step: what its node computes, one filter run.

    ``inputs``: the displacements of the stalled steps never reached it; when the
    next one arrives it fills them (rths_common.gaps, as the node does) and
    filters the filled values in their place.
    """
    from scipy.signal import lfilter

    from rths_common.gaps import DISPLACEMENT_ORDER, GapFiller

    fed = displacement(np.arange(N_STEPS))
    if kind == 'inputs':
        gaps = GapFiller(DISPLACEMENT_ORDER)
        for k in range(STALL_AT - 8, STALL_AT):
            gaps.fill(k, fed[k:k + 1])
        back = STALL_AT + stall
        filled = gaps.fill(back, fed[back:back + 1])
        assert len(filled) == stall
        fed[STALL_AT:back] = np.ravel(filled)
    return lfilter(*designed_taps(), fed)


def run(kind: str, stall_ms: float, watchdog_steps: int, stall_limit_s: float = 0.5) -> tuple:
    """Run the loop through a stall; return (applied commands, final state, fault text)."""
    bridge = Bridge()
    bridge.configure({'backend': 'simulated', 'fs_hz': FS, 'actuator_model': '3pole',
                      'dtm': 'valve4', 'seed': 1, 'watchdog_steps': watchdog_steps,
                      'stall_limit_s': stall_limit_s})
    bridge.activate()
    stall = int(round(stall_ms * 1e-3 * FS))
    command = commands(kind, stall)
    applied = []
    k = 0
    while k < N_STEPS and bridge.state != STOPPED:
        if k == STALL_AT and kind == 'clock':
            bridge.supervisor.stalled(stall, k)          # the bridge's tick k came this late
        lost = kind == 'inputs' and STALL_AT <= k < STALL_AT + stall
        result = bridge.step(k, None if lost else [float(command[k])])
        if result.applied.size:
            applied.append(float(result.applied[0]))
        k += 1
    bridge.close()
    return np.array(applied), bridge.state, bridge.supervisor.fault


def assert_within_limits(u):
    from rths_actuator_bridge.safety import SafetyLimits

    lim = SafetyLimits()
    tol = 1 + 1e-9
    assert np.all(np.isfinite(u))
    assert np.max(np.abs(u)) <= lim.stroke_m * tol
    path = np.concatenate([[0.0, 0.0], u])                 # armed at rest at 0 m
    velocity = np.abs(np.diff(path)) * FS
    acceleration = np.abs(np.diff(path, 2)) * FS ** 2
    assert velocity.max() <= lim.velocity_m_s * tol, velocity.max()
    assert acceleration.max() <= lim.acceleration_m_s2 * tol, acceleration.max()


@pytest.mark.parametrize('stall_ms', STALL_MS)
def test_a_stall_of_the_clock_resumes_within_the_limits(stall_ms):
    """Composed layout / host stall: the commands continue in step order after it."""
    u, state, fault = run('clock', stall_ms, watchdog_steps=10)
    assert_within_limits(u)
    assert state == ACTIVE and not fault, fault
    assert len(u) == N_STEPS


@pytest.mark.parametrize('stall_ms', STALL_MS)
def test_a_stall_of_the_clock_beyond_its_limit_aborts_safely(stall_ms):
    u, state, fault = run('clock', stall_ms, watchdog_steps=10, stall_limit_s=0.01)
    assert_within_limits(u)
    assert state == STOPPED and 'watchdog: the loop stalled' in fault, fault
    assert abs(u[-1]) < 1e-9                               # ramped to the safe position
    assert len(u) > STALL_AT                               # (the loop ran up to the stall)


@pytest.mark.parametrize('stall_ms', STALL_MS)
def test_stalled_inputs_beyond_the_watchdog_abort_safely_within_the_limits(stall_ms):
    """Processes layout: the bridge ticks on without commands, then trips its watchdog."""
    u, state, fault = run('inputs', stall_ms, watchdog_steps=10)
    assert_within_limits(u)
    assert state == STOPPED and 'watchdog: no command' in fault, fault
    assert abs(u[-1]) < 1e-9


@pytest.mark.parametrize('stall_ms', STALL_MS)
def test_stalled_inputs_within_the_watchdog_keep_every_command_within_the_limits(stall_ms):
    """A long watchdog: extrapolation, then the high-pass commands rejoined (or a safe stop)."""
    u, state, fault = run('inputs', stall_ms, watchdog_steps=400)
    assert_within_limits(u)
    assert state in (ACTIVE, STOPPED)
