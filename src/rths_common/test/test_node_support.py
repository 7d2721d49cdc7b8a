"""ROS-side helpers of rths_common: CPU lists, process tuning, QoS per mode, the tick loop."""

import gc
import os

import pytest

from rths_common import node_support as ns
from rths_common import qos


def test_parse_cpus():
    assert ns.parse_cpus('') == set()
    assert ns.parse_cpus('1') == {1}
    assert ns.parse_cpus('0,1') == {0, 1}
    assert ns.parse_cpus('0-2, 5') == {0, 1, 2, 5}
    with pytest.raises(ValueError, match='cpus'):
        ns.parse_cpus('one')


def test_tune_process_gc_modes_and_bad_values():
    try:
        assert 'gc freeze' in ns.tune_process(gc_mode='freeze')
        assert gc.isenabled()
        assert 'gc disable' in ns.tune_process(gc_mode='disable')
        assert not gc.isenabled()
    finally:
        gc.enable()
        gc.unfreeze()
    with pytest.raises(ValueError, match='gc'):
        ns.tune_process(gc_mode='off')


def test_tune_process_affinity_and_priority_fall_back_cleanly():
    before = os.sched_getaffinity(0)
    policy = os.sched_getscheduler(0)
    try:
        text = ns.tune_process(rt_priority=1, cpus=','.join(map(str, sorted(before))))
        # either SCHED_FIFO was granted or the refusal is reported, never an exception
        assert 'SCHED_FIFO 1' in text
        assert 'cpus' in text or 'affinity' in text
    finally:
        for tid in map(int, os.listdir('/proc/self/task')):
            try:
                os.sched_setscheduler(tid, policy, os.sched_param(0))
                os.sched_setaffinity(tid, before)
            except OSError:
                pass


def test_qos_per_mode():
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    rt = qos.loop_qos('realtime')
    assert rt.reliability == ReliabilityPolicy.BEST_EFFORT and rt.depth == 1
    ls = qos.loop_qos('lockstep')
    assert ls.reliability == ReliabilityPolicy.RELIABLE
    assert qos.recorder_qos('realtime').reliability == ReliabilityPolicy.BEST_EFFORT
    info = qos.run_info_qos()
    assert info.durability == DurabilityPolicy.TRANSIENT_LOCAL and info.depth == 1
    with pytest.raises(ValueError):
        qos.loop_qos('fast')


def test_tick_thread_ticks_in_order_and_stops():
    import time

    period = 2_000_000
    t0 = time.monotonic_ns() + period
    ticks = []

    def due():
        return t0 + len(ticks) * period if len(ticks) < 5 else None

    def tick():
        ticks.append(time.monotonic_ns())

    clock = ns.TickThread(due, tick, poll_s=0.001).start()
    end = time.monotonic() + 5.0
    while len(ticks) < 5 and time.monotonic() < end:
        time.sleep(0.005)
    clock.stop()
    assert clock.error is None
    assert len(ticks) == 5
    assert all(t >= t0 + i * period for i, t in enumerate(ticks))
