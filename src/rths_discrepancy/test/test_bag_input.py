"""Bag input of the discrepancy workflow: ``rths_discrepancy.io.read_bag(bag, 'actuator')``.

A small bag is written with :class:`rths_common.bagio.BagWriter` the way the
recorder writes a run: ``/rths/measurement`` messages (``applied`` = what the
bridge wrote to the actuator, ``displacement`` = measured) and run information
from :func:`rths_common.runinfo.flatten` (``fs_hz``, the bridge's
``command_delay_steps``).  The record is the self-test's Table 1 3-pole
actuator with a hidden stiffness error, at 512 Hz, as the loop sees it: the
command of step k is applied D steps later by the bridge's delay line.
"""

import json

import numpy as np
import pytest

from rths_discrepancy import effects as fx
from rths_discrepancy import selftest

FS_HZ = 512.0
#: Bridge delay line of the run: the actuator columns are the loop's, shifted by it.
DELAY_STEPS = 3
DURATION_S = 8.0


@pytest.fixture(scope='module')
def actuator_bag(tmp_path_factory):
    """(bag path, record, truth): the run's last step applied nothing (empty ``applied``)."""
    from rths_common import bagio, runinfo, topics

    data, truth = selftest.make_record('actuator', ['stiffness_error'], 3,
                                       duration_s=DURATION_S, fs=FS_HZ)
    store = bagio.typestore()
    meas = store.types['rths_msgs/msg/Measurement']
    header = store.types['std_msgs/msg/Header']
    stamp = store.types['builtin_interfaces/msg/Time']
    info = runinfo.flatten('identification', FS_HZ, 'lockstep',
                           {'bridge': {'command_delay_steps': DELAY_STEPS, 'dtm': 'none'}})
    bag = tmp_path_factory.mktemp('actuator') / 'bag'
    n = data['time'].size
    with bagio.BagWriter(bag, run_info=info) as writer:
        for k in range(n + DELAY_STEPS + 1):
            t_ns = int(round(k * 1e9 / FS_HZ))
            last = k == n + DELAY_STEPS  # the bridge's final step: nothing applied
            applied = [] if last else [data['command'][k - DELAY_STEPS] if k >= DELAY_STEPS
                                       else 0.0]
            msg = meas(header=header(stamp=stamp(sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                                     frame_id=''),
                       step=k,
                       applied=np.array(applied),
                       displacement=np.array([data['measured'][k] if k < n else 0.0]),
                       force=np.array([0.0]))
            writer.write_msg(topics.MEASUREMENT, t_ns, msg)
    return bag, data, truth


def test_read_bag_actuator_columns(actuator_bag):
    from rths_discrepancy.io import read_bag

    bag, data, _ = actuator_bag
    got = read_bag(bag, 'actuator')
    assert sorted(got) == ['command', 'measured', 'time']
    # the steps whose command was never applied are dropped; time is step / fs_hz
    assert got['time'].size == data['time'].size
    np.testing.assert_allclose(got['time'], np.arange(data['time'].size) / FS_HZ, rtol=0,
                               atol=1e-12)
    # the loop's plant, as rths identify reads it: the command of step k (applied at tick
    # k + DELAY_STEPS by the bridge's delay line) and the displacement measured at step k
    np.testing.assert_array_equal(got['command'], data['command'])
    np.testing.assert_array_equal(got['measured'], data['measured'])


def test_discrepancy_cli_names_the_effect_from_the_bag(actuator_bag, tmp_path):
    from rths_bringup.cli import main

    bag, data, truth = actuator_bag
    out = tmp_path / 'out'
    assert main(['discrepancy', '--scenario', 'actuator', '--measured', str(bag),
                 '--out', str(out)]) == 0
    res = json.loads((out / 'result.json').read_text())
    assert res['sample_rate_hz'] == pytest.approx(FS_HZ)
    assert res['samples'] == data['time'].size
    assert res['effect'] == 'stiffness_error'
    got = res['parameters']['stiffness_error'][fx.LIBRARY['actuator']['stiffness_error'].param]
    assert abs(got - truth['stiffness_error']) <= 0.15 * truth['stiffness_error']


def test_read_bag_actuator_bag_without_measurements(tmp_path):
    from rths_common import bagio, runinfo
    from rths_discrepancy.io import read_bag

    bag = tmp_path / 'empty'
    with bagio.BagWriter(bag, run_info=runinfo.flatten('identification', FS_HZ, 'lockstep', {})):
        pass
    with pytest.raises(ValueError, match='no /rths/measurement messages'):
        read_bag(bag, 'actuator')
