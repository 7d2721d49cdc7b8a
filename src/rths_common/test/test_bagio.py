"""Bags: write/read, run information, and recovery of a recording killed mid-run."""

import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from rths_common import bagio


def _measurement(step):
    store = bagio.typestore()
    header = store.types['std_msgs/msg/Header']
    stamp = store.types['builtin_interfaces/msg/Time']
    cls = store.types['rths_msgs/msg/Measurement']
    return cls(header=header(stamp=stamp(sec=0, nanosec=0), frame_id=''), step=step,
               applied=np.array([0.001 * step]), displacement=np.array([0.001 * step - 1e-5]),
               force=np.array([2.0 * step]))


def test_write_read_and_run_info(tmp_path):
    bag = tmp_path / 'bag'
    with bagio.BagWriter(bag, run_info={'fs_hz': 512.0, 'kind': 'identification'}) as w:
        for k in range(10):
            w.write_msg('/rths/measurement', 1000 + k, _measurement(k))
    assert bagio.info(bag)['topics']['/rths/measurement']['count'] == 10
    assert bagio.sampling_rate(bag) == 512.0
    t, command, measured = bagio.read_identification(bag)
    assert np.allclose(t, np.arange(10) / 512.0)
    assert np.allclose(command, 0.001 * np.arange(10))
    assert np.allclose(measured - command, -1e-5)


def test_a_topic_the_bag_does_not_hold_reads_as_empty(tmp_path):
    # rosbags reads every connection when asked for none: a review of a bag recorded
    # before /rths/run_inputs existed got its LoopStatus messages as run inputs
    bag = tmp_path / 'bag'
    with bagio.BagWriter(bag, run_info={'fs_hz': 1024.0}) as w:
        w.write_msg('/rths/measurement', 10, _measurement(0))
    assert bagio.read_topic(bag, '/rths/run_inputs') == []
    assert len(bagio.read_topic(bag, '/rths/measurement')) == 1


def test_existing_bag_is_refused(tmp_path):
    (tmp_path / 'bag').mkdir()
    with pytest.raises(OSError, match='already exists'):
        bagio.BagWriter(tmp_path / 'bag')


def test_bag_without_fs_names_the_fix(tmp_path):
    bag = tmp_path / 'bag'
    with bagio.BagWriter(bag) as w:
        w.write_msg('/rths/measurement', 1, _measurement(0))
    with pytest.raises(ValueError, match='fs_hz'):
        bagio.read_identification(bag)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_sigkilled_writer_leaves_a_readable_bag(tmp_path, storage):
    """A recording process killed with SIGKILL: committed messages survive, reindex restores."""
    bag = tmp_path / 'bag'
    script = textwrap.dedent(f'''
        import os, signal, sys, time
        import numpy as np
        sys.path[:0] = {sys.path!r}
        from rths_common import bagio
        from test_bagio import _measurement
        w = bagio.BagWriter({str(bag)!r}, run_info={{'fs_hz': 1024.0}}, storage={storage!r})
        for k in range(300):
            w.write_msg('/rths/measurement', 10 + k, _measurement(k))
        w.commit()
        for k in range(300, 350):  # written but not committed: lost with the process
            w.write_msg('/rths/measurement', 10 + k, _measurement(k))
        os.kill(os.getpid(), signal.SIGKILL)
    ''')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [os.path.dirname(__file__)] + sys.path))
    proc = subprocess.run([sys.executable, '-c', script], env=env, timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not (bag / 'metadata.yaml').exists()
    info = bagio.info(bag)  # reindexes
    assert (bag / 'metadata.yaml').exists() and info['storage'] == storage
    assert info['topics']['/rths/measurement']['count'] == 300
    steps = [m.step for _, m in bagio.read_topic(bag, '/rths/measurement')]
    assert steps == list(range(300))
    assert bagio.sampling_rate(bag) == 1024.0  # run information survives via the side file


def test_identification_pairs_the_loop_command_with_its_measurement(tmp_path):
    """With command_delay_steps D the command of step k was applied at tick k + D."""
    bag = tmp_path / 'bag'
    with bagio.BagWriter(bag, run_info={'fs_hz': 512.0, 'kind': 'identification',
                                        'bridge.command_delay_steps': '2'}) as w:
        for k in range(10):
            w.write_msg('/rths/measurement', 1000 + k, _measurement(k))
    assert bagio.delay_steps(bag) == 2
    t, command, measured = bagio.read_identification(bag)            # loop plant
    np.testing.assert_allclose(command, 0.001 * (np.arange(8) + 2))   # applied[k + 2]
    np.testing.assert_allclose(measured, 0.001 * np.arange(8) - 1e-5)
    np.testing.assert_allclose(t, np.arange(8) / 512.0)
    _, command, _ = bagio.read_identification(bag, loop=False)         # the actuator alone
    np.testing.assert_allclose(command, 0.001 * np.arange(10))
