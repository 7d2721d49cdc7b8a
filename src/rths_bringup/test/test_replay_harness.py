"""The three cores through one contract without ROS (rths_common.replay): each missing-input policy.

The loop: the 2-story building under Kobe x 0.135, the designed compensator of
config/compensator.yaml, the simulated plant with the DTM (as
test_lockstep_equivalence).  ``closed_loop(..., lose=...)`` is the realtime
loop at zero latency; each case loses one message and checks the policy of
the core that misses it (docs/nodes.md): the numerical core interpolates a
lost force linearly, the compensator a lost displacement with a cubic, the
bridge extrapolates a missing command at constant velocity.
"""

from pathlib import Path

import numpy as np
import pytest

from rths_common import gaps, runinfo
from rths_common.replay import closed_loop

CONFIG = Path(__file__).resolve().parents[3] / 'config'
LOST = 300   # a step well inside the run (the building moves, the DTM pushes back)


def cores():
    """Build the three cores as the nodes do, from the repo's params files (0.5 s of record)."""
    from rths_actuator_bridge.bridge import Bridge
    from rths_common.params import core_params
    from rths_compensator.core import CompensatorCore
    from rths_numerical.stepping import NumericalCore
    from rths_numerical.substructure import make_substructure

    numerical = dict(runinfo.load_params(CONFIG / 'numerical.yaml', 'numerical'),
                     model='building2story', record='kobe', scale=0.135, duration_s=0.5,
                     force_scale=5.0)
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta'):
        numerical.pop(key, None)
    sub = make_substructure(core_params(numerical))
    compensator = runinfo.load_params(CONFIG / 'compensator.yaml', 'compensator')
    bridge = Bridge()
    bridge.configure(core_params(dict(runinfo.load_params(CONFIG / 'bridge.yaml', 'bridge'),
                                      dtm='valve4', force_noise_n=0.5, seed=3)))
    bridge.activate()
    return NumericalCore(sub), CompensatorCore(compensator), bridge


def run(lose=None):
    numerical, compensator, bridge = cores()
    out = closed_loop(numerical, compensator, bridge, numerical.sub.n_steps, lose=lose)
    out['history'] = numerical.sub.history()
    out['taps'] = compensator.params['taps']
    bridge.close()
    return out


@pytest.fixture(scope='module')
def reference():
    return run()


def test_nothing_lost_every_step_runs_and_nothing_is_filled(reference):
    assert reference['steps_run'] == reference['force'].shape[0] == 512
    assert np.all(np.isfinite(reference['command']))
    assert reference['filled_numerical'] == reference['filled_compensator'] == 0
    assert reference['missing_commands'] == 0
    assert np.max(np.abs(reference['force'])) > 1.0   # the loop acted


def test_lost_measurement_numerical_core_interpolates_the_force_linearly():
    out = run({'measurement': {LOST}})
    assert out['filled_numerical'] == 1
    force, used = out['force'][:, 0], out['history']['measured_force']
    used = np.asarray(used).reshape(len(used), -1)[:, 0]
    assert used[LOST] == pytest.approx(0.5 * (force[LOST - 1] + force[LOST + 1]), abs=1e-12)
    assert used[LOST] != force[LOST]
    # no interface displacement for LOST + 1 came out: the bridge missed that command
    assert np.isnan(out['command'][LOST + 1, 0]) and out['missing_commands'] == 1


def test_lost_displacement_compensator_core_interpolates_with_a_cubic(reference):
    from rths_compensator.filters import MultiChannelFilter

    out = run({'interface_displacement': {LOST}})
    assert out['filled_compensator'] == 1
    assert np.isnan(out['command'][LOST, 0])
    x = out['interface_displacement'][:, 0].copy()
    nodes = [LOST - 3, LOST - 2, LOST - 1, LOST + 1]
    x[LOST] = gaps.interpolate(nodes, x[nodes], [LOST])[0, 0]
    filt = MultiChannelFilter(out['taps'], n_channels=1)
    expected = [filt.step(x[k:k + 1])[0] for k in range(LOST + 2)]
    assert out['command'][LOST + 1, 0] == expected[LOST + 1]
    assert out['command'][LOST - 1, 0] == reference['command'][LOST - 1, 0]


def test_lost_command_bridge_extrapolates_at_constant_velocity():
    out = run({'command': {LOST}})
    applied = out['applied'][:, 0]
    assert out['missing_commands'] == 1 and out['filled_compensator'] == 0
    assert applied[LOST] == pytest.approx(2 * applied[LOST - 1] - applied[LOST - 2], abs=1e-12)
    assert applied[LOST + 1] == out['command'][LOST + 1, 0]   # rejoined (within the limits)


def test_closed_loop_names_the_messages_it_can_lose():
    numerical, compensator, bridge = cores()
    with pytest.raises(ValueError, match='cannot lose'):
        closed_loop(numerical, compensator, bridge, 10, lose={'force': {3}})
    bridge.close()
