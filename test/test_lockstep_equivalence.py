"""Lock-step RTHS over ROS equals the offline coupled simulation bit for bit (issues 6, 18).

The three nodes run as separate processes with the 2-story building, Kobe,
the designed compensator of config/compensator.yaml and the simulated plant
(3-pole actuator + table + DTM valve #4); rths_bringup.offline.offline_rths
steps the same cores through the same contract in the same order without ROS
(the replay harness, rths_common.replay.closed_loop).
"""

import numpy as np
import pytest

from rths_system_tests import REPO, rths


@pytest.mark.parametrize('method, divisor', [('fir', 1), ('amb', 1), ('fir', 4)])
def test_lockstep_run_equals_offline_coupled_simulation(tmp_path, method, divisor):
    """Also with an adaptive method: command k waits for measurement k-1 in both.

    ``divisor`` 4: the numerical substructure at 256 Hz inside the 1024 Hz loop
    (``rate_divisor``, rths_numerical.multirate); the bag still holds every loop step.
    """
    from rths_bringup.offline import offline_rths
    from rths_common import bagio, runinfo, topics

    config = REPO / 'config'
    numerical = dict(runinfo.load_params(config / 'numerical.yaml', 'numerical'),
                     model='building2story', record='kobe', scale=0.135, duration_s=2.0,
                     force_scale=5.0, rate_divisor=divisor)
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta'):
        numerical.pop(key)
    compensator = runinfo.load_params(config / 'compensator.yaml', 'compensator')
    if method != 'fir':
        compensator['method'] = method
        compensator['provenance'] = dict(compensator.get('provenance') or {},
                                         plant=str(config / 'plant.yaml'))
    bridge = dict(runinfo.load_params(config / 'bridge.yaml', 'bridge'), dtm='valve4',
                  displacement_noise_m=1e-6, force_noise_n=0.5, seed=3)
    cfg = tmp_path / 'config'
    runinfo.write_params(cfg / 'numerical.yaml', 'numerical', numerical)
    runinfo.write_params(cfg / 'compensator.yaml', 'compensator', compensator)
    runinfo.write_params(cfg / 'bridge.yaml', 'bridge', bridge)
    bag = tmp_path / 'bag'
    rths('launch', '--config', cfg, '--bag', bag, timeout=300)

    offline = offline_rths(numerical, compensator, bridge)
    n = offline['force'].shape[0]
    assert n == 2048
    disp = bagio.step_arrays(bag, topics.INTERFACE_DISPLACEMENT, ('displacement',))
    meas = bagio.step_arrays(bag, topics.MEASUREMENT, ('applied', 'displacement', 'force'))
    cmd = bagio.step_arrays(bag, topics.COMMAND, ('command',))
    assert np.array_equal(disp['step'], np.arange(n))
    pairs = {
        'interface displacement': (disp['displacement'], offline['interface_displacement']),
        'command': (cmd['command'], offline['command']),
        'applied': (meas['applied'], offline['applied']),
        'measured displacement': (meas['displacement'], offline['displacement']),
        'measured force': (meas['force'], offline['force']),
    }
    for name, (ros, ref) in pairs.items():
        assert np.max(np.abs(ref)) > 0, name
        # the same float operations in the same order: bitwise, not allclose
        assert np.array_equal(ros, ref), name
    if method != 'fir':   # the coefficients are recorded, decimated (every 64th step)
        coefs = bagio.read_topic(bag, topics.COMPENSATOR_COEFFICIENTS)
        assert n // 64 - 2 <= len(coefs) <= n // 64
        assert all(len(m.data) == 4 and np.all(np.isfinite(m.data)) for _, m in coefs)
    # and the loop did something physical: the building moved and the DTM pushed back
    assert np.max(np.abs(offline['interface_displacement'])) > 1e-4
    assert np.max(np.abs(offline['force'])) > 10.0


def test_offline_node_keys_cover_every_node_parameter():
    """The offline loop strips exactly the node-level keys the nodes take for themselves."""
    from rths_actuator_bridge.node import NODE_PARAMS as bridge
    from rths_common.params import NODE_KEYS
    from rths_compensator.node import NODE_PARAMS as compensator
    from rths_numerical.node import NODE_PARAMS as numerical

    assert set(bridge) | set(compensator) | set(numerical) == set(NODE_KEYS)
