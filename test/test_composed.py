"""The composed layout: the three nodes in one process (rths_bringup.container), issue 12.

* lock-step: the composed and the processes layouts give bit-equal runs (the
  same cores in the same step order; only the transport differs);
* realtime: a short composed run records every step (the container's
  recording tee: count of steps in the bag = steps run, for the measurement,
  the command, the interface displacement and every node's status) and its
  miss accounting matches the bag;
* SIGINT/SIGTERM of the container stops all three nodes cleanly (each logs its
  end-of-run line) and leaves a readable bag whose steps have no gap.
"""

import os
import signal

import numpy as np
import pytest

from rths_system_tests import (
    REPO,
    Drain,
    launch_background,
    rths,
    started_pids,
    wait_for,
    wait_steps,
)

RATE_HZ = 256.0
DURATION_S = 2.0
N_STEPS = int(RATE_HZ * DURATION_S)


def lockstep_config(directory):
    """Write the repo config with the building, Kobe and 0.25 s of record (lock-step)."""
    from rths_common import runinfo

    config = REPO / 'config'
    numerical = dict(runinfo.load_params(config / 'numerical.yaml', 'numerical'),
                     model='building2story', record='kobe', scale=0.135, duration_s=0.25,
                     force_scale=5.0, mode='lockstep')
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta'):
        numerical.pop(key, None)
    bridge = dict(runinfo.load_params(config / 'bridge.yaml', 'bridge'), dtm='valve4',
                  displacement_noise_m=1e-6, force_noise_n=0.5, seed=3)
    runinfo.write_params(directory / 'numerical.yaml', 'numerical', numerical)
    runinfo.write_params(directory / 'compensator.yaml', 'compensator',
                         runinfo.load_params(config / 'compensator.yaml', 'compensator'))
    runinfo.write_params(directory / 'bridge.yaml', 'bridge', bridge)
    return directory


def loop_arrays(bag) -> dict:
    from rths_common import bagio, topics

    return {
        'displacement': bagio.step_arrays(bag, topics.INTERFACE_DISPLACEMENT, ('displacement',)),
        'command': bagio.step_arrays(bag, topics.COMMAND, ('command',)),
        'measurement': bagio.step_arrays(bag, topics.MEASUREMENT,
                                         ('applied', 'displacement', 'force')),
    }


def test_lockstep_composed_equals_processes_bit_for_bit(tmp_path):
    config = lockstep_config(tmp_path / 'config')
    runs = {}
    for layout in ('composed', 'processes'):
        bag = tmp_path / layout
        proc = rths('launch', '--config', config, '--bag', bag, '--layout', layout, timeout=300)
        assert ('started container' in proc.stdout) == (layout == 'composed')
        runs[layout] = loop_arrays(bag)
    n = 256
    for name, table in runs['composed'].items():
        other = runs['processes'][name]
        assert np.array_equal(table['step'], np.arange(n)), name
        for key, values in table.items():
            assert np.array_equal(values, other[key]), (name, key)   # bitwise, not allclose
    assert np.max(np.abs(runs['composed']['measurement']['force'])) > 1.0   # the loop acted


def realtime_config(directory, duration_s=DURATION_S):
    from rths_bench.bench_loop import write_config

    # normal scheduling (CI may not allow SCHED_FIFO); a watchdog of a whole second: a loaded
    # machine can stall the process for tens of ms
    return write_config(directory, rate_hz=RATE_HZ, duration_s=duration_s, taps=50,
                        model='sdof', priority=0, watchdog_steps=int(RATE_HZ))


def test_realtime_composed_bag_holds_every_step_and_the_miss_accounting(tmp_path):
    from rths_bench.bench_loop import bag_check
    from rths_review.review import read_loop

    bag = tmp_path / 'bag'
    proc = rths('launch', '--config', realtime_config(tmp_path / 'config'), '--bag', bag,
                '--timeout', 180, timeout=300)
    out = proc.stdout
    assert 'started container' in out and 'run finished' in out, out[-3000:]
    assert f'run complete after {N_STEPS} ticks' in out
    assert '0 dropped' in out and 'BAG INCOMPLETE' not in out
    loop = read_loop(bag)
    for topic, data in loop['steps'].items():   # displacement, command, measurement
        assert data['step'] == list(range(N_STEPS)), topic
    status = loop['status']
    for node in ('numerical', 'compensator', 'bridge'):
        assert sorted(status[node]['step']) == list(range(N_STEPS)), node
    bridge = status['bridge']
    flags = read_bridge_flags(bag)
    assert bridge['misses'] == sum(flags)   # the running count equals the flagged steps
    check = bag_check(bag, N_STEPS, np.asarray(flags, dtype=bool))
    assert check['recorder_loss'] == {t: 0 for t in loop['steps']}
    assert check['status_matches_bridge']


def read_bridge_flags(bag) -> list:
    from rths_common import bagio, topics

    flags = {}
    for _, _, msg in bagio.read_messages(bag, [topics.STATUS]):
        if msg.node == 'bridge':
            flags[int(msg.step)] = bool(msg.deadline_missed)
    return [flags[k] for k in sorted(flags)]


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_to_the_container_stops_all_three_nodes_and_keeps_the_bag(tmp_path, sig):
    from rths_review.review import read_loop, step_check

    bag = tmp_path / 'bag'
    proc = launch_background(realtime_config(tmp_path / 'config', duration_s=600.0), bag)
    try:
        head = wait_for(proc, 'graph connected', timeout=120)
        drain = Drain(proc, head)
        wait_steps(bag, int(RATE_HZ), timeout=60, drain=drain)
        os.kill(started_pids(head)['container'], sig)
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    out = drain.text()
    assert f'node container died (exit code {128 + sig})' in out, out[-3000:]
    for line in ('numerical: ', 'compensator: ', 'bridge: ', 'recording tee: ',
                 f'container: ended by signal {int(sig)}'):
        assert line in out, (line, out[-3000:])
    assert 'BAG INCOMPLETE' not in out
    assert (bag / 'metadata.yaml').exists()          # closed by the recorder itself
    loop = read_loop(bag)
    for topic, data in loop['steps'].items():
        check = step_check(data['step'])
        assert check['first'] == 0 and check['count'] >= RATE_HZ, (topic, check)
        assert check['gaps'] == 0 and check['duplicates'] == 0 and check['in_order'], topic
    ticks = len(loop['steps']['/rths/measurement']['step'])
    assert sorted(loop['status']['bridge']['step']) == list(range(ticks))
