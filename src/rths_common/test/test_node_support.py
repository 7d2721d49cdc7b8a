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
    import numpy  # noqa: F401 (a loop process has numpy's OpenBLAS loaded when it tunes)
    before = os.sched_getaffinity(0)
    policy = os.sched_getscheduler(0)
    env = {k: os.environ.get(k) for k in ns.BLAS_THREADS_ENV}
    try:
        text = ns.tune_process(rt_priority=1, cpus=','.join(map(str, sorted(before))))
        # either SCHED_FIFO was granted or the refusal is reported, never an exception
        assert 'SCHED_FIFO 1' in text
        assert 'cpus' in text or 'affinity' in text
        # BLAS's spinning worker threads are off (they hung a loop pinned to one CPU)
        from threadpoolctl import threadpool_info
        assert 'BLAS on 1 thread' in text
        blas = [lib for lib in threadpool_info() if lib['user_api'] == 'blas']
        assert blas and all(lib['num_threads'] == 1 for lib in blas)
        assert all(os.environ[k] == '1' for k in ns.BLAS_THREADS_ENV)   # for those loaded later
    finally:
        for k, v in env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
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
    # realtime: the loop's readers stay best-effort, depth 1; the writers and the recorder
    # are reliable with a deep history (issue 30: a best-effort recorder lost 220 steps)
    writer = qos.loop_writer_qos('realtime')
    assert writer.reliability == ReliabilityPolicy.RELIABLE
    assert writer.durability == DurabilityPolicy.VOLATILE
    assert writer.depth == qos.REALTIME_WRITER_DEPTH >= 4 * 1024
    rec = qos.recorder_qos('realtime')
    assert rec.reliability == ReliabilityPolicy.RELIABLE and rec.depth == writer.depth
    assert qos.loop_writer_qos('lockstep') == ls
    info = qos.run_info_qos()
    assert info.durability == DurabilityPolicy.TRANSIENT_LOCAL and info.depth == 1
    with pytest.raises(ValueError):
        qos.loop_qos('fast')


def test_realtime_recorder_matches_the_loop_writer_and_loses_nothing_while_it_lags():
    """Issue 30: a recorder that does not take messages for a while (a loaded machine) loses none.

    Over DDS (Fast DDS here): the realtime loop writer matches both a loop reader
    (best-effort, depth 1: it still sees only the newest step) and the recorder's
    reader; 3000 steps published while the recorder is not spun all reach it, in
    order.  (With the former best-effort recorder of depth 1000 the first 2000
    were gone.)  A reliable reader would not match a best-effort writer: the
    writers must offer reliability.
    """
    import time
    import uuid

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import UInt64

    topic = f'/rths_test_{uuid.uuid4().hex[:8]}'
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node('qos_probe', context=ctx)
        pub = node.create_publisher(UInt64, topic, qos.loop_writer_qos('realtime'))
        got_loop, got_rec = [], []
        node.create_subscription(UInt64, topic, lambda m: got_loop.append(m.data),
                                 qos.loop_qos('realtime'))
        node.create_subscription(UInt64, topic, lambda m: got_rec.append(m.data),
                                 qos.recorder_qos('realtime'))
        best_effort_pub = node.create_publisher(
            UInt64, topic + '_be', QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        node.create_subscription(UInt64, topic + '_be', lambda m: None,
                                 qos.recorder_qos('realtime'))
        t_end = time.monotonic() + 10.0
        while pub.get_subscription_count() < 2 and time.monotonic() < t_end:
            time.sleep(0.01)
        assert pub.get_subscription_count() == 2      # the loop reader and the recorder
        assert best_effort_pub.get_subscription_count() == 0
        n = 3000
        for k in range(n):                 # nobody takes them meanwhile
            pub.publish(UInt64(data=k))
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        t_end = time.monotonic() + 20.0
        while len(got_rec) < n and time.monotonic() < t_end:
            executor.spin_once(timeout_sec=0.05)
        assert got_rec == list(range(n))
        assert got_loop and len(got_loop) < n      # best-effort depth 1: the newest only
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


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


def test_the_step_logger_writes_what_rclpy_writes_and_keeps_the_threshold(capfd):
    import rclpy
    from rclpy.logging import LoggingSeverity

    logger = rclpy.logging.get_logger('rths_step_logger_test')
    log = ns.StepLogger(logger)
    assert log.info('progress: step 1024 of 2048 (1.0 s simulated)')
    logger.info('progress: step 1024 of 2048 (1.0 s simulated)')
    err = capfd.readouterr().err.splitlines()
    ours, rclpys = [line.split('] ', 2)[2] for line in err[-2:]]
    # the same line ("[INFO] [time] [name]: text") as rclpy's, which the launcher parses
    text = 'progress: step 1024 of 2048 (1.0 s simulated)'
    assert ours == rclpys == f'[rths_step_logger_test]: {text}'
    assert err[-2].startswith('[INFO]')
    child = log.get_child('container')
    assert child.name == 'rths_step_logger_test.container'
    logger.set_level(LoggingSeverity.WARN)
    try:
        assert not log.info('below the threshold') and not log.debug('nor this')
        assert log.warning('a warning') and log.error('an error')
        err = capfd.readouterr().err
        assert 'below the threshold' not in err and '[WARN]' in err and '[ERROR]' in err
    finally:
        logger.set_level(LoggingSeverity.INFO)


class _Clock:
    """A simulated monotonic clock for spin_clocked (``ns.time``): only sleeps and work move it.

    The host's stalls cannot then change what the tests see.
    """

    def __init__(self):
        self.now = 1_000_000_000

    def monotonic_ns(self):
        return self.now

    def sleep(self, seconds):
        self.now += int(seconds * 1e9)

    def work(self, ns_):
        self.now += ns_


class _Executor:
    """spin_once recorder: each call's timeout; a call hands over one queued event.

    A call costs ``cost_ns`` on ``clock``; a timed one waits out its timeout (nothing arrives).
    """

    def __init__(self, clock, cost_ns=35_000):
        self.clock, self.cost_ns = clock, cost_ns
        self.calls = []
        self.events = []

    def add_node(self, node):
        pass

    def remove_node(self, node):
        pass

    def spin_once(self, timeout_sec=None):
        self.calls.append(timeout_sec)
        self.clock.work(self.cost_ns + int((timeout_sec or 0.0) * 1e9))
        if self.events:
            self.events.pop(0)()


def _clocked(monkeypatch, period_ns, n_ticks, quiet, ready=lambda: True, at_tick=None,
             ok=lambda: True, done=True, tick_ns=100_000, **kwargs):
    """Run spin_clocked for ``n_ticks`` ticks on a simulated clock; (executor, tick times, start).

    ``at_tick(k, executor)`` is called in tick k, which works ``tick_ns``; ``ok`` stands for
    ``rclpy.ok``; ``done``: what spin_clocked must return.
    """
    clock = _Clock()
    monkeypatch.setattr(ns, 'time', clock)
    monkeypatch.setattr(ns.rclpy, 'ok', ok)
    executor = _Executor(clock)
    start = clock.now + period_ns
    ticks = []

    def next_due_ns():
        return start + len(ticks) * period_ns

    def tick():
        if at_tick is not None:
            at_tick(len(ticks), executor)
        ticks.append(clock.now)
        clock.work(tick_ns)

    assert ns.spin_clocked(object(), executor, next_due_ns, tick,
                           is_done=lambda: len(ticks) >= n_ticks, ready=ready, quiet=quiet,
                           **kwargs) is done
    return executor, ticks, start


def test_clocked_loop_with_direct_delivery_sleeps_to_its_ticks_and_passes_each_ms(monkeypatch):
    period = 250_000                  # about 4096 Hz: 80 ticks are 20 ms
    handed_over = []

    def at_tick(k, executor):
        if k == 20:                   # e.g. an emergency stop arrives over DDS
            executor.events.append(lambda: handed_over.append(k_now[0]))
        k_now[0] = k

    k_now = [0]
    executor, ticks, start = _clocked(monkeypatch, period, 80, quiet=lambda: True,
                                      at_tick=at_tick, pass_ns=1_000_000)
    assert ticks == [start + k * period for k in range(80)]     # each on time, never early
    # one executor pass (with no wait in it) each 1-1.25 ms (a tick is the loop's grain),
    # not two calls a tick
    assert set(executor.calls) == {0.0}
    assert 16 <= len(executor.calls) <= 21
    # the event went to its callback within a millisecond (4 periods)
    assert handed_over and handed_over[0] - 20 <= 4


def test_clocked_loop_asks_rclpy_ok_at_its_passes_and_ends_once_it_is_false(monkeypatch):
    """Quiet: rclpy's context (2 us a call) is asked at the executor's passes, not every tick.

    Its shutdown still ends the loop within a pass (1 ms).
    """
    period, asked = 250_000, []

    def ok():
        asked.append(1)
        return True
    executor, _, _ = _clocked(monkeypatch, period, 80, quiet=lambda: True, ok=ok,
                              pass_ns=1_000_000)
    assert len(asked) == len(executor.calls) <= 21          # 80 ticks
    state = {'ok': True}

    def at_tick(k, executor):
        state['ok'] = k < 10
    _, ticks, _ = _clocked(monkeypatch, period, 80, quiet=lambda: True, at_tick=at_tick,
                           ok=lambda: state['ok'], done=False, pass_ns=1_000_000)
    assert 10 < len(ticks) <= 10 + 5                         # within a pass (4 periods)


def test_clocked_loop_waits_in_the_executor_while_messages_cross_dds(monkeypatch):
    period = 1_000_000
    calls_at_tick = []
    executor, _, _ = _clocked(monkeypatch, period, 20, quiet=lambda: False,
                              at_tick=lambda k, ex: calls_at_tick.append(len(ex.calls)))
    # every tick comes after an executor call (a command may arrive until its tick) ...
    assert all(b > a for a, b in zip([0, *calls_at_tick[:-1]], calls_at_tick, strict=True))
    # ... and the loop waited for its ticks in the executor
    assert sum(1 for t in executor.calls if t) >= 19
    # quiet, but the next tick's command is not here: the executor's path, as over DDS
    calls_at_tick.clear()
    executor, _, _ = _clocked(monkeypatch, period, 20, quiet=lambda: True, ready=lambda: False,
                              at_tick=lambda k, ex: calls_at_tick.append(len(ex.calls)))
    assert all(b > a for a, b in zip([0, *calls_at_tick[:-1]], calls_at_tick, strict=True))


def test_clocked_loop_sleeping_to_a_far_tick_looks_again_every_poll(monkeypatch):
    """A tick further away than ``poll_s``: the sleep is cut there (a signal's flag is seen)."""
    clock = _Clock()
    monkeypatch.setattr(ns, 'time', clock)
    monkeypatch.setattr(ns.rclpy, 'ok', lambda: True)
    due = clock.now + 60_000_000
    asked, ticks = [], []

    def next_due_ns():
        asked.append(clock.now)
        return due

    assert ns.spin_clocked(object(), _Executor(clock), next_due_ns, lambda: ticks.append(1),
                           is_done=lambda: bool(ticks), ready=lambda: True,
                           quiet=lambda: True, poll_s=0.02, pass_ns=10**12)
    # woken at 20 and 40 ms to look again, at 60 ms to tick
    assert ticks == [1] and [t - asked[0] for t in asked] == [0, 20_000_000, 40_000_000]
