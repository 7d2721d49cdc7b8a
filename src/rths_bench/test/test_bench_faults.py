"""``rths bench faults`` on a tiny configuration, and the parts it is made of.

The graph run (a 2 s composed run with one injected 200 ms bridge stall, then a
SIGKILL of the recorder) checks what the bench reports against what the run did:
the stall's final safety state is the documented one, the command stays inside
its limits, the bag holds every tick the loop produced and, after the kill, a
complete prefix of them (issue 28's target, the bag ends at most 100 ms before the
kill, is the quiet benchmark's: a loaded CI machine starves the recorder).
"""

import json
import os

import numpy as np
import pytest

from rths_bench import bench_faults as bf
from rths_bringup.cli import main as rths
from rths_common import bagio, cdr, topics


def test_the_documented_state_per_stall_length():
    assert bf.EXPECTED_STATE == {20: bf.SAFETY_OK, 50: bf.SAFETY_OK, 200: bf.SAFETY_OK}
    assert bf.expected_state(600) == bf.SAFETY_STOPPED     # beyond stall_limit_s 0.5 s
    from rths_actuator_bridge.safety import SAFETY_PARAMS
    assert SAFETY_PARAMS['stall_limit_s'][0] == bf.STALL_LIMIT_S


def test_cases_are_selected_by_name_or_prefix_and_a_typo_is_refused():
    assert bf.select('stall_bridge') == ['stall_bridge_20', 'stall_bridge_50', 'stall_bridge_200']
    assert len(bf.select('all')) == 15
    with pytest.raises(ValueError, match='no such case'):
        bf.select('cpu_hogg')


def test_threads_are_listed_with_their_scheduling():
    threads = bf.threads_of(os.getpid())
    me = [t for t in threads if t['tid'] == os.getpid()]
    assert me and me[0]['policy'] in ('SCHED_OTHER', 'SCHED_FIFO') and me[0]['cpus']


def test_command_peaks_are_those_written(tmp_path):
    bag = tmp_path / 'bag'
    fs = 1000.0
    with bagio.BagWriter(bag, topics.LOOP_TOPICS) as w:
        for k, u in enumerate([0.0, 0.001, 0.003, 0.002]):
            w.write(topics.MEASUREMENT, k, cdr.pack_step_arrays(k, k, [u], [u], [0.0]))
    peaks = bf.command_peaks(bag, fs)
    assert peaks['command_peak_m'] == pytest.approx(0.003)
    assert peaks['velocity_peak_m_s'] == pytest.approx(2.0)       # 0.002 m in 1 ms
    assert peaks['acceleration_peak_m_s2'] == pytest.approx(3000.0)   # 2 m/s to -1 m/s


def test_the_memory_hog_stays_bounded(tmp_path):
    before = bf.mem_available()
    with bf.Hogs('memory', tmp_path, 0.01) as hog:
        assert 0 < hog.info['held_mb'] <= max(before >> 20, 1) * 0.01 + 64
    assert not any(p.poll() is None for p in hog.procs)


def test_bench_faults_on_a_tiny_run(tmp_path):
    out = tmp_path / 'faults.json'
    assert rths(['bench', 'faults', '--cases', 'stall_bridge_200,kill_recorder',
                 '--duration', '2', '--taps', '16', '--out', str(out)]) == 0
    report = json.loads(out.read_text())
    stall = report['cases']['stall_bridge_200']
    assert stall['stalls'] == 1 and stall['state_as_documented'] and stall['within_limits']
    assert stall['samples_lost'] == 0 and stall['samples_in_bag'] == stall['samples_produced']
    # the same run's empty SCHED_FIFO thread and the hypervisor's steal are beside it
    assert 0 <= stall['floor_late_or_missed_pct'] <= 100.0 and stall['steal_ms'] >= 0.0
    assert 0 <= stall['stalled_ticks_shared_with_floor'] <= stall['stalled_ticks']
    kill = report['cases']['kill_recorder']
    assert 'floor_late_or_missed_pct' not in kill        # a killed run has no loop to compare
    # the <= 100 ms target is the quiet benchmark's (docs/bench/faults_1024hz_10s.json): a
    # loaded CI machine starves the recorder (nice 10); here the mechanism: a tail is lost,
    # nothing before it, and the loss is measured against what the loop produced
    assert kill['killed_pids'] and kill['bag_prefix_complete'] and kill['within_limits']
    assert 0 <= kill['loss_before_kill_ms'] <= 2000.0
    assert kill['last_produced_before_kill_ns'] <= kill['kill_wall_ns']


def test_the_loss_before_a_kill_counts_only_what_the_loop_produced(tmp_path):
    ms = 1_000_000
    timing = tmp_path / 'bridge_timing.npz'
    np.savez(timing, tick_wall_ns=np.arange(0, 1000 * ms, ms))      # ticks 0 .. 999 ms
    mid = bf.loss_before_kill({'kill_wall_ns': 500 * ms, 'last_bridge_stamp_ns': 420 * ms},
                              timing)
    assert mid['loss_before_kill_ms'] == 80.0                         # ticks 421 .. 500 lost
    after_end = bf.loss_before_kill({'kill_wall_ns': 1200 * ms,
                                     'last_bridge_stamp_ns': 999 * ms}, timing)
    assert after_end['loss_before_kill_ms'] == 0.0                    # the bag has it all
    no_timing = bf.loss_before_kill({'kill_wall_ns': 500 * ms, 'last_bridge_stamp_ns': 420 * ms},
                                    tmp_path / 'none.npz')            # a killed container
    assert no_timing['loss_before_kill_ms'] == 80.0


def test_a_loop_stall_counts_as_shared_only_where_the_empty_thread_stalled_too():
    ms = 1_000_000
    period = ms
    # the loop woke 5 ms late at 100 ms and 3 ms late at 400 ms; the probe 4 ms late at 101 ms
    loop = bf.stall_intervals([100 * ms, 400 * ms, 600 * ms], [5 * ms, 3 * ms, ms // 2], period)
    assert loop.tolist() == [[95 * ms, 100 * ms], [397 * ms, 400 * ms]]   # 0.5 ms is no stall
    probe = bf.stall_intervals([101 * ms, 300 * ms], [4 * ms, 2 * ms], period)
    assert bf.shared_stalls(loop, probe, period).tolist() == [True, False]
    # within one period of each other still counts (the two clocks' ticks are not aligned)
    near = bf.stall_intervals([396 * ms + period // 2], [2 * ms], period)   # ends 0.5 ms before
    assert bf.shared_stalls(loop, near, period).tolist() == [False, True]
    assert bf.shared_stalls(loop, near[:0], period).tolist() == [False, False]


def test_the_probe_runs_on_the_cpus_it_is_given(tmp_path):
    import os
    import time
    cpu = max(os.sched_getaffinity(0))
    probe = bf.FloorProbe(1000.0, 0.0, tmp_path / 'probe.npz', str(cpu))
    try:
        allowed = ''
        for _ in range(100):              # the probe pins itself after its imports
            status = open(f'/proc/{probe.proc.pid}/status').read()
            allowed = status.split('Cpus_allowed_list:')[1].split()[0]
            if allowed == str(cpu):
                break
            time.sleep(0.05)
        assert allowed == str(cpu)
    finally:
        probe.stop()


def test_the_probe_sleeps_to_deadlines_until_stopped(tmp_path):
    import time
    probe = bf.FloorProbe(1000.0, 0.0, tmp_path / 'probe.npz')
    time.sleep(3.0)                       # its start-up (imports) included
    probe.stop()
    woke = probe.woke
    assert woke['late_ns'].size >= 100 and woke['late_ns'].min() >= 0
    assert np.all(np.diff(woke['wall_ns']) > 0)
    share = bf.machine_share(probe, tmp_path / 'none.npz', bf.steal_jiffies(), 3.0, 1000.0)
    assert share['floor_late_or_missed_pct'] >= 0 and 'loop_stalls' not in share   # no loop timing
